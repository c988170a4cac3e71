#pragma once
// Calibration health (ROS-free): whether the calibration in force still holds, judged from two
// signals, with a state GOOD / DEGRADED / BAD and the depth error the observed change causes.
//
// Depth mode (addDepthFrame, every frame or every few, light off): sparse scene correspondences
// between the left and right images (FAST corners on the left, pyramidal Lucas-Kanade into the
// right image, forward-backward check), rectified with the calibration in force; a true
// correspondence lies on one rectified row, so its vertical offset is the misalignment. The
// offsets are fitted robustly (Huber) by a rotation of the right camera about its x and z axes
// (the only rotations that move rows), matches outside a band of +-band_half_height_px around
// the epipolar row are dropped, and the fit is smoothed over time (time constant
// smoothing_time_s; the signal counts once it has seen one time constant of frames). Catches
// tilt and roll (knocks, thermal drift about x or z). A rotation about y (pan), a zoom or a
// baseline change moves disparity, not rows: invisible here.
//
// Verification (addVerification, one settled light-on frame every verification_period_s): the
// tracked board corners reprojected with the calibration in force.
//   - board RMS per camera: the corners against the boards at their poses of the calibration
//     (setCalibration's `boards`, fixed to the left camera); without poses, against each board's
//     own PnP pose in that camera (then a common zoom is not seen by this figure).
//   - stereo consistency: each board's pose fitted to the left corners (PnP, left camera in
//     force) predicts the right corners through right_from_left and the right camera; RMS (px).
//   - a fit of the change: right camera rotation (3 angles), right focal scale and, with board
//     poses, left focal scale, to all corners; it catches pan, zoom, principal-point shifts
//     (seen as a rotation) and gives the disparity bias.
// From the fitted change (depth mode's tilt/roll while fresh, verification's pan and zoom) a rig
// "as observed" is built and compared with the calibration in force by evaluateStereoAccuracy
// (stereo_accuracy.h, its definitions): misalignment and disparity bias RMS (px) and the depth
// error RMS (%) at 1, 2, 5 and 10 m, linearised once per calibration (setCalibration).
//
// State: each signal (depth-mode misalignment; the boards' misalignment, disparity bias and the
// corner RMS the fitted change leaves) has a DEGRADED and a BAD threshold; a level is entered
// when the value exceeds its threshold and left only when it falls below threshold *
// (1 - hysteresis). The state is the worst level of the fresh signals; kUnknown until a
// calibration is set and a signal has arrived after it, or when none is fresh. docs/core.md has
// the thresholds in pixels and degrees.
//
// Threading: not thread-safe. One owner thread calls every method (a nodelet serialises its
// image and observation callbacks with a mutex around the monitor).
#include <Eigen/Geometry>
#include <array>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/scene_matches.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"
#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo::core {

struct CalibrationMonitorOptions {
  // Rectification of the product (the calibrator's), used for the depth mode's rows and for the
  // accuracy figures.
  RectificationOptions rectification;

  // --- State thresholds (hysteresis: a level is left below threshold * (1 - hysteresis)).
  // Vertical misalignment RMS over the image (px, rectified), depth mode and verification.
  double misalignment_degraded_px = 0.08;
  double misalignment_bad_px = 1.0;
  // Disparity bias RMS (px) of the change seen by the verification (pan, zoom, baseline).
  double disparity_bias_degraded_px = 0.08;
  double disparity_bias_bad_px = 1.0;
  // Corner RMS the fitted change leaves unexplained (HealthReport::board_residual_px): a
  // distortion change, a bent device, a wrong commit.
  double board_residual_degraded_px = 0.35;
  double board_residual_bad_px = 1.0;
  double hysteresis = 0.3;

  // --- Depth mode.
  // Measure on every n-th depth frame given (the others return at once): at 30 fps and n = 2 the
  // depth mode measures 15 times a second, at half the cost per frame.
  int depth_frame_stride = 2;
  double smoothing_time_s = 0.5;     // exponential smoothing of the fitted tilt/roll
  double band_half_height_px = 3.0;  // matches further from their rectified row are dropped
  SceneMatchOptions matching;  // the scene correspondences (scene_matches.h)
  int min_matches = 30;                   // fewer: the frame gives no measurement
  double huber_px = 0.3;                  // Huber scale of the row-offset fit
  double max_depth_age_s = 2.0;           // older depth measurement: not used for the state

