// CalibrationHealth nodelet: says at every frame whether the calibration in force still holds
// (core CalibrationMonitor, on settled light-off frames and on the tracker's board observations
// of settled light-on frames) and restores the previous calibration when a new one verifies
// worse. What it decides (rollback, which boards, which statuses count, calibration_wanted) is
// the core's CalibrationHealthPolicy; this nodelet wires topics and hands it what they bring.
// Topics, parameters, diagnostics: docs/nodelets.md, "CalibrationHealth"; states, rollback and
// the on-demand mode: docs/health.md.
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <message_filters/subscriber.h>
#include <message_filters/sync_policies/exact_time.h>
#include <message_filters/synchronizer.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/package.h>
#include <ros/ros.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <deque>
#include <future>
#include <memory>
#include <optional>

#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/DisparityCoverage.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/VerifiedCalibration.h"
#include "embedded_calibration_stereo/core/calibration/calibration_health_policy.h"
#include "embedded_calibration_stereo/core/calibration/calibration_monitor.h"
#include "embedded_calibration_stereo/core/calibration/depth_coverage_watch.h"
#include "embedded_calibration_stereo/core/calibration/measurement_rate.h"
#include "embedded_calibration_stereo/ros/calibration_health_io.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/frame_stamp_gate.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/lazy_synced_input.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

using sensor_msgs::CameraInfo;
using sensor_msgs::CameraInfoConstPtr;
using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

// Threads: the frame, mode, camera_info, observation, status, coverage, verified and timer
// callbacks run on the nodelet's single-threaded queue and alone touch monitor_, coverage_,
// policy_ and the state below; a restore runs on a std::async thread (bounded service calls)
// and shares only its future, read from those callbacks.
class CalibrationHealthNodelet : public GuardedNodelet {
 public:
  CalibrationHealthNodelet() : GuardedNodelet("CalibrationHealth") {}
  ~CalibrationHealthNodelet() override {
    timer_.stop();
    if (restore_.valid()) restore_.wait();  // bounded: two service calls of service_timeout_s
  }

