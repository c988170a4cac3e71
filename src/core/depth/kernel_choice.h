// How our matchers (sad, census_sgm) choose their kernel, the inner loops built once per
// instruction set: "baseline" (the compiler's default instructions) always, "avx2" on x86-64
// CPUs with AVX2 when the build has the AVX2 kernels, "avx512" (census_sgm only) on CPUs with
// the AVX-512 subsets its kernel is built for (CMakeLists.txt), "auto" the widest of those.
#pragma once

#include <opencv2/core/utility.hpp>
#include <stdexcept>
#include <string>
#include <vector>

namespace embedded_calibration_stereo::core {

// True when this build has the AVX2 kernels and this CPU runs them.
inline bool kernelsAvx2Available() {
#if defined(ECS_SAD_AVX2) && defined(ECS_SGM_AVX2)
  return cv::checkHardwareSupport(CV_CPU_AVX2);
#else
  return false;
#endif
}

// True when this build has the census_sgm AVX-512 kernel and this CPU runs it: the SKX set
// (F, BW, VL, DQ, CD) with VBMI's byte permutes and BITALG's byte popcount.
inline bool kernelAvx512Available() {
#if defined(ECS_SGM_AVX512)
  return kernelsAvx2Available() && cv::checkHardwareSupport(CV_CPU_AVX512_SKX) &&
         cv::checkHardwareSupport(CV_CPU_AVX_512VBMI) && cv::checkHardwareSupport(CV_CPU_AVX_512BITALG);
#else
  return false;
#endif
}

// A matcher's kernels: the baseline one, and the getters of the wider ones it has (nullptr
// where the build has none).
template <class Kernel>
struct KernelSet {
  const Kernel& baseline;
  const Kernel& (*avx2)();
  const Kernel& (*avx512)();
};

template <class Kernel>
std::vector<std::string> kernelNames(const KernelSet<Kernel>& set) {
  std::vector<std::string> names{"baseline"};
  if (set.avx2 && kernelsAvx2Available()) names.push_back("avx2");
  if (set.avx512 && kernelAvx512Available()) names.push_back("avx512");
  return names;
}

// The kernel called `name` ("auto": the last, widest, of kernelNames). Throws
// std::invalid_argument naming `matcher` and the kernels there are.
template <class Kernel>
const Kernel& kernelNamed(const std::string& matcher, const std::string& name, const KernelSet<Kernel>& set) {
  const std::vector<std::string> names = kernelNames(set);
  const std::string chosen = name == "auto" ? names.back() : name;
  if (chosen == "baseline") return set.baseline;
  for (const std::string& n : names) {
    if (n != chosen) continue;
    return n == "avx2" ? set.avx2() : set.avx512();
  }
  std::string listed;
  for (const auto& n : names) listed += n + ", ";
  throw std::invalid_argument(matcher + " matcher: kernel '" + name + "' is not available here (" +
                              listed + "auto)");
}

}  // namespace embedded_calibration_stereo::core
