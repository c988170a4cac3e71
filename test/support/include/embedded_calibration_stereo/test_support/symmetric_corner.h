#pragma once
// A corner measurement without cv::cornerSubPix's own error floor (bilinear resampling of the
// window and discrete gradients): around a chessboard corner the (blurred) image is
// point-symmetric, I(c + d) = I(c - d), so the corner is the centre c minimising
// sum_d (I(c + d) - I(c - d))^2, sampled with bicubic interpolation. The simulator's corner
// tests measure the renderer with it.
#include <opencv2/core.hpp>

namespace embedded_calibration_stereo::core {

// Bicubic (Keys, a = -0.5) sample of a CV_32F image at (x, y), borders replicated.
double bicubicSample(const cv::Mat& image, double x, double y);

// Gauss-Newton on the symmetry residuals over |dx|, |dy| <= radius (numeric derivatives), from
// `start`, on a CV_32F image.
cv::Point2d symmetricCorner(const cv::Mat& image, cv::Point2d start, int radius);

}  // namespace embedded_calibration_stereo::core
