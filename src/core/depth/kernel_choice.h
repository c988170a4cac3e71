// How our matchers (sad, census_sgm) choose their kernel, the inner loops built once per
// instruction set: "baseline" (the compiler's default instructions) always, "avx2" on x86-64
// CPUs with AVX2 when the build has the AVX2 kernels (CMakeLists.txt), "auto" the widest of
// those.
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

inline std::vector<std::string> kernelNames() {
  std::vector<std::string> names{"baseline"};
  if (kernelsAvx2Available()) names.push_back("avx2");
  return names;
}

// The kernel called `name`; `avx2` is only read when AVX2 is available. Throws
// std::invalid_argument naming `matcher` and the kernels there are.
template <class Kernel>
const Kernel& kernelNamed(const std::string& matcher, const std::string& name, const Kernel& baseline,
                          const Kernel& (*avx2)()) {
  const bool wide = kernelsAvx2Available();
  if (name == "baseline" || (name == "auto" && !wide)) return baseline;
  if ((name == "avx2" || name == "auto") && wide) return avx2();
  std::string names;
  for (const auto& n : kernelNames()) names += n + ", ";
  throw std::invalid_argument(matcher + " matcher: kernel '" + name + "' is not available here (" +
                              names + "auto)");
}

}  // namespace embedded_calibration_stereo::core
