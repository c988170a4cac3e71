#pragma once
// The ROS side of one calibration solve for the OnlineCalibrator nodelet: parameters, checking
// incoming observation messages, solve + quality gate against the calibration in force, and the
// commit (left|right/set_camera_info of the driver, then the left->right transform on
// /tf_static; or, with commit "none" for a bag replay without driver, the transform only).
// The nodelet keeps the threads, topics and windows; this file keeps the logic.
#include <ros/ros.h>

#include <mutex>
#include <sensor_msgs/CameraInfo.h>
#include <tf2_ros/static_transform_broadcaster.h>

#include <optional>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/calibration/calibration_filter.h"
#include "embedded_calibration_stereo/core/calibration/calibration_outcome.h"
#include "embedded_calibration_stereo/core/calibration/paced_queue.h"
#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/calibration/quality_gate.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"

namespace embedded_calibration_stereo {

// Where an accepted calibration goes.
enum class CommitTarget {
  kDriver,  // the driver's left|right/set_camera_info, then /tf_static
  kNone,    // nowhere but /tf_static (bag replay: the camera_info comes from the bag)
};

// Reads "driver" | "none"; throws core::ConfigError otherwise.
CommitTarget parseCommitTarget(const std::string& name);

// status.reason of a calibration accepted by the gate but, with commit "none", committed nowhere.
constexpr const char* kAcceptedNotCommittedReason = "accepted (commit: none): gate passed, not committed to a driver";
// Start of status.reason when a solve fits no better than the calibration in force (the gate keeps
// it): nothing needs changing, which a recalibration request answers as a success.
constexpr const char* kInForceConfirmedReason = "calibration in force confirmed";

struct CalibratorParams {
  std::string device_config;  // sim_rig.yaml format: the `device` node
  std::string left_frame_id = "stereo_left_optical_frame";
  std::string right_frame_id = "stereo_right_optical_frame";
  bool auto_calibrate = true;  // solve at the end of every light-on window of the driver
  // The automatic windows are the tracker's calibration/window_observations (one per light
  // burst, solved as it comes) instead of the per-frame observations of each light-on window.
  bool window_observations = false;
  int min_frames = 5;          // a light-on window with fewer frames is not solved
  int max_frames = 30;         // frames kept per window (the first ones)
  double service_timeout_s = 2.0;  // for each set_light / set_camera_info call: to appear, then to answer (wall)
  double max_request_timeout_s = 60.0;  // recalibrate's timeout_s is limited to it
  double window_timeout_s = 5.0;   // an automatic window with no settled frame added for this long ends (wall)
  double stamp_tolerance_s = 2.0;  // inputs stamped further from the others are dropped (stamp_guard.h)
  double commit_retry_s = 10.0;    // s between commits again of a calibration the driver could not store; 0: never
  // Automatic solves (windows, window observations): min_solve_interval_s apart at the least,
  // solve_queue_size waiting at most (the oldest dropped): paced_queue.h.
  core::PacedQueueOptions solve_pacing;
  CommitTarget commit = CommitTarget::kDriver;
  // cv::stereoRectify's alpha for the committed CameraInfo R and P: 0 every rectified pixel
  // valid, 1 every raw pixel kept, -1 OpenCV's default scaling.
  double rectification_alpha = 0.0;
  core::BundleAdjustmentOptions adjustment;
  core::BundleAdjustmentConfig terms;  // which distortion terms are estimated (k1 k2 by default)
  core::GateOptions gate;
  // Each window solved again with what the earlier ones taught as the prior of the parameter
  // groups it does not contradict (calibration_filter.h).
  bool prior_from_earlier_windows = true;
  core::CalibrationFilterOptions filter;
};

// Reads the private parameters; throws core::ConfigError naming a bad one.
CalibratorParams loadCalibratorParams(const ros::NodeHandle& pnh, const std::string& default_device_config);

// A recalibrate request within the calibrator's limits: `frames` (0: min_frames) at most
// max_frames, `timeout_s` (<= 0: kDefaultRequestTimeoutS) at most max_request_timeout_s. A
// non-finite timeout_s is refused (`refusal` says why: nothing may be done). `note` says what
// was limited ("" when nothing was).
struct BoundedRequest {
  std::string refusal;
  size_t frames = 0;
  double timeout_s = 0.0;
  std::string note;
};
constexpr double kDefaultRequestTimeoutS = 10.0;
BoundedRequest boundRecalibrateRequest(uint32_t frames, double timeout_s, const CalibratorParams& params);

// The defects of one observation message that make the calibrator drop it (non-finite
// coordinates, duplicate ids, ids outside the board, unknown board, mismatched lengths), from
// the core validator; a board with merely few corners is not a defect. Empty when usable.
std::vector<std::string> observationDefects(const core::StereoObservation& observation,
                                            const std::vector<core::VirtualBoard>& boards);

// CalibrationStatus of a solve (every field filled; intrinsics fx, fy, cx, cy, k1, k2, p1, p2, k3).
// Its outcome is the gate's (accepted: kCommitted, what a commit then makes of it is the caller's).
// The predicted accuracy for depth is that of the rig rectified with `rectification` (the
// committed CameraInfo's), from the solve's covariance; zero without one.
CalibrationStatus makeStatus(const core::BundleAdjustmentSummary& summary, const core::GateDecision& decision,
                             const core::RectificationOptions& rectification = {});

// Sets status.outcome to `outcome`, and accepted and in_force_confirmed as they follow from it.
void setOutcome(CalibrationStatus* status, core::CalibrationOutcome outcome);

// The status of a request or job that ended without a solve (`outcome`: why, as a value).
CalibrationStatus statusWithoutSolve(const std::string& reason, uint32_t epoch,
                                     core::CalibrationOutcome outcome = core::CalibrationOutcome::kNotSolved);

// The calibration/recalibrate answer's message for a solve's `status`: "committed", or its reason.
std::string recalibrateMessage(const CalibrationStatus& status);

// The pair a successful commit sent to the driver's set_camera_info services.
struct CommittedCalibration {
  sensor_msgs::CameraInfo left, right;
};

// True when `published` (a camera_info of the driver) carries the calibration `committed`: same
// image size and distortion model, and D, K, R, P equal to 1e-6 (relative above 1; a driver may
// store the calibration as text and read it back). Header, binning and ROI are not compared.
bool carriesCalibration(const sensor_msgs::CameraInfo& published, const sensor_msgs::CameraInfo& committed);

// An accepted calibration the driver did not store (its set_camera_info failed): what
// CalibrationSession::commitAgain() needs to try again.
struct UncommittedCalibration {
  CommittedCalibration infos;
  core::StereoRig rig;
  // The calibration in force it was gated against (the left one is put back when only the right
  // side is refused): committed again only while the driver still publishes these.
  sensor_msgs::CameraInfo left_in_force, right_in_force;
  CalibrationStatus status;  // the solve's status (accepted false, reason "not committed: ...")
  double predicted_px = 0.0;  // its predicted hypot(misalignment, disparity bias) (QualityGate::predictedPx)
};

// What CalibrationSession::solve() solves.
struct SolveRequest {
  std::vector<core::StereoObservation> frames;  // the window
  // The calibration in force (null when none received yet) and its calibration_epoch.
  sensor_msgs::CameraInfoConstPtr left_info, right_info;
  uint32_t epoch = 0;
  bool dry_run = false;  // solve and gate only: nothing committed, nothing learned
  // The stamp (s) of the newest calibration/health verdict below GOOD, if any: when it is not
  // older than what earlier windows taught, the stereo rotation and the focal lengths (what the
  // health's change model sees) get no prior from them.
  std::optional<double> health_problem_s;
};

// What became of it.
struct SolveResult {
  // status.outcome says what became of the solve; status.epoch is always the request's.
  CalibrationStatus status;
  // After a commit: the pair sent to the driver; the caller reads the epoch the driver put in
  // force from the driver's frames (see carriesCalibration).
  std::optional<CommittedCalibration> committed;
  // After a failed commit: what commitAgain() needs.
  std::optional<UncommittedCalibration> uncommitted;
};

// Solve, gate and commit. Threading: solve() runs on the calibrator's worker thread only (it
// blocks on service calls and on the solver); broadcastTransform() may also be called from a
// subscriber callback (the calibration in force at start-up), so the broadcaster is guarded.
class CalibrationSession {
 public:
  // `nh`: the head's namespace (the driver's services are looked up there). `nominal`: the
  // device description's cameras; a solve whose focal lengths lie far from theirs
  // (checkNominalFocal) is not committed. None: no such check.
  CalibrationSession(ros::NodeHandle nh, CalibratorParams params, core::CalibrationDevice device,
                     std::optional<core::StereoRig> nominal = std::nullopt);