 private:
  using SyncPolicy = message_filters::sync_policies::ExactTime<Image, CameraInfo, Image, CameraInfo, CalibrationMode>;
  using Pair = std::pair<CameraInfo, CameraInfo>;
  using HealthPolicy = core::CalibrationHealthPolicy<Pair>;

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
    params_ = loadHealthParams(pnh, package_path.empty() ? "" : package_path + "/config/sim_rig.yaml");
    monitor_ = std::make_unique<core::CalibrationMonitor>(params_.monitor);
    if (params_.depth_rate_hz > 0.0) depth_rate_.emplace(params_.depth_rate_hz);
    coverage_ = std::make_unique<core::DepthCoverageWatch>(params_.coverage);
    policy_ = std::make_unique<HealthPolicy>(params_.policy, [](const Pair& in_force, const Pair& other) {
      return carriesCalibration(in_force.first, other.first) && carriesCalibration(in_force.second, other.second);
    });
    health_pub_ = nh.advertise<CalibrationHealth>("calibration/health", 5);
    status_pub_ = nh.advertise<CalibrationStatus>("calibration/status", 1);
    subscribeFrames(nh);
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
    char depth_rate[80] = "every settled light-off frame";
    if (params_.depth_rate_hz > 0.0)
      std::snprintf(depth_rate, sizeof(depth_rate), "%g settled light-off frames a second at most", params_.depth_rate_hz);
    NODELET_INFO("CalibrationHealth: depth mode on %s and %s (%s), verification on %s, boards %s, %s",
                 left_sub_.getTopic().c_str(), right_sub_.getTopic().c_str(), depth_rate,
                 observations_sub_.getTopic().c_str(),
                 params_.policy.boards_posed ? "at their poses of the calibration's solve (device_config's for others)"
                                             : "posed per frame",
                 params_.policy.rollback ? "a new calibration that verifies worse is rolled back" : "no rollback");
  }

  // The images with their camera_info and calibration_mode (ExactTime), and every frame's light,
  // epoch and calibration on their own, deeper subscriptions: a frame the synchroniser drops (the
  // images queue up under load) must not hide a new calibration or the light of a verification
  // frame. A calibration_mode counts only for a frame whose left camera_info came, once per
  // stamp (frame_stamp_gate.h).
  void subscribeFrames(ros::NodeHandle& nh) {
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
    sync_ = std::make_unique<message_filters::Synchronizer<SyncPolicy>>(
        SyncPolicy(params_.queue_size), left_sub_, left_info_sub_, right_sub_, right_info_sub_, *mode_admit_);
    sync_->registerCallback(&CalibrationHealthNodelet::onFrame, this);
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
      records_.addCameraInfo(true, info);
      for (const FrameStampGate::Release& release : gate_->image(info->header.stamp)) release();
    });
    right_info_record_sub_ = nh.subscribe<CameraInfo>(
        "right/camera_info", kKeptFrames, [this](const CameraInfoConstPtr& info) { records_.addCameraInfo(false, info); });
  }

  // Every frame (the camera_info of its stamp arrived before it: the driver publishes it first).
  void onMode(const CalibrationModeConstPtr& mode) {
    collectRestore();
    stopWaitingForBoards();
    const ros::Time stamp = mode->header.stamp;
    const bool lit = mode->light_on && mode->settled, dark = !mode->light_on && mode->settled;
    records_.addFrame({stamp, mode->calibration_epoch, lit, dark});
    if (policy_->epoch() == mode->calibration_epoch) return;
    const CameraInfoConstPtr left = records_.cameraInfo(true, stamp), right = records_.cameraInfo(false, stamp);
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
    if (!monitor_->hasCalibration() || policy_->epoch() != mode->calibration_epoch) return;
    if (mode->light_on || !mode->settled) return;
    if (depth_rate_ && !depth_rate_->take(stamp.toSec())) return;
    std::chrono::steady_clock::time_point start;
    try {  // a cv_bridge::Exception too
      const cv_bridge::CvImageConstPtr left_cv = cv_bridge::toCvShare(left), right_cv = cv_bridge::toCvShare(right);
      start = std::chrono::steady_clock::now();
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
    const HealthFrameRecords::Frame* seen = records_.frame(msg->header.stamp);
    if (!seen || !seen->lit || policy_->epoch() != seen->epoch) return;
    stopWaitingForBoards();
    if (policy_->waitingForBoards()) {
      policy_->deferVerification();
      deferred_ = msg;  // verified once the solve's boards are known (or the wait is over)
      return;
    }
    verify(msg);
  }

  // The calibration the driver keeps as verified GOOD (latched): the policy's reference after a
  // restart.
  void onVerified(const VerifiedCalibrationConstPtr& msg) { policy_->earlierRunVerified({msg->left, msg->right}); }

  // The valid fraction of a light-off frame's disparity (lit frames carry the boards' separation).
  void onCoverage(const DisparityCoverageConstPtr& msg) {
    const HealthFrameRecords::Frame* seen = records_.frame(msg->header.stamp);
    if (seen && seen->dark && std::isfinite(msg->valid_fraction))
      coverage_->add(msg->header.stamp.toSec(), msg->valid_fraction);
  }

  // A settled light-on frame of the calibration in force: the monitor checks it against the
  // boards.
  void verify(const StereoPatternObservationConstPtr& msg) {
    const core::StereoObservation observation = fromMsg(*msg);
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

  // An accepted solve: its board poses, for verifying its calibration once it is in force. A
  // confirmation of the calibration in force: a collapse of depth since is the scene's, and the
  // policy stops wanting windows for it.
  void onStatus(const CalibrationStatusConstPtr& status) {
    const core::CalibratorStatus seen = toCalibratorStatus(*status);
    policy_->noteRefinement(seen);
    if (std::optional<SolvedBoards> solved = solvedBoards(*status, params_.boards)) {
      solved_.push_back(std::move(*solved));
      if (solved_.size() > kKeptSolves) solved_.pop_front();
      if (policy_->waitingForBoards()) useSolveBoards();
    }
    if (!policy_->confirmsInForce(seen, monitor_->hasCalibration())) return;
    if (coverage_->collapse()) {  // the calibration holds by the boards
      NODELET_WARN("CalibrationHealth: %s, but the calibrator confirmed the calibration in force: taken as the "
                   "scene's; watching depth from its level now",
                   coverage_->collapse()->text().c_str());
      coverage_->rebase();
    }
    policy_->confirmedInForce(effectiveReport());
  }

  // The newest accepted solve whose calibration is the one in force gives the boards to verify
  // it against; true when there was one. A verification deferred meanwhile runs now.
  bool useSolveBoards() {
    const std::optional<Pair>& in_force = policy_->inForce();
    if (!in_force || !rig_in_force_ || !monitor_->hasCalibration()) return false;
    for (auto it = solved_.rbegin(); it != solved_.rend(); ++it) {
      if (!solvedWith(*it, in_force->first, in_force->second)) continue;
      monitor_->setCalibration(*rig_in_force_, static_cast<int>(*policy_->epoch()), it->boards, true);
      boards_source_ = "its solve";
      if (policy_->solveBoardsUsed()) runDeferred();
      return true;
    }
    return false;
  }

  // A wait for a solve's boards that is over: a deferred verification runs against
  // device_config's boards.
  void stopWaitingForBoards() {
    if (policy_->endWaitIfOver(ros::WallTime::now().toSec())) runDeferred();
  }

  void runDeferred() {
    const StereoPatternObservationConstPtr msg = deferred_;
    deferred_.reset();
    if (msg) verify(msg);
  }

  core::HealthReport effectiveReport() const {
    return policy_->effectiveReport(monitor_->report(), coverage_->collapse());
  }

  // A new epoch: the monitor starts again with it; the policy keeps the newest verified pair for
  // a restore.
  void newCalibration(const CameraInfo& left, const CameraInfo& right, uint32_t epoch) {
    policy_->newCalibration(epoch, {left, right});
    deferred_.reset();
    // Plausible as every consumer checks a CameraInfo, focal lengths near device_config's.
    const std::string implausible = checkCalibrationPair(left, left_info_record_sub_.getTopic(), right,
                                                         right_info_record_sub_.getTopic(), params_.nominal);
    if (!implausible.empty()) {
      const std::string why = "the calibration of epoch " + std::to_string(epoch) + " is not plausible: " + implausible;
      policy_->setImplausible(why);
      NODELET_ERROR("CalibrationHealth: %s", why.c_str());
    }
    core::StereoRig rig;
    std::string error;
    if (!fromStereoCameraInfo(left, right, &rig, &error)) {
      policy_->setUnusable("calibration of epoch " + std::to_string(epoch) + " not usable: " + error);
    } else {
      try {
        rig_in_force_ = rig;
        monitor_->setCalibration(rig, static_cast<int>(epoch), params_.boards, params_.policy.boards_posed);
        boards_source_ = "device_config";
        const bool solve_boards = params_.policy.boards_posed && useSolveBoards();
        policy_->calibrationSet(solve_boards, ros::WallTime::now().toSec());
      } catch (const std::exception& e) {
        policy_->setUnusable("calibration of epoch " + std::to_string(epoch) + " not usable: " + e.what());
      }
    }
    if (!policy_->problem().empty()) {
      monitor_ = std::make_unique<core::CalibrationMonitor>(params_.monitor);  // no calibration: UNKNOWN
      NODELET_ERROR("CalibrationHealth: %s", policy_->problem().c_str());
    }
  }

  // After a verification: a new calibration under test is kept, or its reference restored by a
  // std::async thread (two bounded service calls) while calibration/status says why.
  void checkNewCalibration() {
    const HealthPolicy::Verified verified = policy_->afterVerification(effectiveReport());
    if (verified.outcome == HealthPolicy::Verified::Outcome::kKept)
      NODELET_INFO("CalibrationHealth: %s", verified.text.c_str());
    if (verified.outcome != HealthPolicy::Verified::Outcome::kRestore) return;
    NODELET_WARN("CalibrationHealth: %s", verified.text.c_str());
    restore_ = restoreCalibration(getNodeHandle(), *verified.restore, params_.service_timeout_s);
    status_pub_.publish(rolledBackStatus(*policy_->epoch(), verified.text));
  }

  // Callback queue: the outcome of a finished restore.
  void collectRestore() {
    if (!restore_.valid() || restore_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
    const std::string error = restore_.get();
    if (policy_->restoreFinished(error))
      NODELET_WARN("CalibrationHealth: previous calibration restored");
    else
      NODELET_ERROR("CalibrationHealth: restoring the previous calibration failed: %s", error.c_str());
  }

  void publish(const ros::Time& stamp) {
    const core::HealthReport report = effectiveReport();
    const core::HealthVerdict verdict = policy_->published(report, stamp.toSec());
    const CalibrationHealthPtr msg = toHealthMsg(report, policy_->epoch().value_or(0), stamp);
    msg->reason = verdict.reason;
    msg->calibration_wanted = verdict.calibration_wanted;
    health_pub_.publish(msg);
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    const core::HealthReport report = effectiveReport();
    HealthDiagnostics extra;
    extra.boards_source = policy_->waitingForBoards() ? "waiting for its solve's" : boards_source_;
    extra.depth_frames = depth_frames_;
    extra.verifications = verifications_;
    extra.depth_ms = depth_ms_;
    fillHealthDiagnostics(report, *policy_, policy_->reason(report), extra, &status);
  }

  static constexpr size_t kKeptFrames = 64;  // stamps -> epochs remembered for the observations
  static constexpr size_t kKeptSolves = 8;
  static constexpr size_t kSyncedMode = 0, kRecordedMode = 1;

  HealthParams params_;
  std::deque<SolvedBoards> solved_;  // the calibrator's accepted solves
  std::optional<core::StereoRig> rig_in_force_;
  std::string boards_source_;                  // what the calibration in force is verified against
  StereoPatternObservationConstPtr deferred_;  // a verification waiting for its solve's boards
  std::unique_ptr<core::CalibrationMonitor> monitor_;
  std::unique_ptr<core::DepthCoverageWatch> coverage_;
  std::unique_ptr<HealthPolicy> policy_;
  message_filters::Subscriber<Image> left_sub_, right_sub_;
  message_filters::Subscriber<CameraInfo> left_info_sub_, right_info_sub_;
  message_filters::Subscriber<CalibrationMode> mode_sub_;
  std::unique_ptr<FrameStampGate> gate_;  // the frames are known by their left camera_info
  std::unique_ptr<AdmissionFilter<CalibrationMode>> mode_admit_;  // mode_sub_ -> mode_admit_ -> sync_
  std::unique_ptr<message_filters::Synchronizer<SyncPolicy>> sync_;
  ros::Subscriber observations_sub_, status_sub_, mode_record_sub_, left_info_record_sub_, right_info_record_sub_,
      coverage_sub_, verified_sub_;
  ros::Publisher health_pub_, status_pub_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::WallTimer timer_;

  HealthFrameRecords records_{kKeptFrames};  // the latest frames' light, epoch and calibrations
  std::future<std::string> restore_;          // the running restore: "" or why it failed
  std::optional<core::MeasurementRate> depth_rate_;  // which light-off frames to measure; none: all
  uint64_t depth_frames_ = 0, verifications_ = 0;
  double depth_ms_ = 0.0;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::CalibrationHealthNodelet, nodelet::Nodelet)
