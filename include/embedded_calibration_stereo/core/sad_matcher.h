#pragma once
// The original head's block matcher ("sad" algorithm): sum of absolute differences over a
// square window of x-Sobel prefiltered images (clipped to +-prefilter_cap, like StereoBM's
// XSOBEL prefilter), winner-take-all over the disparity range.
//
// Cost: O(W * H * D) whatever the window size. Per row band, the per-disparity column sums of
// the window are updated by one entering and one leaving row, and the window sums by one
// entering and one leaving column (running box sums), vectorised across the disparities with
// OpenCV's universal intrinsics (SSE2/NEON/... as the build allows; a scalar fallback gives
// identical results). The sums of 8 pixels are then transposed so that the winner search, the
// uniqueness test (as StereoBM's: no other disparity than the winner and its two neighbours may
// cost within uniqueness_ratio % of it) and the right image's winners (for the left-right
// check, taken from the same sums) run across 8 pixels at a time. Row bands run on
// cv::parallel_for_; results do not depend on the number of threads.
//
// Threading: computeSadDisparity16 is reentrant (no shared state).
#include <opencv2/core.hpp>

namespace ecs {

struct SadMatcherParams {
  int window_size = 9;        // odd, 3..15 (the int16 window sums must not overflow)
  int min_disparity = 0;
  int num_disparities = 64;   // multiple of 16
  int prefilter_cap = 31;     // 1..63
  double uniqueness_ratio = 10;  // percent; 0 disables
  bool left_right_check = true;
  int left_right_tolerance = 1;  // pixels
  bool subpixel = true;          // parabola through the best cost and its neighbours
};

// left, right: rectified CV_8UC1 of one size. Returns CV_16SC1 disparity scaled by 16
// (cv::StereoMatcher::DISP_SCALE), invalid pixels = (min_disparity - 1) * 16, i.e. the same
// encoding as OpenCV's matchers so that cv::filterSpeckles applies. Throws std::invalid_argument
// on bad input or parameters.
cv::Mat computeSadDisparity16(const cv::Mat& left, const cv::Mat& right,
                              const SadMatcherParams& params);

}  // namespace ecs
