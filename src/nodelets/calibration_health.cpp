// CalibrationHealth nodelet: says at every frame whether the calibration in force still holds
// (core CalibrationMonitor) and restores the previous calibration when a new one does not.
//  - Depth mode: every depth_every_n_frames-th settled light-off stereo frame (left|right/
//    image_raw with their camera_info and calibration_mode, ExactTime) goes to the monitor,
//    which measures the vertical misalignment of scene correspondences rectified with the
//    frame's calibration.
//  - Verification: the tracker's board observations (calibration/observations) of settled
//    light-on frames taken with the calibration in force: the driver's verification flashes
//    (verification_period_s) and its calibration bursts alike.
// Each frame's light, epoch and calibration come from calibration_mode and camera_info on their
// own subscriptions, so that a frame the image synchroniser drops hides neither. A calibration_mode
// counts (in the synchroniser and in the records) only for a frame whose left camera_info came,
// once per stamp (frame_stamp_gate.h): rogue modes neither fill the queue nor fake a light.
// It publishes calibration/health (CalibrationHealth) at every new calibration and after every
// measurement, and the state on diagnostics (GOOD OK, DEGRADED WARN, BAD ERROR, no verdict yet
// WARN). calibration_wanted tells an on-demand driver to calibrate: BAD, or DEGRADED until the
// calibrator confirms the calibration in force as the best it can do (calibration/status) and
// again once a signal doubles since.
// A new calibration (a new calibration_epoch) resets the monitor. Its verification places the
// boards where the calibrator's solve that made it placed them (its calibration/status, matched
// by the intrinsics; it may follow the driver's first frames: the first verification waits for
// it up to solve_boards_wait_s), or where device_config puts them for any other calibration. A
// solve's cameras and board poses explain the boards together: against the nominal device, the
// small errors a solve has in either look like a turn or a zoom of several times their effect on
// depth. The first verification of a new calibration must find it GOOD; when it does not and the
// newest calibration verified before it was doing better (GOOD, or a better state), that pair is
// sent back to the driver's left|right/set_camera_info (rollback true; never a pair that was
// replaced before its first verdict: rollback_policy.h), and calibration/health,
// calibration/status and the diagnostics say why.
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <message_filters/subscriber.h>
#include <message_filters/sync_policies/exact_time.h>
#include <message_filters/synchronizer.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/package.h>
#include <ros/ros.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <future>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>

#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/VerifiedCalibration.h"
#include "embedded_calibration_stereo/DisparityCoverage.h"
#include "embedded_calibration_stereo/core/calibration/calibration_monitor.h"
#include "embedded_calibration_stereo/core/calibration/depth_coverage_watch.h"
#include "embedded_calibration_stereo/core/calibration/rollback_policy.h"
#include "embedded_calibration_stereo/core/geometry/config_error.h"
#include "embedded_calibration_stereo/core/geometry/config_io.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/frame_stamp_gate.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/lazy_synced_input.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/service_call.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

