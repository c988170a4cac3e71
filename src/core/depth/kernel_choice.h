// How our matchers (sad, census_sgm) choose their kernel, the inner loops built once per
// instruction set: "baseline" (the compiler's default instructions) always, "avx2" on x86-64
// CPUs with AVX2 when the build has the AVX2 kernels, "avx512" (census_sgm only) on CPUs with
// the AVX-512 subsets its kernel is built for (CMakeLists.txt), "auto" the widest of those.
#pragma once

#include <initializer_list>
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

// True when this build has the census_sgm AVX-512 kernel and this CPU runs it: F, BW, VL, DQ,
// CD, VBMI's byte permutes and BITALG's byte popcount. Asked one by one (not as OpenCV's SKX
// group) so that OPENCV_CPU_DISABLE=AVX512F, which clears the feature but not the group, makes
// the matchers fall back to AVX2.
inline bool kernelAvx512Available() {
#if defined(ECS_SGM_AVX512)
  for (const int feature : {CV_CPU_AVX_512F, CV_CPU_AVX_512BW, CV_CPU_AVX_512VL, CV_CPU_AVX_512DQ,
                            CV_CPU_AVX_512CD, CV_CPU_AVX_512VBMI, CV_CPU_AVX_512BITALG})
    if (!cv::checkHardwareSupport(feature)) return false;
  return kernelsAvx2Available();
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

// The kernel called `name` ("auto": the widest there is). Throws std::invalid_argument naming
// `matcher` and the kernels there are. Called for every frame: it builds no list unless it throws.
template <class Kernel>
const Kernel& kernelNamed(const std::string& matcher, const std::string& name, const KernelSet<Kernel>& set) {
  const bool avx2 = set.avx2 && kernelsAvx2Available();
  const bool avx512 = set.avx512 && kernelAvx512Available();  // implies AVX2
  if ((name == "avx512" || name == "auto") && avx512) return set.avx512();
  if ((name == "avx2" || name == "auto") && avx2) return set.avx2();
  if (name == "baseline" || name == "auto") return set.baseline;
  std::string listed;
  for (const auto& n : kernelNames(set)) listed += n + ", ";
  throw std::invalid_argument(matcher + " matcher: kernel '" + name + "' is not available here (" +
                              listed + "auto)");
}

}  // namespace embedded_calibration_stereo::core
