#pragma once
// The original head's block matcher ("sad" algorithm): sum of absolute differences over a
// square window of x-Sobel prefiltered images (clipped to +-prefilter_cap, like StereoBM's
// XSOBEL prefilter), winner-take-all over the disparity range.
//
// Cost: O(W * H * D) whatever the window size. Per row band, the per-disparity column sums of
// the window are updated by one entering and one leaving row, and the window sums by one
// entering and one leaving column (running box sums), vectorised across the disparities with
// OpenCV's universal intrinsics. The sums of a vector's worth of pixels are then transposed so
// that the winner search, the uniqueness test (as StereoBM's: no other disparity than the winner
// and its two neighbours may cost within uniqueness_ratio % of it) and the right image's winners
// (for the left-right check, taken from the same sums) run across those pixels at once. Row
// bands run on cv::parallel_for_.
//
// Kernels: "baseline" is built with the compiler's default instruction set (SSE2 on x86-64,
// NEON on ARM, plain C++ elsewhere); on x86-64 an "avx2" kernel (16-bit lanes twice as wide) is
// built as well and chosen at run time when the CPU has AVX2. Results are identical whatever
// the kernel and the number of threads.
//
// Threading: computeSadDisparity16 is reentrant: its only state is scratch memory and work
// images kept per thread (thread_local) between calls.
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace embedded_calibration_stereo::core {

struct SadMatcherParams {
  int window_size = 9;        // odd, 3..15 (the int16 window sums must not overflow)
  int min_disparity = 0;
  int num_disparities = 64;   // multiple of 16
  int prefilter_cap = 31;     // 1..63
  double uniqueness_ratio = 10;  // percent; 0 disables
  bool left_right_check = true;
  int left_right_tolerance = 1;  // pixels
  bool subpixel = true;          // parabola through the best cost and its neighbours
  std::string kernel = "auto";   // "auto" (the widest this CPU runs), or one of sadKernelNames()
};

// The kernels this build and CPU can run: "baseline" always, "avx2" on x86-64 CPUs with AVX2.
std::vector<std::string> sadKernelNames();

// left, right: rectified CV_8UC1 of one size. Returns CV_16SC1 disparity scaled by 16
// (cv::StereoMatcher::DISP_SCALE), invalid pixels = (min_disparity - 1) * 16, i.e. the same
// encoding as OpenCV's matchers so that cv::filterSpeckles applies. Throws std::invalid_argument
// on bad input or parameters, or a kernel this machine cannot run.
cv::Mat computeSadDisparity16(const cv::Mat& left, const cv::Mat& right,
                              const SadMatcherParams& params);
// The same into *disparity, reusing its buffer when it already has the size and type.
void computeSadDisparity16(const cv::Mat& left, const cv::Mat& right, const SadMatcherParams& params,
                           cv::Mat* disparity);

}  // namespace embedded_calibration_stereo::core
