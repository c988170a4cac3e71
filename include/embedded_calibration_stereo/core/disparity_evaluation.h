#pragma once
// Middlebury-style evaluation of a disparity map against ground truth.
#include <opencv2/core.hpp>
#include <string>

namespace ecs {

struct BadPixelStats {
  int evaluated = 0;       // pixels with ground truth (ground truth > 0)
  int bad = 0;             // |d - gt| > threshold, invalid output included
  int invalid = 0;         // pixels with ground truth but no output disparity
  double badPercent() const { return evaluated > 0 ? 100.0 * bad / evaluated : 0.0; }
};

// disparity: CV_32F in pixels, NaN or +-inf = invalid. ground_truth: CV_32F in pixels, <= 0 (or
// non-finite) = unknown. Throws std::invalid_argument on mismatched sizes or types.
BadPixelStats evaluateBadPixels(const cv::Mat& disparity, const cv::Mat& ground_truth,
                                double threshold_px);

// Loads an 8- or 16-bit ground-truth image (PNG/PGM, palette PNGs as gray) and divides by scale:
// the Middlebury convention (value / scale = disparity, 0 = unknown). Throws std::runtime_error
// when the file cannot be read.
cv::Mat loadScaledGroundTruth(const std::string& path, double scale);

}  // namespace ecs