namespace {

using sensor_msgs::CameraInfo;
using sensor_msgs::CameraInfoConstPtr;
using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

struct HealthParams {
  std::string device_config;
  // true: the boards sit at their poses (verification against them: a common zoom is seen), as
  // the solve of the calibration in force placed them (calibration/status), or where
  // device_config puts them for a calibration no solve here made; false: each board's pose is
  // fitted in each frame.
  bool boards_posed = true;
  // A new calibration waits this long (wall) for its solve's board poses before it is verified
  // against device_config's; 0: never waits.
  double solve_boards_wait_s = 2.0;
  // A calibration the calibrator committed with a predicted misalignment or disparity bias
  // (calibration/status) above this asks for more bursts, at most max_refinements in a row, so
  // that it can refine it with what they add; 0: never. The default is the DEGRADED thresholds':
  // a calibration predicted no better than a degraded one. Such bursts light frames while GOOD.
  double refine_predicted_px = 0.08;
  int max_refinements = 2;
  int depth_every_n_frames = 2;  // measured here; the monitor's own stride is 1
  int queue_size = 5;
  bool rollback = true;
  double service_timeout_s = 2.0;
  ecs::CalibrationMonitorOptions monitor;
  ecs::DepthCoverageWatchOptions coverage;  // disparity_coverage of light-off frames
};

// Every parameter is read and checked here, once, at start.
HealthParams loadParams(const ros::NodeHandle& pnh, const std::string& default_device_config) {
  const ParameterReader read(pnh);
  HealthParams p;
  p.device_config = read.get("device_config", default_device_config);
  if (p.device_config.empty()) throw ecs::ConfigError("device_config", "missing");
  p.boards_posed = read.get("boards_posed", p.boards_posed);
  p.solve_boards_wait_s = read.inRange("solve_boards_wait_s", p.solve_boards_wait_s, 0.0, 60.0);
  p.refine_predicted_px = read.atLeast("refine_predicted_px", p.refine_predicted_px, 0.0);
  p.max_refinements = read.inRange("max_refinements", p.max_refinements, 0, 10);
  p.depth_every_n_frames = read.atLeast("depth_every_n_frames", p.depth_every_n_frames, 1);
  p.queue_size = read.atLeast("queue_size", p.queue_size, 1);
  p.rollback = read.get("rollback", p.rollback);
  p.service_timeout_s = read.inRange("service_timeout_s", p.service_timeout_s, 0.1, 60.0);
  ecs::CalibrationMonitorOptions& m = p.monitor;
  m.rectification.alpha = read.get("rectification_alpha", m.rectification.alpha);
  if (!(m.rectification.alpha == -1.0 || (m.rectification.alpha >= 0.0 && m.rectification.alpha <= 1.0)))
    throw ecs::ConfigError("rectification_alpha", "must be in [0, 1], or -1 for OpenCV's default scaling");
  m.misalignment_degraded_px = read.atLeast("misalignment_degraded_px", m.misalignment_degraded_px, 0.0);
  m.misalignment_bad_px = read.atLeast("misalignment_bad_px", m.misalignment_bad_px, m.misalignment_degraded_px);
  m.disparity_bias_degraded_px = read.atLeast("disparity_bias_degraded_px", m.disparity_bias_degraded_px, 0.0);
  m.disparity_bias_bad_px =
      read.atLeast("disparity_bias_bad_px", m.disparity_bias_bad_px, m.disparity_bias_degraded_px);
  m.board_residual_degraded_px = read.atLeast("board_residual_degraded_px", m.board_residual_degraded_px, 0.0);
  m.board_residual_bad_px = read.atLeast("board_residual_bad_px", m.board_residual_bad_px, m.board_residual_degraded_px);
  m.hysteresis = read.inRange("hysteresis", m.hysteresis, 0.0, 0.99);
  m.smoothing_time_s = read.atLeast("smoothing_time_s", m.smoothing_time_s, 0.0);
  m.max_depth_age_s = read.atLeast("max_depth_age_s", m.max_depth_age_s, 0.0);
  m.max_verification_age_s = read.atLeast("max_verification_age_s", m.max_verification_age_s, 0.0);
  m.depth_frame_stride = 1;  // depth_every_n_frames strides before the images are converted
  ecs::throwIfProblem(m.problem());
  p.coverage.collapse_ratio = read.inRange("coverage_collapse_ratio", p.coverage.collapse_ratio, 0.01, 0.99);
  p.coverage.history_s = read.inRange("coverage_history_s", p.coverage.history_s, 10.0, 3600.0);
  p.coverage.min_history_s = std::min(p.coverage.min_history_s, p.coverage.history_s);
  return p;
}

uint8_t toMsgState(ecs::CalibrationHealth state) {
  switch (state) {
    case ecs::CalibrationHealth::kGood: return CalibrationHealth::GOOD;
    case ecs::CalibrationHealth::kDegraded: return CalibrationHealth::DEGRADED;
    case ecs::CalibrationHealth::kBad: return CalibrationHealth::BAD;
    default: return CalibrationHealth::UNKNOWN;
  }
}

// Whether `intrinsics` (fx, fy, cx, cy, then D, as in CalibrationStatus) are those of `info`.
bool sameIntrinsics(const std::vector<double>& intrinsics, const CameraInfo& info) {
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

// Threads: the frame, observation and timer callbacks run on the nodelet's single-threaded
// queue and alone touch monitor_ and the state below; a restore runs on a std::async thread
// (bounded service calls) and shares only its future, read from those callbacks.
class CalibrationHealthNodelet : public GuardedNodelet {
 public:
  CalibrationHealthNodelet() : GuardedNodelet("CalibrationHealth") {}
  ~CalibrationHealthNodelet() override {
    timer_.stop();
    if (restore_.valid()) restore_.wait();  // bounded: two service calls of service_timeout_s
  }

 private:
  using Policy = message_filters::sync_policies::ExactTime<Image, CameraInfo, Image, CameraInfo, CalibrationMode>;

  void releaseAfterFailedStart() override {
    timer_.stop();
    for (ros::Subscriber* sub :
         {&observations_sub_, &status_sub_, &mode_record_sub_, &left_info_record_sub_, &right_info_record_sub_,
          &coverage_sub_, &verified_sub_})
      sub->shutdown();
  }

  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const std::string package_path = ros::package::getPath("embedded_calibration_stereo");
    params_ = loadParams(pnh, package_path.empty() ? "" : package_path + "/config/sim_rig.yaml");
    try {
      cv::FileStorage fs = ecs::openYaml(params_.device_config);
      boards_ = ecs::loadDevice(fs["device"], "device").virtualBoards();
      if (!fs["rig"].empty()) nominal_ = ecs::loadStereoRig(fs["rig"], "rig");
    } catch (const std::exception& e) {
      throw ecs::ConfigError("device_config", "'" + params_.device_config + "': " + e.what());
    }
    monitor_ = std::make_unique<ecs::CalibrationMonitor>(params_.monitor);
    coverage_ = std::make_unique<ecs::DepthCoverageWatch>(params_.coverage);

    health_pub_ = nh.advertise<CalibrationHealth>("calibration/health", 5);
    status_pub_ = nh.advertise<CalibrationStatus>("calibration/status", 1);
    left_sub_.subscribe(nh, "left/image_raw", params_.queue_size);
    left_info_sub_.subscribe(nh, "left/camera_info", params_.queue_size);
    right_sub_.subscribe(nh, "right/image_raw", params_.queue_size);
    right_info_sub_.subscribe(nh, "right/camera_info", params_.queue_size);
    mode_sub_.subscribe(nh, "calibration_mode", params_.queue_size);
    gate_ = std::make_unique<FrameStampGate>(std::vector<std::string>(2, mode_sub_.getTopic()), getName());
    mode_admit_ = std::make_unique<AdmissionFilter<CalibrationMode>>(
        mode_sub_, [this](const ros::MessageEvent<CalibrationMode const>& event) {
          return gate_->offer(kSyncedMode, event.getMessage()->header.stamp, event.getPublisherName(),
                              [this, event] { mode_admit_->pass(event); }) == FrameStampGate::Verdict::kPass;
        });
    sync_ = std::make_unique<message_filters::Synchronizer<Policy>>(Policy(params_.queue_size), left_sub_,
                                                                    left_info_sub_, right_sub_, right_info_sub_,
                                                                    *mode_admit_);
    sync_->registerCallback(&CalibrationHealthNodelet::onFrame, this);
    // Every frame's light and epoch, and the calibration of every frame, on deeper queues than the
    // images': a frame the synchroniser drops (the images queue up under load) must not hide a
    // new calibration or the light of a verification frame.
    mode_record_sub_ = nh.subscribe<CalibrationMode>(
        "calibration_mode", kKeptFrames,
        boost::function<void(const ros::MessageEvent<CalibrationMode const>&)>(
            [this](const ros::MessageEvent<CalibrationMode const>& event) {
              const CalibrationModeConstPtr mode = event.getMessage();
              if (gate_->offer(kRecordedMode, mode->header.stamp, event.getPublisherName(),
                               [this, mode] { onMode(mode); }) == FrameStampGate::Verdict::kPass)
                onMode(mode);
            }));
    left_info_record_sub_ = nh.subscribe<CameraInfo>("left/camera_info", kKeptFrames, [this](const CameraInfoConstPtr& info) {
      keep(&left_infos_, info);
      for (const FrameStampGate::Release& release : gate_->image(info->header.stamp)) release();
    });
    right_info_record_sub_ = nh.subscribe<CameraInfo>(
        "right/camera_info", kKeptFrames, [this](const CameraInfoConstPtr& info) { keep(&right_infos_, info); });
    status_sub_ = nh.subscribe("calibration/status", 5, &CalibrationHealthNodelet::onStatus, this);
    observations_sub_ = nh.subscribe("calibration/observations", 30, &CalibrationHealthNodelet::onObservation, this);
    coverage_sub_ = nh.subscribe("disparity_coverage", 5, &CalibrationHealthNodelet::onCoverage, this);
    verified_sub_ = nh.subscribe("calibration/verified", 1, &CalibrationHealthNodelet::onVerified, this);

    diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
    diagnostics_->setHardwareID("calibration_health");
    diagnostics_->add("calibration_health", this, &CalibrationHealthNodelet::diagnose);
    timer_ = nh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
      collectRestore();
      stopWaitingForBoards();
      diagnostics_->update();
    });
    NODELET_INFO("CalibrationHealth: depth mode on %s and %s (every %d settled light-off frame%s), verification "
                 "on %s, boards %s, %s",
                 left_sub_.getTopic().c_str(), right_sub_.getTopic().c_str(), params_.depth_every_n_frames,
                 params_.depth_every_n_frames == 1 ? "" : "s", observations_sub_.getTopic().c_str(),
                 params_.boards_posed ? "at their poses of the calibration's solve (device_config's for others)"
                                      : "posed per frame",
                 params_.rollback ? "a new calibration that verifies worse is rolled back"
                                  : "no rollback");
  }

  static void keep(std::deque<CameraInfoConstPtr>* infos, const CameraInfoConstPtr& info) {
    infos->push_back(info);
    if (infos->size() > kKeptFrames) infos->pop_front();
  }

  static CameraInfoConstPtr at(const std::deque<CameraInfoConstPtr>& infos, const ros::Time& stamp) {
    for (auto it = infos.rbegin(); it != infos.rend(); ++it)
      if ((*it)->header.stamp == stamp) return *it;
    return nullptr;
  }

  // Every frame (the camera_info of its stamp arrived before it: the driver publishes it first).
  void onMode(const CalibrationModeConstPtr& mode) {
    collectRestore();
    stopWaitingForBoards();
    const ros::Time stamp = mode->header.stamp;
    frames_.push_back({stamp, mode->calibration_epoch, mode->light_on && mode->settled, !mode->light_on && mode->settled});
    if (frames_.size() > kKeptFrames) frames_.pop_front();
    if (epoch_ && *epoch_ == mode->calibration_epoch) return;
    const CameraInfoConstPtr left = at(left_infos_, stamp), right = at(right_infos_, stamp);
    if (!left || !right) {  // the next frame of this epoch brings it
      NODELET_WARN_THROTTLE(5.0, "CalibrationHealth: no camera_info on %s and %s for the frame of %.3f s",
                            left_info_record_sub_.getTopic().c_str(), right_info_record_sub_.getTopic().c_str(),
                            stamp.toSec());
      return;
    }
    newCalibration(*left, *right, mode->calibration_epoch);
    publish(stamp);  // no verdict on the new calibration yet
  }

  void onFrame(const ImageConstPtr& left, const CameraInfoConstPtr&, const ImageConstPtr& right,
               const CameraInfoConstPtr&, const CalibrationModeConstPtr& mode) {
    collectRestore();
    const ros::Time stamp = mode->header.stamp;
    if (!monitor_->hasCalibration() || !epoch_ || *epoch_ != mode->calibration_epoch) return;
    if (mode->light_on || !mode->settled) return;
    if (++light_off_frames_ % params_.depth_every_n_frames != 0) return;
    cv_bridge::CvImageConstPtr left_cv, right_cv;
    try {
      left_cv = cv_bridge::toCvShare(left);
      right_cv = cv_bridge::toCvShare(right);
    } catch (const cv_bridge::Exception& e) {
      NODELET_ERROR_THROTTLE(5.0, "CalibrationHealth: frame of %s not measured: %s", left_sub_.getTopic().c_str(),
                             e.what());
      return;
    }
    const auto start = std::chrono::steady_clock::now();
    try {
      monitor_->addDepthFrame(stamp.toSec(), left_cv->image, right_cv->image);
    } catch (const std::exception& e) {
      NODELET_ERROR_THROTTLE(5.0, "CalibrationHealth: frame of %s not measured: %s", left_sub_.getTopic().c_str(),
                             e.what());
      return;
    }
    depth_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    ++depth_frames_;
    publish(stamp);
  }

  void onObservation(const StereoPatternObservationConstPtr& msg) {
    collectRestore();
    if (!monitor_->hasCalibration()) return;
    // Only settled light-on frames taken with the calibration in force verify it.
    const FrameSeen* seen = nullptr;
    for (const FrameSeen& frame : frames_)
      if (frame.stamp == msg->header.stamp) seen = &frame;
    if (!seen || !seen->lit || seen->epoch != *epoch_) return;
    if (waiting_for_boards_ && !stopWaitingForBoards()) {
      deferred_ = msg;  // verified once the solve's boards are known (or the wait is over)
      return;
    }
    verify(msg);
  }

  // The calibration the driver keeps as verified GOOD (latched): after a restart, the reference
  // until a calibration of this run has a verdict; a calibration in force without a verdict yet
  // (the one the driver started with) is tested against it.
  void onVerified(const VerifiedCalibrationConstPtr& msg) {
    policy_.seedEarlierRun(std::make_pair(msg->left, msg->right));
    if (!params_.rollback || !epoch_ || !in_force_ || policy_.testing(*epoch_) || restored_epoch_ == epoch_) return;
    const auto& reference = policy_.reference();
    if (reference->epoch != Rollback::kEarlierRun) return;  // this run has verdicts of its own
    if (carriesCalibration(in_force_->first, msg->left) && carriesCalibration(in_force_->second, msg->right)) return;
    policy_.start(*epoch_, true);
  }

  // The valid fraction of a light-off frame's disparity (lit frames carry the boards' separation).
  void onCoverage(const DisparityCoverageConstPtr& msg) {
    for (const FrameSeen& frame : frames_) {
      if (frame.stamp != msg->header.stamp) continue;
      if (frame.dark && std::isfinite(msg->valid_fraction)) coverage_->add(msg->header.stamp.toSec(), msg->valid_fraction);
      return;
    }
  }

  // A settled light-on frame of the calibration in force: the monitor checks it against the
  // boards.
  void verify(const StereoPatternObservationConstPtr& msg) {
    const ecs::StereoObservation observation = fromMsg(*msg);
    if (observation.left.empty() && observation.right.empty()) return;
    bool verified = false;
    try {
      verified = monitor_->addVerification(msg->header.stamp.toSec(), observation);
    } catch (const std::exception& e) {
      NODELET_ERROR_THROTTLE(5.0, "CalibrationHealth: observation on %s not used: %s",
                             observations_sub_.getTopic().c_str(), e.what());
      return;
    }
    if (verified) {
      ++verifications_;
      checkNewCalibration();
    }
    publish(msg->header.stamp);
  }

  // An accepted solve: its board poses, for verifying its calibration once it is in force. The
  // calibrator found nothing better than the calibration in force: while DEGRADED, no more
  // windows are wanted for it until a signal doubles.
  void onStatus(const CalibrationStatusConstPtr& status) {
    noteRefinement(*status);
    if (status->accepted && !status->board_ids.empty() && status->board_ids.size() == status->board_poses.size()) {
      SolvedBoards solved{status->left_intrinsics, status->right_intrinsics, boards_};
      std::vector<ecs::VirtualBoard> placed;
      for (ecs::VirtualBoard board : boards_)
        for (size_t i = 0; i < status->board_ids.size(); ++i)
          if (status->board_ids[i] == board.virtual_id) {
            board.rig_from_board = fromPoseMsg(status->board_poses[i]);
            placed.push_back(board);
          }
      solved.boards = std::move(placed);
      solved_.push_back(std::move(solved));
      if (solved_.size() > kKeptSolves) solved_.pop_front();
      if (waiting_for_boards_) useSolveBoards();
    }
    if (status->accepted || !status->in_force_confirmed) return;
    if (!epoch_ || status->epoch != *epoch_ || !monitor_->hasCalibration()) return;
    // A window taken before the health left GOOD confirms nothing about what it sees now.
    if (left_good_at_ && status->newest_frame < *left_good_at_) return;
    // The calibration holds by the boards: a collapse of depth since is the scene's.
    if (coverage_->collapse()) {
      NODELET_WARN("CalibrationHealth: %s, but the calibrator confirmed the calibration in force: taken as the "
                   "scene's; watching depth from its level now",
                   coverage_->collapse()->text().c_str());
      coverage_->rebase();
    }
    const ecs::HealthReport report = effectiveReport();
    if (ecs::healthRank(report.state) <= 0) return;
    confirmed_severity_ = severity(report);
  }

  // A commit predicted worse than refine_predicted_px wants one more burst while it is in force,
  // until a solve of a later window; refinements in a row are counted until the health leaves
  // GOOD again (a new change).
  void noteRefinement(const CalibrationStatus& status) {
    if (params_.refine_predicted_px <= 0.0) return;
    const double predicted = std::max(status.predicted_misalignment_rms_px, status.predicted_disparity_bias_rms_px);
    if (status.accepted && predicted > params_.refine_predicted_px && refinements_ < params_.max_refinements) {
      refine_ = Refinement{status.epoch, status.newest_frame, predicted};
      ++refinements_;
    } else if (refine_ && status.newest_frame > refine_->after) {
      refine_.reset();
    }
  }

  // The newest accepted solve whose calibration is the one in force gives the boards to verify
  // it against; true when there was one. A verification deferred meanwhile runs now.
  bool useSolveBoards() {
    if (!in_force_ || !rig_in_force_ || !monitor_->hasCalibration()) return false;
    for (auto it = solved_.rbegin(); it != solved_.rend(); ++it) {
      if (!sameIntrinsics(it->left, in_force_->first) || !sameIntrinsics(it->right, in_force_->second)) continue;
      monitor_->setCalibration(*rig_in_force_, static_cast<int>(*epoch_), it->boards, true);
      boards_source_ = "its solve";
      waiting_for_boards_.reset();
      runDeferred();
      return true;
    }
    return false;
  }

  // The wait for a solve's boards is over: true, and a deferred verification runs against
  // device_config's boards.
  bool stopWaitingForBoards() {
    if (!waiting_for_boards_) return true;
    if (ros::WallTime::now() < *waiting_for_boards_) return false;
    waiting_for_boards_.reset();
    runDeferred();
    return true;
  }

  void runDeferred() {
    if (!deferred_) return;
    const StereoPatternObservationConstPtr msg = deferred_;
    deferred_.reset();
    verify(msg);
  }

  // The monitor's report, worsened by what it cannot see: a calibration in force that is not
  // plausible (BAD) and a collapse of depth's valid fraction (at least DEGRADED).
  ecs::HealthReport effectiveReport() const {
    ecs::HealthReport report = monitor_->report();
    if (!implausible_.empty()) {
      report.state = ecs::CalibrationHealth::kBad;
      report.reason = implausible_;
    } else if (const std::optional<ecs::CoverageCollapse> collapse = coverage_->collapse()) {
      if (ecs::healthRank(report.state) < 1) report.state = ecs::CalibrationHealth::kDegraded;
      report.reason += (report.reason.empty() ? "" : "; ") + collapse->text();
    }
    return report;
  }

  // The largest signal in units of its DEGRADED threshold (signals not measured count 0).
  double severity(const ecs::HealthReport& report) const {
    const ecs::CalibrationMonitorOptions& o = params_.monitor;
    double worst = 0.0;
    if (report.epipolar_age_s >= 0.0) worst = std::max(worst, report.misalignment_px / o.misalignment_degraded_px);
    if (report.board_age_s >= 0.0) {
      worst = std::max(worst, report.disparity_bias_px / o.disparity_bias_degraded_px);
      worst = std::max(worst, report.board_residual_px / o.board_residual_degraded_px);
    }
    return worst;
  }

  // A new epoch: the monitor starts again with it; the newest verified pair (rollback_policy.h)
  // is kept for a restore.
  void newCalibration(const CameraInfo& left, const CameraInfo& right, uint32_t epoch) {
    const bool is_restore = restored_ && carriesCalibration(left, restored_->first) &&
                            carriesCalibration(right, restored_->second);
    policy_.start(epoch, params_.rollback && !is_restore);
    if (is_restore) {
      restored_.reset();
      restored_epoch_ = epoch;  // the health reason says why until it has a verdict
    }
    epoch_ = epoch;
    in_force_ = std::make_pair(left, right);
    // Plausible as every consumer checks a CameraInfo, focal lengths near device_config's.
    implausible_ = checkCalibrationPair(left, left_info_record_sub_.getTopic(), right,
                                        right_info_record_sub_.getTopic(), nominal_);
    if (!implausible_.empty()) {
      implausible_ = "the calibration of epoch " + std::to_string(epoch) + " is not plausible: " + implausible_;
      NODELET_ERROR("CalibrationHealth: %s", implausible_.c_str());
    }
    confirmed_severity_.reset();
    left_good_at_.reset();
    ecs::StereoRig rig;
    std::string error;
    if (!fromStereoCameraInfo(left, right, &rig, &error)) {
      calibration_problem_ = "calibration of epoch " + std::to_string(epoch) + " not usable: " + error;
    } else {
      try {
        rig_in_force_ = rig;
        monitor_->setCalibration(rig, static_cast<int>(epoch), boards_, params_.boards_posed);
        boards_source_ = "device_config";
        calibration_problem_.clear();
        // A solve's calibration is verified against its solve's boards: already here, or soon
        // (its status follows the driver's first frames with it).
        waiting_for_boards_.reset();
        deferred_.reset();
        if (params_.boards_posed && !useSolveBoards() && params_.solve_boards_wait_s > 0.0)
          waiting_for_boards_ = ros::WallTime::now() + ros::WallDuration(params_.solve_boards_wait_s);
      } catch (const std::exception& e) {
        calibration_problem_ = "calibration of epoch " + std::to_string(epoch) + " not usable: " + e.what();
      }
    }
    if (!calibration_problem_.empty()) {
      monitor_ = std::make_unique<ecs::CalibrationMonitor>(params_.monitor);  // no calibration: UNKNOWN
      NODELET_ERROR("CalibrationHealth: %s", calibration_problem_.c_str());
    }
  }

  // After a verification: a new calibration under test is kept when GOOD or no worse than its
  // reference, and the reference restored otherwise (rollback_policy.h).
  void checkNewCalibration() {
    if (!epoch_ || !in_force_ || !policy_.testing(*epoch_)) return;
    if (restore_.valid()) return;  // an earlier restore still running: the next verification decides
    const ecs::HealthReport report = effectiveReport();
    const Rollback::Decision decision = policy_.decide(*epoch_, *in_force_, report.state);
    if (decision.outcome == Rollback::Outcome::kUndecided) return;  // no verdict yet: the next verification decides
    const uint32_t epoch = *epoch_;
    const Rollback::Reference& previous = *decision.reference;
    if (decision.outcome == Rollback::Outcome::kKept) {
      NODELET_INFO("CalibrationHealth: the calibration of epoch %u verified %s%s%s", epoch,
                   ecs::toString(report.state), report.reason.empty() ? "" : ": ", report.reason.c_str());
      return;
    }
    const std::string previous_name = previous.epoch == Rollback::kEarlierRun
                                          ? std::string("the one verified before the restart")
                                          : "the previous one (epoch " + std::to_string(previous.epoch) + ")";
    char text[400];
    snprintf(text, sizeof(text), "the calibration of epoch %u verified %s (%s) where %s was %s: restoring the previous one",
             epoch, ecs::toString(report.state), report.reason.c_str(), previous_name.c_str(),
             ecs::toString(previous.state));
    last_restore_ = text;
    restore_failed_ = false;
    NODELET_WARN("CalibrationHealth: %s", text);
    restored_ = previous.calibration;
    const ros::NodeHandle nh = getNodeHandle();
    const double timeout_s = params_.service_timeout_s;
    restore_ = std::async(std::launch::async, [nh, pair = previous.calibration, timeout_s]() -> std::string {
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
    CalibrationStatus status;
    status.header.stamp = ros::Time::now();
    status.epoch = epoch;
    status.accepted = false;
    status.reason = std::string("rolled back: ") + text;
    status_pub_.publish(status);
  }

  // Callback queue: the outcome of a finished restore.
  void collectRestore() {
    if (!restore_.valid() || restore_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
    const std::string error = restore_.get();
    ++restores_;
    if (error.empty()) {
      last_restore_ += "; restored";
      NODELET_WARN("CalibrationHealth: previous calibration restored");
    } else {
      restored_.reset();
      last_restore_ += "; restore failed: " + error;
      restore_failed_ = true;
      NODELET_ERROR("CalibrationHealth: restoring the previous calibration failed: %s", error.c_str());
    }
  }

  void publish(const ros::Time& stamp) {
    const ecs::HealthReport report = effectiveReport();
    if (epoch_ && in_force_) policy_.observe(*epoch_, *in_force_, report.state);
    auto msg = boost::make_shared<CalibrationHealth>();
    msg->header.stamp = stamp;
    msg->epoch = epoch_.value_or(0);
    msg->state = toMsgState(report.state);
    constexpr double nan = std::numeric_limits<double>::quiet_NaN();
    const bool depth = report.epipolar_age_s >= 0.0, boards = report.board_age_s >= 0.0;
    msg->misalignment_px = depth ? report.misalignment_px : nan;
    msg->misalignment_sd_px = depth ? report.misalignment_sd_px : nan;
    msg->board_rms_left_px = boards ? report.board_rms_left_px : nan;
    msg->board_rms_right_px = boards ? report.board_rms_right_px : nan;
    msg->stereo_consistency_px = boards ? report.stereo_consistency_px : nan;
    for (size_t i = 0; i < 4; ++i) {
      msg->predicted_depths_m[i] = ecs::kHealthDepthsM[i];
      msg->predicted_depth_error_pct[i] = report.predicted_depth_error_pct[i];
    }
    msg->misalignment_age_s = report.epipolar_age_s;
    msg->verification_age_s = report.board_age_s;
    msg->reason = reasonOf(report);
    const int level = ecs::healthRank(report.state);
    if (level == 0) confirmed_severity_.reset();  // GOOD again: a later change wants a window again
    if (level == 0) left_good_at_.reset();
    if (level > 0 && !left_good_at_) {
      left_good_at_ = stamp;
      refinements_ = 0;  // a new change: its commits may be refined again
    }
    // BAD: always (depth cannot be trusted). DEGRADED: until the calibrator confirms the
    // calibration in force as its best, and again once a signal doubles since.
    msg->calibration_wanted =
        level == 2 || (level == 1 && !(confirmed_severity_ && severity(report) < kRearmFactor * *confirmed_severity_));
    if (level == 1 && !msg->calibration_wanted)
      msg->reason += "; the calibrator found nothing better: no calibration window until a signal doubles";
    if (refine_ && epoch_ && refine_->epoch == *epoch_ && level >= 0 && !msg->calibration_wanted) {
      msg->calibration_wanted = true;
      char text[120];
      std::snprintf(text, sizeof(text), "; refining: the calibration's predicted error %.3f px (limit %.3f px)",
                    refine_->predicted_px, params_.refine_predicted_px);
      msg->reason += text;
    }
    health_pub_.publish(msg);
  }

  std::string reasonOf(const ecs::HealthReport& report) const {
    std::string reason = calibration_problem_.empty() ? report.reason : calibration_problem_;
    if (epoch_ && policy_.testing(*epoch_)) reason += (reason.empty() ? "" : "; ") + std::string("new calibration awaiting its verification");
    // Until the restored calibration has a verdict of its own.
    const bool restoring = restored_ || (epoch_ == restored_epoch_ && report.state == ecs::CalibrationHealth::kUnknown);
    if (!last_restore_.empty() && restoring) reason += (reason.empty() ? "" : "; ") + last_restore_;
    return reason;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    using diagnostic_msgs::DiagnosticStatus;
    const ecs::HealthReport report = effectiveReport();
    const std::string reason = reasonOf(report);
    if (!calibration_problem_.empty()) {
      status.summary(DiagnosticStatus::ERROR, calibration_problem_);
    } else if (restore_failed_) {
      status.summary(DiagnosticStatus::ERROR, last_restore_);
    } else {
      const int8_t level = report.state == ecs::CalibrationHealth::kGood       ? DiagnosticStatus::OK
                           : report.state == ecs::CalibrationHealth::kBad      ? DiagnosticStatus::ERROR
                                                                                : DiagnosticStatus::WARN;
      const std::string head = report.state == ecs::CalibrationHealth::kUnknown ? "no verdict yet"
                                                                               : ecs::toString(report.state);
      status.summary(level, reason.empty() ? head : head + ": " + reason);
    }
    status.add("state", ecs::toString(report.state));
    status.add("calibration epoch", epoch_.value_or(0));
    status.add("boards verified against", waiting_for_boards_ ? "waiting for its solve's" : boards_source_);
    status.add("misalignment (px)", report.misalignment_px);
    status.add("misalignment sd (px)", report.misalignment_sd_px);
    status.add("board rms left (px)", report.board_rms_left_px);
    status.add("board rms right (px)", report.board_rms_right_px);
    status.add("stereo consistency (px)", report.stereo_consistency_px);
    for (size_t i = 0; i < 4; ++i) {
      char key[64];
      snprintf(key, sizeof(key), "predicted depth error at %.0f m (%%)", ecs::kHealthDepthsM[i]);
      status.add(key, report.predicted_depth_error_pct[i]);
    }
    status.add("misalignment age (s)", report.epipolar_age_s);
    status.add("verification age (s)", report.board_age_s);
    status.add("frames measured", depth_frames_);
    status.add("last measurement (ms)", depth_ms_);
    status.add("verifications", verifications_);
    status.add("restores", restores_);
    status.add("last restore", last_restore_.empty() ? "none" : last_restore_);
  }

  static constexpr double kRearmFactor = 2.0;  // see calibration_wanted
  static constexpr size_t kKeptFrames = 64;  // stamps -> epochs remembered for the observations

  struct FrameSeen {
    ros::Time stamp;
    uint32_t epoch;
    bool lit;   // light on and settled
    bool dark;  // light off and settled
  };
  using Rollback = ecs::RollbackPolicy<std::pair<CameraInfo, CameraInfo>>;

  // Board poses of the calibrator's accepted solves, with the intrinsics they were solved with.
  struct SolvedBoards {
    std::vector<double> left, right;  // as CalibrationStatus: fx, fy, cx, cy, D
    std::vector<ecs::VirtualBoard> boards;
  };
  static constexpr size_t kKeptSolves = 8;

  HealthParams params_;
  std::vector<ecs::VirtualBoard> boards_;  // device_config's
  std::deque<SolvedBoards> solved_;
  std::optional<ecs::StereoRig> rig_in_force_;
  std::string boards_source_;                         // what the calibration in force is verified against
  std::optional<ros::WallTime> waiting_for_boards_;   // a new calibration waits for its solve's boards until then
  StereoPatternObservationConstPtr deferred_;         // the verification that waits with it
  std::unique_ptr<ecs::CalibrationMonitor> monitor_;
  std::unique_ptr<ecs::DepthCoverageWatch> coverage_;
  std::optional<ecs::StereoRig> nominal_;  // device_config's cameras
  std::string implausible_;                // why the calibration in force is not plausible, or ""
  message_filters::Subscriber<Image> left_sub_, right_sub_;
  message_filters::Subscriber<CameraInfo> left_info_sub_, right_info_sub_;
  message_filters::Subscriber<CalibrationMode> mode_sub_;
  std::unique_ptr<FrameStampGate> gate_;  // the frames are known by their left camera_info
  static constexpr size_t kSyncedMode = 0, kRecordedMode = 1;
  std::unique_ptr<AdmissionFilter<CalibrationMode>> mode_admit_;  // mode_sub_ -> mode_admit_ -> sync_
  std::unique_ptr<message_filters::Synchronizer<Policy>> sync_;
  ros::Subscriber observations_sub_, status_sub_, mode_record_sub_, left_info_record_sub_, right_info_record_sub_,
      coverage_sub_, verified_sub_;
  ros::Publisher health_pub_, status_pub_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::WallTimer timer_;

  std::deque<FrameSeen> frames_;
  std::deque<CameraInfoConstPtr> left_infos_, right_infos_;  // the latest frames' calibrations
  std::optional<uint32_t> epoch_;
  std::optional<std::pair<CameraInfo, CameraInfo>> in_force_;
  Rollback policy_;  // which calibration is tested against which, and restored
  std::optional<std::pair<CameraInfo, CameraInfo>> restored_;  // sent back to the driver, not seen yet
  std::future<std::string> restore_;                           // the running restore: "" or why it failed
  std::optional<uint32_t> restored_epoch_;
  std::optional<ros::Time> left_good_at_;  // stamp of the first verdict below GOOD since the last GOOD
  // A commit to refine: its epoch, its newest frame, its predicted error (px).
  struct Refinement {
    uint32_t epoch;
    ros::Time after;
    double predicted_px;
  };
  std::optional<Refinement> refine_;
  int refinements_ = 0;  // refinements asked since the health last left GOOD
  std::optional<double> confirmed_severity_;  // severity() when the calibrator confirmed the calibration                     // the epoch of the restored calibration
  std::string calibration_problem_, last_restore_;
  bool restore_failed_ = false;  // the last restore failed (its error is in last_restore_)
  uint64_t light_off_frames_ = 0, depth_frames_ = 0, verifications_ = 0, restores_ = 0;
  double depth_ms_ = 0.0;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::CalibrationHealthNodelet, nodelet::Nodelet)
