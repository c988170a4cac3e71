#include "embedded_calibration_stereo/ros/calibration_health_io.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include <boost/make_shared.hpp>
#include <sensor_msgs/SetCameraInfo.h>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/service_call.h"

namespace embedded_calibration_stereo {

namespace {

void loadMonitorParams(const ParameterReader& read, core::CalibrationMonitorOptions* monitor) {
  core::CalibrationMonitorOptions& m = *monitor;
  m.rectification.alpha = read.get("rectification_alpha", m.rectification.alpha);
  if (!(m.rectification.alpha == -1.0 || (m.rectification.alpha >= 0.0 && m.rectification.alpha <= 1.0)))
    throw core::ConfigError("rectification_alpha", "must be in [0, 1], or -1 for OpenCV's default scaling");
  m.misalignment_degraded_px = read.atLeast("misalignment_degraded_px", m.misalignment_degraded_px, 0.0);
  m.misalignment_bad_px = read.atLeast("misalignment_bad_px", m.misalignment_bad_px, m.misalignment_degraded_px);
  m.disparity_bias_degraded_px = read.atLeast("disparity_bias_degraded_px", m.disparity_bias_degraded_px, 0.0);
  m.disparity_bias_bad_px =
      read.atLeast("disparity_bias_bad_px", m.disparity_bias_bad_px, m.disparity_bias_degraded_px);
  m.board_residual_degraded_px = read.atLeast("board_residual_degraded_px", m.board_residual_degraded_px, 0.0);
  m.board_residual_bad_px =
      read.atLeast("board_residual_bad_px", m.board_residual_bad_px, m.board_residual_degraded_px);
  m.hysteresis = read.inRange("hysteresis", m.hysteresis, 0.0, 0.99);
  m.smoothing_time_s = read.atLeast("smoothing_time_s", m.smoothing_time_s, 0.0);
  m.max_depth_age_s = read.atLeast("max_depth_age_s", m.max_depth_age_s, 0.0);
  m.max_verification_age_s = read.atLeast("max_verification_age_s", m.max_verification_age_s, 0.0);
  m.depth_frame_stride = 1;  // depth_rate_hz picks the frames before the images are converted
  core::throwIfProblem(m.problem());
}

}  // namespace

void HealthFrameRecords::addFrame(const Frame& frame) {
  frames_.push_back(frame);
  if (frames_.size() > kept_) frames_.pop_front();
}

void HealthFrameRecords::addCameraInfo(bool left, const sensor_msgs::CameraInfoConstPtr& info) {
  std::deque<sensor_msgs::CameraInfoConstPtr>& infos = left ? left_infos_ : right_infos_;
  infos.push_back(info);
  if (infos.size() > kept_) infos.pop_front();
}

const HealthFrameRecords::Frame* HealthFrameRecords::frame(const ros::Time& stamp) const {
  for (auto it = frames_.rbegin(); it != frames_.rend(); ++it)
    if (it->stamp == stamp) return &*it;
  return nullptr;
}

sensor_msgs::CameraInfoConstPtr HealthFrameRecords::cameraInfo(bool left, const ros::Time& stamp) const {
  const std::deque<sensor_msgs::CameraInfoConstPtr>& infos = left ? left_infos_ : right_infos_;
  for (auto it = infos.rbegin(); it != infos.rend(); ++it)
    if ((*it)->header.stamp == stamp) return *it;
  return nullptr;
}

HealthParams loadHealthParams(const ros::NodeHandle& pnh, const std::string& default_device_config) {
  const ParameterReader read(pnh);
  HealthParams p;
  p.device_config = read.get("device_config", default_device_config);
  if (p.device_config.empty()) throw core::ConfigError("device_config", "missing");
  core::CalibrationHealthPolicyOptions& policy = p.policy;
  policy.boards_posed = read.get("boards_posed", policy.boards_posed);
  policy.solve_boards_wait_s = read.inRange("solve_boards_wait_s", policy.solve_boards_wait_s, 0.0, 60.0);
  policy.refine_predicted_px = read.atLeast("refine_predicted_px", policy.refine_predicted_px, 0.0);
  policy.max_refinements = read.inRange("max_refinements", policy.max_refinements, 0, 10);
  // A launch file written for the frame-counting stride is refused, not silently measured at 15 Hz.
  if (read.has("depth_every_n_frames"))
    throw core::ConfigError("depth_every_n_frames", "replaced by depth_rate_hz (measurements a second, at any frame rate)");
  p.depth_rate_hz = read.inRange("depth_rate_hz", p.depth_rate_hz, 0.0, 1000.0);
  p.queue_size = read.atLeast("queue_size", p.queue_size, 1);
  policy.rollback = read.get("rollback", policy.rollback);
  p.service_timeout_s = read.inRange("service_timeout_s", p.service_timeout_s, 0.1, 60.0);
  loadMonitorParams(read, &p.monitor);
  policy.misalignment_degraded_px = p.monitor.misalignment_degraded_px;
  policy.disparity_bias_degraded_px = p.monitor.disparity_bias_degraded_px;
  policy.board_residual_degraded_px = p.monitor.board_residual_degraded_px;
  p.coverage.collapse_ratio = read.inRange("coverage_collapse_ratio", p.coverage.collapse_ratio, 0.01, 0.99);
  p.coverage.history_s = read.inRange("coverage_history_s", p.coverage.history_s, 10.0, 3600.0);
  p.coverage.min_history_s = std::min(p.coverage.min_history_s, p.coverage.history_s);
  const core::DeviceDescription device = core::loadDeviceDescription(p.device_config, "device_config");
  p.boards = device.device.virtualBoards();
  p.nominal = device.nominal;
  return p;
}

CalibrationHealthPtr toHealthMsg(const core::HealthReport& report, uint32_t epoch, const ros::Time& stamp) {
  auto msg = boost::make_shared<CalibrationHealth>();
  msg->header.stamp = stamp;
  msg->epoch = epoch;
  switch (report.state) {
    case core::CalibrationHealth::kGood:
      msg->state = CalibrationHealth::GOOD;
      break;
    case core::CalibrationHealth::kDegraded:
      msg->state = CalibrationHealth::DEGRADED;
      break;
    case core::CalibrationHealth::kBad:
      msg->state = CalibrationHealth::BAD;
      break;
    default:
      msg->state = CalibrationHealth::UNKNOWN;
  }
  constexpr double nan = std::numeric_limits<double>::quiet_NaN();
  const bool depth = report.epipolar_age_s >= 0.0, boards = report.board_age_s >= 0.0;
  msg->misalignment_px = depth ? report.misalignment_px : nan;
  msg->misalignment_sd_px = depth ? report.misalignment_sd_px : nan;
  msg->board_rms_left_px = boards ? report.board_rms_left_px : nan;
  msg->board_rms_right_px = boards ? report.board_rms_right_px : nan;
  msg->stereo_consistency_px = boards ? report.stereo_consistency_px : nan;
  for (size_t i = 0; i < 4; ++i) {
    msg->predicted_depths_m[i] = core::kHealthDepthsM[i];
    msg->predicted_depth_error_pct[i] = report.predicted_depth_error_pct[i];
  }
  msg->misalignment_age_s = report.epipolar_age_s;
  msg->verification_age_s = report.board_age_s;
  return msg;
}

void fillHealthDiagnostics(const core::HealthReport& report, const core::CalibrationHealthDecisions& policy,
                           const std::string& reason, const HealthDiagnostics& extra,
                           diagnostic_updater::DiagnosticStatusWrapper* status) {
  using diagnostic_msgs::DiagnosticStatus;
  if (!policy.problem().empty()) {
    status->summary(DiagnosticStatus::ERROR, policy.problem());
  } else if (policy.restoreFailed()) {
    status->summary(DiagnosticStatus::ERROR, policy.lastRestore());
  } else {
    const int8_t level = report.state == core::CalibrationHealth::kGood  ? DiagnosticStatus::OK
                         : report.state == core::CalibrationHealth::kBad ? DiagnosticStatus::ERROR
                                                                        : DiagnosticStatus::WARN;
    const std::string head =
        report.state == core::CalibrationHealth::kUnknown ? "no verdict yet" : core::toString(report.state);
    status->summary(level, reason.empty() ? head : head + ": " + reason);
  }
  status->add("state", core::toString(report.state));
  status->add("calibration epoch", policy.epoch().value_or(0));
  status->add("boards verified against", extra.boards_source);
  status->add("misalignment (px)", report.misalignment_px);
  status->add("misalignment sd (px)", report.misalignment_sd_px);
  status->add("board rms left (px)", report.board_rms_left_px);
  status->add("board rms right (px)", report.board_rms_right_px);
  status->add("stereo consistency (px)", report.stereo_consistency_px);
  for (size_t i = 0; i < 4; ++i) {
    char key[64];
    std::snprintf(key, sizeof(key), "predicted depth error at %.0f m (%%)", core::kHealthDepthsM[i]);
    status->add(key, report.predicted_depth_error_pct[i]);
  }
  status->add("misalignment age (s)", report.epipolar_age_s);
  status->add("verification age (s)", report.board_age_s);
  status->add("frames measured", extra.depth_frames);
  status->add("last measurement (ms)", extra.depth_ms);
  status->add("verifications", extra.verifications);
  status->add("restores", policy.restores());
  status->add("last restore", policy.lastRestore().empty() ? "none" : policy.lastRestore());
}

std::future<std::string> restoreCalibration(
    const ros::NodeHandle& nh, const std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo>& calibration,
    double timeout_s) {
  return std::async(std::launch::async, [nh, pair = calibration, timeout_s]() -> std::string {
    for (const bool left : {true, false}) {
      sensor_msgs::SetCameraInfo srv;
      srv.request.camera_info = left ? pair.first : pair.second;
      std::string error;
      const std::string name = left ? "left/set_camera_info" : "right/set_camera_info";
      if (!callService(nh, name, &srv, timeout_s, &error)) return error;
      if (!srv.response.success) return name + " refused: " + srv.response.status_message;
    }
    return "";
  });
}

CalibrationStatus rolledBackStatus(uint32_t epoch, const std::string& why) {
  CalibrationStatus status;
  status.header.stamp = ros::Time::now();
  status.epoch = epoch;
  status.accepted = false;
  status.outcome = CalibrationStatus::OUTCOME_ROLLED_BACK;
  status.reason = "rolled back: " + why;
  return status;
}

core::CalibratorStatus toCalibratorStatus(const CalibrationStatus& status) {
  core::CalibratorStatus out;
  out.epoch = status.epoch;
  out.accepted = status.accepted;
  out.in_force_confirmed = status.in_force_confirmed;
  out.newest_frame_s = status.newest_frame.toSec();
  out.predicted_misalignment_px = status.predicted_misalignment_rms_px;
  out.predicted_disparity_bias_px = status.predicted_disparity_bias_rms_px;
  return out;
}

std::optional<SolvedBoards> solvedBoards(const CalibrationStatus& status,
                                         const std::vector<core::VirtualBoard>& boards) {
  if (!status.accepted || status.board_ids.empty() || status.board_ids.size() != status.board_poses.size())
    return std::nullopt;
  SolvedBoards solved{status.left_intrinsics, status.right_intrinsics, {}};
  for (core::VirtualBoard board : boards)
    for (size_t i = 0; i < status.board_ids.size(); ++i)
      if (status.board_ids[i] == board.virtual_id) {
        board.rig_from_board = fromPoseMsg(status.board_poses[i]);
        solved.boards.push_back(board);
      }
  return solved;
}

namespace {

// Whether `intrinsics` (fx, fy, cx, cy, then D, as in CalibrationStatus) are those of `info`.
bool sameIntrinsics(const std::vector<double>& intrinsics, const sensor_msgs::CameraInfo& info) {
  const auto near = [](double a, double b) { return std::abs(a - b) <= 1e-6 * std::max(1.0, std::abs(b)); };
  if (intrinsics.size() != 4 + info.D.size()) return false;
  if (!near(intrinsics[0], info.K[0]) || !near(intrinsics[1], info.K[4]) || !near(intrinsics[2], info.K[2]) ||
      !near(intrinsics[3], info.K[5]))
    return false;
  for (size_t i = 0; i < info.D.size(); ++i)
    if (!near(intrinsics[4 + i], info.D[i])) return false;
  return true;
}

}  // namespace

bool solvedWith(const SolvedBoards& solved, const sensor_msgs::CameraInfo& left, const sensor_msgs::CameraInfo& right) {
  return sameIntrinsics(solved.left, left) && sameIntrinsics(solved.right, right);
}

}  // namespace embedded_calibration_stereo
