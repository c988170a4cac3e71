// PatternTracker nodelet: finds the device's board corners in every settled light-on stereo frame
// and publishes them on calibration/observations; teaches its prior (core TeachingPlan decides
// when and on what) and, with window_tracking, tracks each light burst as a whole
// (WindowTrackingWorker). Topics, parameters and behaviour: docs/nodelets.md#patterntracker.
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/package.h>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <chrono>
#include <fstream>
#include <memory>
#include <optional>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"
#include "embedded_calibration_stereo/core/tracker/teaching_plan.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/lazy_synced_input.h"
#include "embedded_calibration_stereo/ros/light_burst.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/tracker_teaching.h"
#include "embedded_calibration_stereo/ros/tracking_figures.h"
#include "embedded_calibration_stereo/ros/window_tracking_worker.h"

namespace embedded_calibration_stereo {

using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

// Threads (docs/architecture.md#threads): the single-threaded callback queue runs frameCb, ~teach,
// the ground-truth scene subscribers, the connect callbacks and both timers, and alone touches the
// members here; tracking runs in frameCb (cameras in parallel). Teaching runs on a std::async
// worker with copies of the frames (or a burst's message pointers, never written) and returns
// through teaching_ (tracker_teaching.h), collected by frameCb. Window tracking runs on
// window_worker_'s thread (window_tracking_worker.h). input_ (un)subscribes under its own mutex.
class PatternTrackerNodelet : public GuardedNodelet {
 public:
  PatternTrackerNodelet() : GuardedNodelet("PatternTracker") {}

 private:
  using FrameInput = LazySyncedInput<Image, Image, CalibrationMode>;

  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const std::string package_path = ros::package::getPath("embedded_calibration_stereo");
    const ParameterReader read(pnh);
    prior_file_ = read.get("prior_file", defaultPatternPriorFile());
    device_config_ = read.get("device_config", package_path + "/config/sim_rig.yaml");
    prior_write_.emplace(prior_file_, getName());
    const bool teach_on_start = read.get("teach_on_start", true);
    const bool from_truth = read.get("teach_from_ground_truth", false);
    const bool from_burst = read.choice("teach_from", "burst", {"burst", "light_off"}) == "burst";
    // The test-only truth teaching takes precedence over teach_from.
    plan_ = core::TeachingPlan(from_truth   ? core::TeachFrom::kGroundTruth
                              : from_burst ? core::TeachFrom::kBurst
                                           : core::TeachFrom::kLightOff);
    const int queue_size = read.atLeast("queue_size", 10, 1);
    stale_background_level_ = read.atLeast("stale_background_level", core::TrackerOptions().stale_background_level, 0.0);
    window_tracking_ = read.get("window_tracking", false);
    window_options_.scene_matches = read.get("scene_matches", true);
    try {
      device_ = core::loadSimRigConfig(device_config_);
    } catch (const std::exception& e) {
      throw core::ConfigError("device_config", "'" + device_config_ + "': " + e.what());
    }
    bursts_.emplace(window_options_.min_light_on_frames);  // window tracking and teaching from a burst
    loadPrior(teach_on_start);

