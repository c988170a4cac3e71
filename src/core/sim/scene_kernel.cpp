// Which scene kernel runs: the AVX2 one where it was built and the CPU has AVX2 and FMA.
#include "scene_kernel.h"

#include <opencv2/core/utility.hpp>

namespace embedded_calibration_stereo::core {
namespace sim {
namespace scene_kernel {

const Kernel& bestKernel() {
#ifdef ECS_SIM_AVX2
  static const bool avx2 = cv::checkHardwareSupport(CV_CPU_AVX2) && cv::checkHardwareSupport(CV_CPU_FMA3);
  if (avx2) return avx2Kernel();
#endif
  return baselineKernel();
}

}  // namespace scene_kernel
}  // namespace sim
}  // namespace embedded_calibration_stereo::core
