#pragma once
// Hole filling of a CV_32F disparity map (invalid = NaN, see disparity.h).
// Holes in a rectified left disparity map are mostly occlusions: surfaces seen by the left
// camera only, just left of a foreground edge, which belong to the background. So each run of
// invalid pixels on a row takes the smaller (farther) of the valid disparities at its two ends,
// or the one that exists at the image border; a 3x3 median over the filled pixels then removes
// the single-row streaks this leaves. Rows without any valid pixel stay invalid.
// Threading: works on its argument only; rows run on cv::parallel_for_.
#include <opencv2/core.hpp>

namespace embedded_calibration_stereo::core {

void fillDisparityHoles(cv::Mat* disparity);

}  // namespace embedded_calibration_stereo::core
