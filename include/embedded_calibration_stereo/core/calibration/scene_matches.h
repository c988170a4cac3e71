#pragma once
// Sparse left-right correspondences of the scene in one stereo frame (ROS-free): what the
// scene tells about the calibration. Two synchronised cameras see every scene point at the same
// instant, so a true correspondence obeys the epipolar constraint of the rig whatever the scene
// does (the head driving, people walking): its vertical offset after rectification is the
// misalignment the calibration causes there. Unlike the boards, which all lie about 1.2 m away,
// the scene spans every depth, which separates the stereo rotation from the translation
// (bundle_adjuster.h uses the matches as epipolar constraints; calibration_monitor.h measures
// the misalignment with them).
//
// Matching (matchStereoScene): FAST corners on the raw left image, the strongest per grid cell
// so that they cover the image; pyramidal Lucas-Kanade into the raw right image, started where
// a point at infinity would be with the given calibration (so the search only covers the
// disparity); then back from right to left, and a match whose way back misses its start by
// more than lk_max_backward_error_px is dropped (the left-right consistency check). The
// calibration only guides the search: the matches are raw pixels and do not depend on it.
//
// Threading: matchStereoScene is reentrant; a SceneMatchBuffers belongs to one caller.
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"
#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo::core {

struct SceneMatchOptions {
  int max_features = 200;            // FAST corners kept (strongest per grid cell)
  int fast_threshold = 8;
  int grid_cols = 8, grid_rows = 5;  // bucketing of the features over the left image
  int lk_window_px = 13;
  int lk_levels = 3;
  double lk_max_backward_error_px = 0.3;
  // Empty when usable, otherwise what is wrong (names the field).
  std::string validate() const;  // problem().text()
  ConfigProblem problem() const;
};

// Image pyramids kept from call to call (no allocation per frame).
struct SceneMatchBuffers {
  std::vector<cv::Mat> pyramid_left, pyramid_right;
};

// The matches of one stereo frame. `left`, `right`: 8-bit grey (CV_8UC1) of the rig's image
// size. `features_found` (optional): how many features were tried. Throws
// std::invalid_argument for images of another type or size, or options that fail validate().
std::vector<SceneMatch> matchStereoScene(const cv::Mat& left, const cv::Mat& right, const StereoRig& rig,
                                         const SceneMatchOptions& options, SceneMatchBuffers* buffers = nullptr,
                                         int* features_found = nullptr);

}  // namespace embedded_calibration_stereo::core