  // --- Verification.
  double verification_period_s = 2.0;  // how often the owner should call addVerification
  int min_board_corners = 12;          // boards with fewer corners per camera are ignored
  int min_corners = 40;                // fewer corners in all: no verification
  double max_verification_age_s = 10.0;  // older: not used for the state

  // Empty when usable, otherwise what is wrong (names the field).
  std::string validate() const;  // problem().text()
  ConfigProblem problem() const;
};

enum class CalibrationHealth { kUnknown, kGood, kDegraded, kBad };
// "UNKNOWN", "GOOD", "DEGRADED", "BAD".
const char* toString(CalibrationHealth health);

// Depths of HealthReport::predicted_depth_error_pct.
constexpr std::array<double, 4> kHealthDepthsM{{1.0, 2.0, 5.0, 10.0}};

struct HealthReport {
  CalibrationHealth state = CalibrationHealth::kUnknown;
  int epoch = 0;  // of the calibration in force (setCalibration)
  // Depth mode: vertical misalignment RMS over the image (px) and its standard deviation.
  double misalignment_px = 0.0, misalignment_sd_px = 0.0;
  int matches = 0;  // correspondences used by the last depth measurement
  // Verification: corner RMS per camera, stereo consistency (px), and the change it saw.
  double board_rms_left_px = 0.0, board_rms_right_px = 0.0, stereo_consistency_px = 0.0;
  double disparity_bias_px = 0.0;  // RMS over the accuracy samples, from the fitted change
  // RMS (px, both cameras) of the corners the fitted change leaves unexplained: a distortion
  // change, a bent device, a commit that is wrong in a way no rotation or zoom explains.
  double board_residual_px = 0.0;
  Eigen::Vector3d right_rotation_deg = Eigen::Vector3d::Zero();  // fitted: x, z from depth mode
  double left_focal_scale = 1.0, right_focal_scale = 1.0;      // fitted (left: with board poses)
  // Depth error RMS (%) at kHealthDepthsM, from the observed change.
  std::array<double, 4> predicted_depth_error_pct{{0, 0, 0, 0}};
  // Seconds since each signal's last measurement (at the latest time given to the monitor);
  // negative when there is none since the calibration was set.
  double epipolar_age_s = -1.0, board_age_s = -1.0;
  std::string reason;  // why the state is what it is, for users
};

class CalibrationMonitor {
 public:
  // Throws std::invalid_argument when options.validate() fails.
  explicit CalibrationMonitor(CalibrationMonitorOptions options);
  ~CalibrationMonitor();
  CalibrationMonitor(CalibrationMonitor&&) noexcept;
  CalibrationMonitor& operator=(CalibrationMonitor&&) noexcept;

  // The calibration in force (raw camera models + extrinsics) and its epoch; resets every
  // signal and the state to kUnknown. `boards`: the virtual boards with their rig_from_board
  // as the calibration estimated them (BundleAdjustmentSummary::rig_from_board), or with only
  // their layout (ids, cols, rows, square, mirrored) and boards_posed = false. Throws
  // std::invalid_argument for an invalid rig (or one that cannot be rectified).
  void setCalibration(const StereoRig& rig, int epoch, const std::vector<VirtualBoard>& boards,
                      bool boards_posed);
  bool hasCalibration() const;

  // One light-off stereo pair (raw images of the calibration's size, CV_8UC1 or CV_8UC3) at time
  // t (s). Returns false when it gave no measurement: skipped (depth_frame_stride) or too few
  // matches (see report().reason).
  bool addDepthFrame(double t, const cv::Mat& left_raw, const cv::Mat& right_raw);

  // One settled light-on frame's tracked corners (PatternTracker::trackStereo). Returns false
  // when it gave no verification (too few corners).
  bool addVerification(double t, const StereoObservation& observation);

  // The state and figures as of the latest time given.
  HealthReport report() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace embedded_calibration_stereo::core