    input_ = std::make_unique<FrameInput>(
        nh, pnh, FrameInput::Topics{"left/image_raw", "right/image_raw", "calibration_mode"}, false, queue_size,
        [this](const auto& left, const auto& right, const auto& mode) { frameCb(left, right, mode); });
    diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
    diagnostics_->setHardwareID("pattern_tracker");
    diagnostics_->add("pattern_tracker", this, &PatternTrackerNodelet::diagnose);
    diagnostics_timer_ = nh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
      diagnostics_->update();
    });
    teach_srv_ = pnh.advertiseService("teach", &PatternTrackerNodelet::teachCb, this);
    const auto cb = input_->connectCallback();
    observations_pub_ = nh.advertise<StereoPatternObservation>("calibration/observations", 10, cb, cb);
    input_->watch(observations_pub_);
    if (window_tracking_) {
      ros::Publisher pub = nh.advertise<StereoPatternObservation>("calibration/window_observations", 10, cb, cb);
      input_->watch(pub);
      window_worker_ = std::make_unique<WindowTrackingWorker>(pub, getName(), device_config_);
    }
    updateNeed();
    input_->start();  // subscribes the inputs while someone listens or teaching waits
    NODELET_INFO("PatternTracker: prior %s (%s), device %s%s", prior_file_.c_str(), core::toString(plan_.state()),
                 device_config_.c_str(),
                 window_tracking_ ? ", window tracking on (one observation per light burst on "
                                    "calibration/window_observations)"
                                  : "");
  }

  void loadPrior(bool teach_on_start) {
    if (!std::ifstream(prior_file_).good()) {
      plan_.priorMissing(teach_on_start);
      if (!teach_on_start) NODELET_ERROR("%s", idleMessage().c_str());
      return;
    }
    try {
      startTracking(core::readPatternPrior(prior_file_));
    } catch (const std::exception& e) {
      plan_.priorUnusable(e.what());
      NODELET_ERROR("%s", idleMessage().c_str());
    }
  }

  // Throws ConfigError (or std::invalid_argument) when the prior is unusable.
  void startTracking(const core::PatternPrior& prior) {
    if (prior.cameras.size() != 2)
      throw std::invalid_argument("expected 2 cameras (left, right), found " + std::to_string(prior.cameras.size()));
    core::TrackerOptions options;
    options.stale_background_level = stale_background_level_;
    auto window_tracker =
        window_tracking_ ? std::make_shared<core::WindowTracker>(prior, options, window_options_, device_.rig) : nullptr;
    tracker_ = std::make_unique<core::PatternTracker>(prior, options);
    window_tracker_ = std::move(window_tracker);  // the worker keeps the previous one until its window is done
    background_stamp_ = ros::Time();  // the tracker has no background yet
    plan_.tracking();
  }

  std::string idleMessage() const {
    return "PatternTracker: prior file '" + prior_file_ + "' " + plan_.idleReason() +
           "; idle until teaching (service " + getPrivateNodeHandle().resolveName("teach") + ")";
  }

  // The inputs while teaching waits or runs; the simulator's scene only while teaching from it
  // waits for a frame (the driver renders it only for subscribers).
  void updateNeed() {
    input_->need(plan_.needsInputs());
    if (!plan_.needsGroundTruth()) return truth_.unsubscribe();
    if (!truth_.subscribed()) truth_.subscribe(getNodeHandle(), [this] { teachFromTruthIfMatched(); });
  }

  // Teaches on the newest light-on pair kept whose ground-truth scenes have arrived.
  void teachFromTruthIfMatched() {
    const std::optional<GroundTruthPairing::Match> match = plan_.teachRequested() ? truth_.newest() : std::nullopt;
    if (!match) return;
    const Image &on = *match->light_on.first, &scene = *match->scene.first;
    cv::Mat left, right;
    core::ColorOrder order;
    if (scene.encoding != on.encoding || scene.width != on.width || scene.height != on.height) {
      NODELET_ERROR_THROTTLE(5.0, "PatternTracker: ground_truth/left/image_scene (%s %ux%u) does not match %s; "
                             "cannot teach from it", scene.encoding.c_str(), scene.width, scene.height,
                             input_->topic(0).c_str());
      return;
    }
    if (!toImages(match->light_on.first, match->light_on.second, &left, &right, &order)) return;
    NODELET_INFO("PatternTracker: teaching on a light-on frame minus the simulator's scene of the same stamp");
    startTeaching(left, right, cv_bridge::toCvShare(match->scene.first)->image,
                  cv_bridge::toCvShare(match->scene.second)->image, order);
  }

  bool teachCb(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    res.success = plan_.request();  // false while teaching runs
    res.message = res.success ? plan_.teachesAt() + ("; prior file " + prior_file_) : "busy: teaching is running";
    if (res.success) updateNeed();
    return true;
  }

  void frameCb(const ImageConstPtr& left, const ImageConstPtr& right, const CalibrationModeConstPtr& mode) {
    collectTeaching();
    if (!mode->settled) return;  // the light is changing: neither a scene nor a board frame
    if (auto ended = bursts_->add(left, right, mode->light_on)) endBurst(std::move(*ended));
    if (!mode->light_on) {
      light_off_left_ = left;  // zero-copy: keeps the shared messages alive
      light_off_right_ = right;
      return;
    }
    cv::Mat left_image, right_image;  // the messages' pixels
    core::ColorOrder order;
    if (!toImages(left, right, &left_image, &right_image, &order)) return;
    if (teachOnLightOn(left, right, left_image, right_image, order)) return;
    if (!tracker_) {
      if (plan_.state() != core::PriorState::kTeaching && !plan_.teachRequested())
        NODELET_ERROR_THROTTLE(5.0, "%s", idleMessage().c_str());
      return;
    }
    track(left, left_image, right_image, order);
  }

  // Teaching's part of a settled light-on frame (TeachingPlan::lightOn). True when teaching
  // started.
  bool teachOnLightOn(const ImageConstPtr& left, const ImageConstPtr& right, const cv::Mat& left_image,
                      const cv::Mat& right_image, core::ColorOrder order) {
    using Step = core::TeachingPlan::LightOnStep;
    switch (plan_.lightOn(bursts_->lightOnFramesKept(), lightOffMatches(*left))) {
      case Step::kNone: return false;
      case Step::kMatchGroundTruth:
        truth_.addLightOn({left, right});
        teachFromTruthIfMatched();
        if (!plan_.teachRequested()) return true;
        NODELET_WARN_THROTTLE(5.0, "PatternTracker: teaching waits for ground_truth/left|right/image_scene of a "
                              "settled light-on frame (teach_from_ground_truth is set)");
        return false;
      case Step::kTeachOnBurstUnderWay: startTeachingFromBurst(bursts_->underWay()); return true;
      case Step::kWaitForBurst:
        NODELET_INFO_THROTTLE(30.0, "PatternTracker: teaching waits for a light burst of %d settled light-on frames "
                              "on %s", core::TeachingPlan::kTeachLightOnFrames, input_->topic(0).c_str());
        return false;
      case Step::kTeachOnLightOff:
        startTeaching(left_image, right_image, cv_bridge::toCvShare(light_off_left_)->image,
                      cv_bridge::toCvShare(light_off_right_)->image, order);
        return true;
      case Step::kWaitForLightOff:
        NODELET_WARN_THROTTLE(5.0, "PatternTracker: teaching waits for a settled light-off frame on %s",
                              input_->topic(0).c_str());
        return false;
    }
    return false;
  }

  bool toImages(const ImageConstPtr& left, const ImageConstPtr& right, cv::Mat* left_image, cv::Mat* right_image,
                core::ColorOrder* order) {
    const std::string problem = readStereo(left, right, left_image, right_image, order);
    if (!problem.empty())
      NODELET_ERROR_THROTTLE(5.0, "PatternTracker: %s, %s: %s; frame dropped", input_->topic(0).c_str(),
                             input_->topic(1).c_str(), problem.c_str());
    return problem.empty();
  }

  // The latest settled light-off pair exists and has the format of this light-on frame.
  bool lightOffMatches(const Image& light_on) const {
    return light_off_left_ && light_off_left_->width == light_on.width && light_off_left_->height == light_on.height &&
           light_off_left_->encoding == light_on.encoding;
  }

  // `left_off`/`right_off`: the scene without the device (light-off frame, or the sim's truth),
  // same format as the light-on frames.
  void startTeaching(const cv::Mat& left, const cv::Mat& right, const cv::Mat& left_off, const cv::Mat& right_off,
                     core::ColorOrder order) {
    beginTeaching(false);  // no longer needs the ground-truth scene
    NODELET_INFO("PatternTracker: teaching from a light-on frame and the latest light-off frame (worker thread)");
    teaching_.start({left, left_off}, {right, right_off}, order, device_, prior_file_);
  }

  // Teaches on the device image learned from a burst's light pairs (worker thread): a burst
  // under way (its light-on frames so far with the light-off frame before it) or one that ended.
  void startTeachingFromBurst(LightBurst burst) {
    beginTeaching(!burst.light_off_after.first);
    NODELET_INFO("PatternTracker: teaching on the device image learned from %zu light-on frames of a burst "
                 "(worker thread)", burst.light_on.size());
    teaching_.start(std::move(burst), device_, prior_file_);
  }

  void beginTeaching(bool burst_under_way) {
    plan_.teachingStarted(burst_under_way);
    tracker_.reset();
    window_tracker_.reset();
    taught_burst_.reset();
    prior_write_->replaced();
    updateNeed();
  }

  void collectTeaching() {
    const std::optional<TeachOutcome> outcome = teaching_.finished();
    if (!outcome) return;
    std::string error = outcome->error;
    if (error.empty()) {
      try {
        startTracking(outcome->prior);
        adoptTaught(*outcome);
        return;
      } catch (const std::exception& e) {
        error = e.what();
      }
    }
    plan_.teachFailed(error);
    NODELET_ERROR("%s", idleMessage().c_str());
    updateNeed();
  }

  // A prior taught and in use: written (or retried), taught again if it misses boards
  // (TeachingPlan::teachAgainIfBoardsMissing), and the burst it was taught on tracked with it.
  void adoptTaught(const TeachOutcome& outcome) {
    prior_write_->taught(outcome, getNodeHandle());
    updateNeed();
    const size_t boards = device_.device.virtualBoards().size(), left_boards = outcome.prior.cameras[0].boards.size(),
                 right_boards = outcome.prior.cameras[1].boards.size();
    if (plan_.teachAgainIfBoardsMissing(left_boards, right_boards, boards))
      NODELET_INFO("PatternTracker: %zu + %zu of %zu boards taught on the first light-on frames of a burst; teaching "
                   "again at the end of a burst", left_boards, right_boards, boards);
    if (taught_burst_) endBurst(std::move(*taught_burst_));  // tracked with the prior it taught
    taught_burst_.reset();
  }

  void track(const ImageConstPtr& left_msg, const cv::Mat& left, const cv::Mat& right, core::ColorOrder order) {
    const auto t0 = std::chrono::steady_clock::now();
    StereoPatternObservation msg;
    try {
      // The latest light-off pair becomes the background once, at the first light-on frame after it.
      if (lightOffMatches(*left_msg) && light_off_left_->header.stamp != background_stamp_) {
        tracker_->setBackground(cv_bridge::toCvShare(light_off_left_)->image,
                                cv_bridge::toCvShare(light_off_right_)->image, order);
        background_stamp_ = light_off_left_->header.stamp;
      }
      msg = toMsg(tracker_->trackStereo(left, right, left_msg->header.stamp.toSec(), order));
      const core::CameraTracker& left_tracker = tracker_->camera(0);
      background_use_ = left_tracker.background().empty() ? "none: raw images, boards aligned whole"
                        : left_tracker.lastBackgroundStale()
                            ? "light-off frame stale (scene moved): raw images, boards aligned whole"
                            : "light-off frame";
    } catch (const std::exception& e) {
      NODELET_ERROR_THROTTLE(5.0, "PatternTracker: tracking failed on %s: %s", input_->topic(0).c_str(), e.what());
      return;
    }
    msg.header = left_msg->header;
    observations_pub_.publish(msg);
    figures_.add(msg, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }

  // A light burst ended (the first settled light-off frame after it): TeachingPlan::burstEnded.
  void endBurst(EndedBurst ended) {
    using Step = core::TeachingPlan::BurstStep;
    switch (plan_.burstEnded(ended.problem.empty(), window_tracking_)) {
      case Step::kIgnore: return;
      case Step::kTeach: return startTeachingFromBurst(ended.burst);
      case Step::kTeachThenTrack:
        startTeachingFromBurst(ended.burst);
        taught_burst_ = std::move(ended);
        return;
      case Step::kTrackOncePrior: taught_burst_ = std::move(ended); return;
      case Step::kTrack: return window_worker_->submit(window_tracker_, std::move(ended.burst));
      case Step::kDropUnusable: return window_worker_->dropped(ended, ended.problem);
      case Step::kDropNoPrior: return window_worker_->dropped(ended, "no prior to track with yet");
      case Step::kCannotTeach:
        NODELET_WARN_THROTTLE(5.0, "PatternTracker: cannot teach from the burst of %d light-on frames that ended: %s",
                              ended.light_on_frames, ended.problem.c_str());
        return;
    }
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    const core::StatusSummary summary = plan_.summary(prior_write_->pending(), prior_write_->error());
    status.summary(toDiagnosticLevel(summary.level), summary.text);
    status.add("prior file", prior_file_);
    status.add("prior state", core::toString(plan_.state()));
    status.add("prior file written", !prior_write_->pending());
    status.add("teach requested", plan_.teachRequested());
    figures_.report(status);
    status.add("scene background", background_use_);
    status.add("last frame (ms)", figures_.last_ms);
    status.add("mean frame (ms)", figures_.frames > 0 ? figures_.total_ms / figures_.frames : 0.0);
    if (window_worker_)
      window_worker_->diagnose(status);
    else
      status.add("window tracking", "off");
  }

  double stale_background_level_ = 0.0;        // parameter, see TrackerOptions
  std::string prior_file_, device_config_;
  core::SimRigConfig device_;
  std::unique_ptr<FrameInput> input_;  // created in initialise, before any callback
  ros::Publisher observations_pub_;
  ros::ServiceServer teach_srv_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::WallTimer diagnostics_timer_;

  // Teaching.
  core::TeachingPlan plan_;
  TeachingRun teaching_;  // waits for a teaching under way when destroyed
  std::optional<EndedBurst> taught_burst_;            // ended while teaching ran: tracked once taught
  std::optional<PriorWriteRetry> prior_write_;  // set in initialise
  GroundTruthPairing truth_;  // teach_from_ground_truth, subscribed while teaching waits

  // Tracking each frame.
  std::unique_ptr<core::PatternTracker> tracker_;
  ImageConstPtr light_off_left_, light_off_right_;  // latest settled light-off pair
  ros::Time background_stamp_;                      // stamp of the pair the tracker has as background
  std::string background_use_ = "none yet";         // what the last tracked frame did with the background
  TrackingFigures figures_;

  // Window tracking, and teaching from a burst.
  bool window_tracking_ = false;  // parameter
  core::WindowTrackerOptions window_options_;
  std::optional<LightBurstCollector> bursts_;           // set in initialise
  std::shared_ptr<core::WindowTracker> window_tracker_;  // null without a prior
  std::unique_ptr<WindowTrackingWorker> window_worker_;  // window_tracking only
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::PatternTrackerNodelet, nodelet::Nodelet)