  // Solves the request's window, gates it against the calibration in force and commits it unless
  // a dry run or rejected. status.accepted is true only for a committed (or, in a dry run, an
  // acceptable) calibration; a failed set_camera_info leaves accepted false with the reason
  // "not committed: ..." (the next window solves again against the unchanged calibration in
  // force: the retry). With commit "none" an acceptable calibration is published on /tf_static
  // only: status.accepted is true, its reason kAcceptedNotCommittedReason and its epoch the
  // request's (still in force: nothing was committed).
  SolveResult solve(const SolveRequest& request);

  // Commits `calibration` again (worker thread). Empty on success, otherwise why not.
  std::string commitAgain(const UncommittedCalibration& calibration);

  // The left->right optical transform of `rig` on /tf_static (also sent at every commit).
  void broadcastTransform(const core::StereoRig& rig);

  const core::CalibrationDevice& device() const { return device_; }
  // What the last solve took from earlier windows, in words ("" when nothing): for the log.
  const std::string& priorNote() const { return prior_note_; }
  const std::vector<core::VirtualBoard>& boards() const { return boards_; }

 private:
  // Why a pair fails the checks every consumer runs (stereo_input_check.h) or lies far from the
  // nominal cameras, or "".
  std::string implausibleCandidate(const CommittedCalibration& infos) const;
  core::BundleAdjustmentSummary solveWindow(const std::vector<core::StereoObservation>& frames,
                                           const sensor_msgs::CameraInfo& left_info, const core::StereoRig* in_force,
                                           std::optional<double> health_problem_s);
  CalibrationStatus statusOf(const core::BundleAdjustmentSummary& candidate, const core::GateDecision& decision,
                             const core::BundleAdjustmentSummary& in_force_fit, uint32_t epoch,
                             const std::vector<core::StereoObservation>& frames) const;
  void commitAccepted(const core::BundleAdjustmentSummary& candidate, bool learned,
                      const sensor_msgs::CameraInfo& left_info, const sensor_msgs::CameraInfo& right_info,
                      SolveResult* result);
  // Empty on success, otherwise why the commit failed. When only the right one was refused, a
  // left calibration the driver stored (a driver without pairs) is restored to `left_in_force`;
  // our driver only staged it ("staged: ..." answer) and has already dropped it.
  std::string commit(const CommittedCalibration& infos, const core::StereoRig& rig,
                     const sensor_msgs::CameraInfo& left_in_force);
  // *answer (optional): the driver's status message of an accepted call.
  bool callSetCameraInfo(const std::string& side, const sensor_msgs::CameraInfo& info, std::string* error,
                         std::string* answer = nullptr);

  ros::NodeHandle nh_;
  CalibratorParams params_;
  core::CalibrationDevice device_;
  std::optional<core::StereoRig> nominal_;
  std::vector<core::VirtualBoard> boards_;
  core::BundleAdjuster adjuster_;
  core::QualityGate gate_;
  // What earlier windows taught, valid while the calibration in force is the one it was
  // learned under (filter_in_force_: left, right; another one, a rollback or a calibration set
  // from outside, resets it). Touched by solve() and commitAgain() only: the worker thread.
  core::CalibrationFilter filter_;
  std::optional<std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo>> filter_in_force_;
  std::optional<double> in_force_predicted_px_;  // our calibration in force's predicted hypot(misalignment, bias)
  std::string prior_note_;
  std::mutex tf_mutex_;  // guards tf_broadcaster_
  tf2_ros::StaticTransformBroadcaster tf_broadcaster_;
};

}  // namespace embedded_calibration_stereo
