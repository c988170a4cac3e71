#pragma once
// Middlebury-style evaluation of a disparity map against ground truth.
#include <opencv2/core.hpp>
#include <string>

#include "embedded_calibration_stereo/core/depth/rectification.h"

namespace embedded_calibration_stereo::core {

struct BadPixelStats {
  int evaluated = 0;       // pixels with ground truth (ground truth > 0)
  int bad = 0;             // |d - gt| > threshold, invalid output included
  int invalid = 0;         // pixels with ground truth but no output disparity
  int inliers = 0;         // valid and |d - gt| <= threshold
  double inlier_square_sum = 0.0;  // of (d - gt) over the inliers, px^2
  double badPercent() const { return evaluated > 0 ? 100.0 * bad / evaluated : 0.0; }
  // The sub-pixel accuracy of the matches that are right (0 without inliers).
  double inlierRmsPx() const;
};

// disparity: CV_32F in pixels, NaN or +-inf = invalid. ground_truth: CV_32F in pixels, <= 0 (or
// non-finite) = unknown. Throws std::invalid_argument on mismatched sizes or types.
BadPixelStats evaluateBadPixels(const cv::Mat& disparity, const cv::Mat& ground_truth,
                                double threshold_px);

// Loads an 8- or 16-bit ground-truth image (PNG/PGM, palette PNGs as gray) and divides by scale:
// the Middlebury convention (value / scale = disparity, 0 = unknown). Throws std::runtime_error
// when the file cannot be read.
cv::Mat loadScaledGroundTruth(const std::string& path, double scale);

// The true disparity of the rectified left image, from a depth map of the raw left image
// (CV_32FC1, z in metres; <= 0, NaN or > 1e6 = no depth) and the maps it is rectified with:
// d = f' * B / z_rect, where z_rect is the depth along the rectified optical axis. Pixels without
// depth are 0 (unknown, the evaluateBadPixels convention). Nearest-neighbour lookup, so depth
// edges are not blended. Throws std::invalid_argument when the depth map does not fit the maps.
cv::Mat rectifiedDisparityFromDepth(const cv::Mat& left_depth, const RectificationMaps& maps);

}  // namespace embedded_calibration_stereo::core
