#pragma once
// The CalibrationHealth nodelet's ROS glue that decides nothing: its parameters, the
// calibration/health message and the diagnostics built from a verdict, and the boards of a
// calibrator's status. Decisions: core/calibration/calibration_health_policy.h.
// Parameters, message and diagnostics: docs/nodelets.md, "CalibrationHealth".
//
// Threading: free functions without shared state; restoreCalibration calls the services on a
// std::async thread that shares only its future.
#include <cstdint>
#include <deque>
#include <future>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <diagnostic_updater/DiagnosticStatusWrapper.h>
#include <ros/node_handle.h>
#include <sensor_msgs/CameraInfo.h>

#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/core/calibration/calibration_health_policy.h"
#include "embedded_calibration_stereo/core/calibration/calibration_monitor.h"
#include "embedded_calibration_stereo/core/calibration/depth_coverage_watch.h"
#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo {

struct HealthParams {
  std::string device_config;
  std::vector<core::VirtualBoard> boards;  // device_config's
  std::optional<core::StereoRig> nominal;  // device_config's cameras, if it has them
  // rollback, boards_posed (true: the boards sit at their poses, as the solve of the calibration
  // in force placed them or where device_config puts them for a calibration no solve here made;
  // false: each board's pose is fitted in each frame), solve_boards_wait_s, refine_predicted_px
  // (a commit predicted no better than a degraded calibration wants more bursts, which light
  // frames while GOOD), max_refinements; the DEGRADED thresholds are copied from `monitor`.
  core::CalibrationHealthPolicyOptions policy;
  // Depth-mode measurements a second, whatever the frame rate (core::MeasurementRate); 0: every
  // settled light-off frame. Picked here; the monitor's own stride is 1.
  double depth_rate_hz = 15.0;
  int queue_size = 5;
  double service_timeout_s = 2.0;
  core::CalibrationMonitorOptions monitor;
  core::DepthCoverageWatchOptions coverage;  // disparity_coverage of light-off frames
};

// The latest frames by stamp: each one's light and epoch (calibration_mode) and calibrations
// (left and right camera_info), `kept` of each.
class HealthFrameRecords {
 public:
  struct Frame {
    ros::Time stamp;
    uint32_t epoch;
    bool lit;   // light on and settled
    bool dark;  // light off and settled
  };
  explicit HealthFrameRecords(size_t kept) : kept_(kept) {}
  void addFrame(const Frame& frame);
  void addCameraInfo(bool left, const sensor_msgs::CameraInfoConstPtr& info);
  // The newest frame of `stamp`, or null.
  const Frame* frame(const ros::Time& stamp) const;
  // The newest camera_info of `stamp`, or null.
  sensor_msgs::CameraInfoConstPtr cameraInfo(bool left, const ros::Time& stamp) const;

 private:
  size_t kept_;
  std::deque<Frame> frames_;
  std::deque<sensor_msgs::CameraInfoConstPtr> left_infos_, right_infos_;
};

// Every parameter, read and checked once at start, then device_config read; throws ConfigError.
HealthParams loadHealthParams(const ros::NodeHandle& pnh, const std::string& default_device_config);

// A verdict as published on calibration/health (its reason and calibration_wanted aside):
// figures of signals not measured are NaN.
CalibrationHealthPtr toHealthMsg(const core::HealthReport& report, uint32_t epoch, const ros::Time& stamp);

// What the diagnostics show besides the report and the policy's state.
struct HealthDiagnostics {
  std::string boards_source;  // "its solve", "device_config", or "waiting for its solve's"
  uint64_t depth_frames = 0, verifications = 0;
  double depth_ms = 0.0;
};
// OK when GOOD, WARN when DEGRADED or without a verdict, ERROR when BAD, when the calibration in
// force cannot be used or a restore failed; then the figures. `reason`: the policy's.
void fillHealthDiagnostics(const core::HealthReport& report, const core::CalibrationHealthDecisions& policy,
                           const std::string& reason, const HealthDiagnostics& extra,
                           diagnostic_updater::DiagnosticStatusWrapper* status);

// Sends `calibration` back to the driver's left|right/set_camera_info on a thread of its own
// (each call bounded by timeout_s); the future gives "" or why it failed.
std::future<std::string> restoreCalibration(
    const ros::NodeHandle& nh, const std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo>& calibration,
    double timeout_s);
// The calibration/status that says the calibration of `epoch` was rolled back, and why.
CalibrationStatus rolledBackStatus(uint32_t epoch, const std::string& why);

// The parts of a calibrator's status the policy decides on.
core::CalibratorStatus toCalibratorStatus(const CalibrationStatus& status);

// Board poses of an accepted solve, with the intrinsics it was solved with.
struct SolvedBoards {
  std::vector<double> left, right;  // as CalibrationStatus: fx, fy, cx, cy, D
  std::vector<core::VirtualBoard> boards;
};
// An accepted status's boards (`boards` placed at its poses), or none when it places none.
std::optional<SolvedBoards> solvedBoards(const CalibrationStatus& status, const std::vector<core::VirtualBoard>& boards);
// Whether `solved` was solved with the intrinsics of `left` and `right`.
bool solvedWith(const SolvedBoards& solved, const sensor_msgs::CameraInfo& left, const sensor_msgs::CameraInfo& right);

}  // namespace embedded_calibration_stereo
