// PatternTracker nodelet: finds the embedded device's board corners in every settled light-on
// stereo frame (calibration_mode light_on && settled, ExactTime with left|right/image_raw) and
// publishes them on calibration/observations with the images' header. Idle in depth mode (light
// off): it only keeps the latest settled light-off pair (the shared message pointers, zero-copy)
// and hands it to the core tracker as scene background at the first light-on frame after it.
//
// The tracker starts from a taught prior (param prior_file). Teaching (service ~teach, or
// automatically when the file is missing and teach_on_start is true) writes the prior
// atomically (temp file + rename) and starts tracking. teach_from chooses what it teaches on:
//  - burst (default): the next light burst, on the device image learned from its light pairs
//    (core/tracker/window_teacher.h): its first kTeachLightOnFrames settled light-on frames with
//    the settled light-off frame before it (or a shorter burst of at least 3 when it ends; a
//    prior that misses boards so is taught again at the end of a burst, with light-off frames on
//    both sides). No covered or still scene needed, so a moving head teaches itself. With
//    window_tracking that burst is then tracked as any other;
//  - light_off: the next settled light-on frame with the latest settled light-off frame (the
//    scene cancels in their difference): the factory step, with the scene covered or still.
// A corrupt prior file leaves the nodelet idle with an error naming the file until teaching
// runs. A prior taught but not written (a full disk) is tracked with from memory and written
// again every kPriorRetryS until it is.
// For tests of other components only, teach_from_ground_truth teaches on a light-on frame minus
// the simulator's ground_truth/left|right/image_scene of the same stamp. No product launch file
// sets it (test/rostest/product_launch_truth.test checks).
//
// With window_tracking, it also tracks each light burst as a whole (core WindowTracker: the
// device image learned from the burst's light pairs, free of the moving scene's pull that every
// frame of a burst shares): it keeps the message pointers of the burst's settled light-on frames
// and of the last settled light-off frame before it, and at the first settled light-off frame
// after it hands them to its worker thread, which publishes one observation for the burst on
// calibration/window_observations, stamped with the burst's last light-on frame. With
// scene_matches (default), that observation also carries the scene correspondences of the
// light-off frames before and after the burst (guided by device_config's nominal cameras): the
// calibrator's epipolar constraints at every depth.
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/package.h>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <opencv2/imgproc.hpp>

#include <chrono>
#include <condition_variable>
#include <deque>
#include <fstream>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/core/geometry/config_error.h"
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/lazy_synced_input.h"
#include "embedded_calibration_stereo/ros/light_burst.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/tracker_teaching.h"

namespace embedded_calibration_stereo {

namespace {

using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

enum class PriorState { kLoaded, kMissing, kCorrupt, kTeaching, kTeachFailed };

const char* toString(PriorState s) {
  switch (s) {
    case PriorState::kLoaded: return "loaded";
    case PriorState::kMissing: return "missing";
    case PriorState::kCorrupt: return "corrupt";
    case PriorState::kTeaching: return "teaching";
    case PriorState::kTeachFailed: return "teaching failed";
  }
  return "?";
}

}  // namespace

// Threads:
//  - the nodelet's single-threaded callback queue runs frameCb, the ~teach service, the connect
//    callbacks, the diagnostics timer and the prior write retry timer: all state below is
//    touched there only.
//    The ground-truth scene subscribers (teach_from_ground_truth, while teaching waits) run there
//    too. Tracking runs in frameCb (both cameras in parallel through cv::parallel_for_): it takes a
//    fraction of a frame period, so it needs no thread of its own;
//  - teaching (learning a burst's device image, cv::findChessboardCornersSB: many frame periods
//    long) runs on a std::async worker that receives copies of the frames (or the burst's message
//    pointers, never written) and the device model and returns a TeachOutcome through
//    teach_result_; frameCb collects it when ready. The destructor waits for it;
//  - window tracking (window_tracking; seconds per burst) runs on window_worker_ (started in
//    onInit, joined in the destructor): frameCb collects a burst's message pointers (bursts_,
//    callback queue only) and hands them over with the WindowTracker in force (a shared_ptr:
//    a new prior makes a new tracker, the worker finishes with the one it got) through
//    window_job_ (one burst waits while the worker is busy: the newest); the worker alone runs
//    that tracker and publishes on window_observations_pub_. window_mutex_ guards window_job_,
//    window_stopping_ and the window figures;
//  - input_ (un)subscribes the inputs under its own mutex (lazy_synced_input.h).
class PatternTrackerNodelet : public GuardedNodelet {
 public:
  PatternTrackerNodelet() : GuardedNodelet("PatternTracker") {}
  ~PatternTrackerNodelet() override {
    stopWindowWorker();
    if (teach_result_.valid()) teach_result_.wait();
  }

 private:
  using FrameInput = LazySyncedInput<Image, Image, CalibrationMode>;
  // One burst handed to the worker.
  struct WindowJob {
    std::shared_ptr<ecs::WindowTracker> tracker;
    ImageConstPtr light_off_before[2], light_off_after[2];
    std::vector<ImageConstPtr> light_on[2];
    std_msgs::Header header;  // the last light-on frame's
  };


  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const std::string package_path = ros::package::getPath("embedded_calibration_stereo");
    const ParameterReader read(pnh);
    prior_file_ = read.get("prior_file", defaultPatternPriorFile());
    device_config_ = read.get("device_config", package_path + "/config/sim_rig.yaml");
    const bool teach_on_start = read.get("teach_on_start", true);
    teach_from_truth_ = read.get("teach_from_ground_truth", false);
    // The test-only truth teaching takes precedence over teach_from.
    teach_from_burst_ = read.choice("teach_from", "burst", {"burst", "light_off"}) == "burst" && !teach_from_truth_;
    const int queue_size = read.atLeast("queue_size", 10, 1);
    stale_background_level_ = read.atLeast("stale_background_level", ecs::TrackerOptions().stale_background_level, 0.0);
    window_tracking_ = read.get("window_tracking", false);
    window_options_.scene_matches = read.get("scene_matches", true);
    try {
      device_ = ecs::loadSimRigConfig(device_config_);
    } catch (const std::exception& e) {
      throw ecs::ConfigError("device_config", "'" + device_config_ + "': " + e.what());
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
      window_observations_pub_ = nh.advertise<StereoPatternObservation>("calibration/window_observations", 10, cb, cb);
      input_->watch(window_observations_pub_);
      window_worker_ = std::thread(&PatternTrackerNodelet::windowWorkerLoop, this);
    }
    updateNeed();
    input_->start();  // subscribes the inputs while someone listens or teaching waits
    NODELET_INFO("PatternTracker: prior %s (%s), device %s%s", prior_file_.c_str(), toString(state_),
                 device_config_.c_str(),
                 window_tracking_ ? ", window tracking on (one observation per light burst on "
                                    "calibration/window_observations)"
                                  : "");
  }

  void loadPrior(bool teach_on_start) {
    if (!std::ifstream(prior_file_).good()) {
      state_ = PriorState::kMissing;
      teach_requested_ = teach_on_start;
      if (!teach_on_start) NODELET_ERROR("%s", idleMessage().c_str());
      return;
    }
    try {
      startTracking(ecs::readPatternPrior(prior_file_));
    } catch (const std::exception& e) {
      state_ = PriorState::kCorrupt;
      prior_error_ = e.what();
      NODELET_ERROR("%s", idleMessage().c_str());
    }
  }

  // Throws ConfigError (or std::invalid_argument) when the prior is unusable.
  void startTracking(const ecs::PatternPrior& prior) {
    if (prior.cameras.size() != 2)
      throw std::invalid_argument("expected 2 cameras (left, right), found " + std::to_string(prior.cameras.size()));
    ecs::TrackerOptions options;
    options.stale_background_level = stale_background_level_;
    auto window_tracker =
        window_tracking_ ? std::make_shared<ecs::WindowTracker>(prior, options, window_options_, device_.rig) : nullptr;
    tracker_ = std::make_unique<ecs::PatternTracker>(prior, options);
    window_tracker_ = std::move(window_tracker);  // the worker keeps the previous one until its window is done
    background_stamp_ = ros::Time();  // the tracker has no background yet
    state_ = PriorState::kLoaded;
    prior_error_.clear();
  }

  std::string teachServiceName() const { return getPrivateNodeHandle().resolveName("teach"); }

  std::string idleMessage() const {
    const std::string why = state_ == PriorState::kMissing       ? "is missing"
                            : state_ == PriorState::kTeachFailed ? "was not taught (" + prior_error_ + ")"
                                                                 : "is unusable (" + prior_error_ + ")";
    return "PatternTracker: prior file '" + prior_file_ + "' " + why + "; idle until teaching (service " +
           teachServiceName() + ")";
  }

  // Inputs are needed, whoever listens, while teaching waits for a frame or runs; the simulator's
  // scene only while teaching waits for a frame (the driver renders it only for subscribers).
  void updateNeed() {
    input_->need(teach_requested_ || state_ == PriorState::kTeaching);
    if (!teach_from_truth_) return;
    if (teach_requested_ && !truth_scene_sub_[0]) {
      ros::NodeHandle& nh = getNodeHandle();
      for (int c = 0; c < 2; ++c)
        truth_scene_sub_[c] = nh.subscribe<Image>(c == 0 ? "ground_truth/left/image_scene" : "ground_truth/right/image_scene", 5,
                                                  [this, c](const ImageConstPtr& msg) { truthSceneCb(c, msg); });
    } else if (!teach_requested_ && truth_scene_sub_[0]) {
      for (ros::Subscriber& sub : truth_scene_sub_) sub.shutdown();
      for (auto& q : truth_scenes_) q.clear();
      pending_light_on_.clear();
    }
  }

  void truthSceneCb(int camera, const ImageConstPtr& msg) {
    auto& q = truth_scenes_[camera];
    q.push_back(msg);
    while (q.size() > kTruthQueue) q.pop_front();
    teachFromTruthIfMatched();
  }

  static ImageConstPtr byStamp(const std::deque<ImageConstPtr>& q, const ros::Time& stamp) {
    for (const ImageConstPtr& m : q)
      if (m->header.stamp == stamp) return m;
    return nullptr;
  }

  // Teaches on the newest pending light-on pair whose ground-truth scenes have arrived.
  void teachFromTruthIfMatched() {
    if (!teach_requested_) return;
    for (auto it = pending_light_on_.rbegin(); it != pending_light_on_.rend(); ++it) {
      const ImageConstPtr scene_left = byStamp(truth_scenes_[0], it->first->header.stamp);
      const ImageConstPtr scene_right = byStamp(truth_scenes_[1], it->first->header.stamp);
      if (!scene_left || !scene_right) continue;
      if (scene_left->encoding != it->first->encoding || scene_left->width != it->first->width ||
          scene_left->height != it->first->height) {
        NODELET_ERROR_THROTTLE(5.0, "PatternTracker: ground_truth/left/image_scene (%s %ux%u) does not match %s; "
                               "cannot teach from it", scene_left->encoding.c_str(), scene_left->width,
                               scene_left->height, input_->topic(0).c_str());
        return;
      }
      const auto light_on = *it;
      cv_bridge::CvImageConstPtr left_cv, right_cv;
      ecs::ColorOrder order;
      if (!toImages(light_on.first, light_on.second, &left_cv, &right_cv, &order)) return;
      NODELET_INFO("PatternTracker: teaching on a light-on frame minus the simulator's scene of the same stamp");
      startTeaching(left_cv->image, right_cv->image, cv_bridge::toCvShare(scene_left)->image,
                    cv_bridge::toCvShare(scene_right)->image, order);
      return;
    }
  }

  bool teachCb(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    if (state_ == PriorState::kTeaching) {
      res.success = false;
      res.message = "busy: teaching is running";
      return true;
    }
    teach_requested_ = true;
    updateNeed();
    res.success = true;
    res.message = std::string(teach_from_burst_ ? "teaching at the next light burst"
                                                                      : "teaching at the next settled light-on frame") +
                  "; prior file " + prior_file_;
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
    cv_bridge::CvImageConstPtr left_cv, right_cv;
    ecs::ColorOrder order;
    if (!toImages(left, right, &left_cv, &right_cv, &order)) return;
    if (teach_requested_ && teach_from_truth_) {
      pending_light_on_.emplace_back(left, right);
      while (pending_light_on_.size() > kTruthQueue) pending_light_on_.pop_front();
      teachFromTruthIfMatched();
      if (!teach_requested_) return;
      NODELET_WARN_THROTTLE(5.0, "PatternTracker: teaching waits for ground_truth/left|right/image_scene of a "
                            "settled light-on frame (teach_from_ground_truth is set)");
    } else if (teach_requested_ && teach_from_burst_) {
      LightBurst now = bursts_->underWay();
      if (!teach_at_burst_end_ && static_cast<int>(now.light_on.size()) >= kTeachLightOnFrames)
        return startTeachingFromBurst(std::move(now));
      NODELET_INFO_THROTTLE(30.0, "PatternTracker: teaching waits for a light burst of %d settled light-on frames on "
                            "%s", kTeachLightOnFrames, input_->topic(0).c_str());
    } else if (teach_requested_) {
      // Teaching needs the scene to cancel: without a light-off frame most boards are missed.
      if (lightOffMatches(*left)) {
        startTeaching(left_cv->image, right_cv->image, cv_bridge::toCvShare(light_off_left_)->image,
                      cv_bridge::toCvShare(light_off_right_)->image, order);
        return;
      }
      NODELET_WARN_THROTTLE(5.0, "PatternTracker: teaching waits for a settled light-off frame on %s",
                            input_->topic(0).c_str());
    }
    if (!tracker_) {
      if (state_ != PriorState::kTeaching && !teach_requested_)
        NODELET_ERROR_THROTTLE(5.0, "%s", idleMessage().c_str());
      return;
    }
    track(left, left_cv->image, right_cv->image, order);
  }

  bool toImages(const ImageConstPtr& left, const ImageConstPtr& right, cv_bridge::CvImageConstPtr* left_cv,
                cv_bridge::CvImageConstPtr* right_cv, ecs::ColorOrder* order) {
    if (left->encoding != right->encoding || left->width != right->width || left->height != right->height) {
      NODELET_ERROR_THROTTLE(5.0, "PatternTracker: %s and %s differ (%s %ux%u vs %s %ux%u); frame dropped",
                             input_->topic(0).c_str(), input_->topic(1).c_str(), left->encoding.c_str(),
                             left->width, left->height, right->encoding.c_str(), right->width, right->height);
      return false;
    }
    if (left->encoding != "mono8" && left->encoding != "bgr8" && left->encoding != "rgb8") {
      NODELET_ERROR_THROTTLE(5.0, "PatternTracker: %s has encoding '%s' (expected mono8, bgr8 or rgb8); frame dropped",
                             input_->topic(0).c_str(), left->encoding.c_str());
      return false;
    }
    try {
      *left_cv = cv_bridge::toCvShare(left);
      *right_cv = cv_bridge::toCvShare(right);
    } catch (const cv_bridge::Exception& e) {
      NODELET_ERROR_THROTTLE(5.0, "PatternTracker: cannot read %s: %s", input_->topic(0).c_str(), e.what());
      return false;
    }
    *order = left->encoding == "rgb8" ? ecs::ColorOrder::kRgb : ecs::ColorOrder::kBgr;
    return true;
  }

  // The latest settled light-off pair exists and has the format of this light-on frame.
  bool lightOffMatches(const Image& light_on) const {
    return light_off_left_ && light_off_left_->width == light_on.width && light_off_left_->height == light_on.height &&
           light_off_left_->encoding == light_on.encoding;
  }

  // `left_off`/`right_off`: the scene without the device (light-off frame, or the sim's truth),
  // same format as the light-on frames.
  void startTeaching(const cv::Mat& left, const cv::Mat& right, const cv::Mat& left_off, const cv::Mat& right_off,
                     ecs::ColorOrder order) {
    teach_requested_ = false;
    updateNeed();  // the ground-truth scene is no longer needed
    ecs::TeachFrame left_frame, right_frame;
    left_frame.light_on = left.clone();  // the worker outlives this callback's messages
    right_frame.light_on = right.clone();
    left_frame.light_off = left_off.clone();
    right_frame.light_off = right_off.clone();
    beginTeaching();
    NODELET_INFO("PatternTracker: teaching from a light-on frame and the latest light-off frame (worker thread)");
    teach_result_ = std::async(std::launch::async, teachStereoPrior, left_frame, right_frame, order, device_,
                               prior_file_);
  }

  // Teaches on the device image learned from a burst's light pairs (worker thread): a burst
  // under way (its light-on frames so far with the light-off frame before it) or one that ended.
  void startTeachingFromBurst(LightBurst burst) {
    teach_requested_ = false;
    teach_at_burst_end_ = false;
    beginTeaching();
    partial_teach_ = !burst.light_off_after.first;
    NODELET_INFO("PatternTracker: teaching on the device image learned from %zu light-on frames of a burst "
                 "(worker thread)", burst.light_on.size());
    teach_result_ = std::async(std::launch::async, [burst = std::move(burst), device = device_,
                                                    path = prior_file_] {
      TeachOutcome out;
      try {
        const ecs::WindowFrames left = windowFrames(burst, 0), right = windowFrames(burst, 1);
        return teachStereoPriorFromBurst(left, right, device, path);
      } catch (const std::exception& e) {  // an image cv_bridge cannot read
        out.error = e.what();
      }
      return out;
    });
  }

  void beginTeaching() {
    state_ = PriorState::kTeaching;
    tracker_.reset();
    window_tracker_.reset();
    taught_burst_.reset();
    unwritten_prior_.reset();  // the new teaching's prior replaces it
  }

  void collectTeaching() {
    if (!teach_result_.valid() ||
        teach_result_.wait_for(std::chrono::seconds(0)) != std::future_status::ready)
      return;
    const TeachOutcome outcome = teach_result_.get();
    if (outcome.error.empty()) {
      try {
        startTracking(outcome.prior);
        if (outcome.write_error.empty()) {
          unwritten_prior_.reset();
          NODELET_INFO("PatternTracker: taught %zu + %zu boards in %.0f ms, prior written to %s (%s)",
                       outcome.prior.cameras[0].boards.size(), outcome.prior.cameras[1].boards.size(), outcome.ms,
                       prior_file_.c_str(), outcome.notes.c_str());
        } else {
          // Tracking needs no file: keep the prior in memory and write it when the disk allows.
          unwritten_prior_ = outcome.prior;
          prior_write_error_ = outcome.write_error;
          NODELET_ERROR("PatternTracker: taught %zu + %zu boards in %.0f ms and tracking, but the prior file '%s' "
                        "could not be written (%s); trying again every %.0f s",
                        outcome.prior.cameras[0].boards.size(), outcome.prior.cameras[1].boards.size(), outcome.ms,
                        prior_file_.c_str(), outcome.write_error.c_str(), kPriorRetryS);
          prior_retry_timer_ = getNodeHandle().createWallTimer(
              ros::WallDuration(kPriorRetryS), [this](const ros::WallTimerEvent&) { retryPriorWrite(); });
        }
        updateNeed();
        teachAgainIfBoardsMissing(outcome.prior);
        if (taught_burst_) endBurst(std::move(*taught_burst_));  // tracked with the prior it taught
        taught_burst_.reset();
        return;
      } catch (const std::exception& e) {
        prior_error_ = e.what();
      }
    } else {
      prior_error_ = outcome.error;
    }
    state_ = PriorState::kTeachFailed;
    NODELET_ERROR("%s", idleMessage().c_str());
    updateNeed();
  }

  // A prior taught on a burst under way (one-sided light pairs: more scene left in the device
  // image) that misses boards is taught again at the end of a burst, once; it is tracked with
  // meanwhile.
  void teachAgainIfBoardsMissing(const ecs::PatternPrior& prior) {
    const bool partial = partial_teach_;
    partial_teach_ = false;
    const size_t boards = device_.device.virtualBoards().size();
    if (!partial || (prior.cameras[0].boards.size() >= boards && prior.cameras[1].boards.size() >= boards)) return;
    NODELET_INFO("PatternTracker: %zu + %zu of %zu boards taught on the first light-on frames of a burst; teaching "
                 "again at the end of a burst", prior.cameras[0].boards.size(), prior.cameras[1].boards.size(), boards);
    teach_requested_ = true;
    teach_at_burst_end_ = true;
  }

  // Retry timer: writes the prior taught but not written yet; stops once written (or replaced
  // by another teaching).
  void retryPriorWrite() {
    if (!unwritten_prior_) {
      prior_retry_timer_.stop();
      return;
    }
    const std::string error = writeStereoPrior(prior_file_, *unwritten_prior_);
    if (error.empty()) {
      NODELET_INFO("PatternTracker: prior written to %s (it could not be written when taught)", prior_file_.c_str());
      unwritten_prior_.reset();
      prior_write_error_.clear();
      prior_retry_timer_.stop();
      return;
    }
    prior_write_error_ = error;
    NODELET_WARN_THROTTLE(60.0, "PatternTracker: the prior file '%s' still cannot be written (%s); trying again every %.0f s",
                          prior_file_.c_str(), error.c_str(), kPriorRetryS);
  }

  void track(const ImageConstPtr& left_msg, const cv::Mat& left, const cv::Mat& right, ecs::ColorOrder order) {
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
      const ecs::CameraTracker& left_tracker = tracker_->camera(0);
      background_use_ = left_tracker.background().empty() ? "none: raw images, boards aligned whole"
                        : left_tracker.lastBackgroundStale()
                            ? "light-off frame stale (scene moved): raw images, boards aligned whole"
                            : "light-off frame";
    } catch (const std::exception& e) {
      NODELET_ERROR_THROTTLE(5.0, "PatternTracker: tracking failed on %s: %s", input_->topic(0).c_str(),
                             e.what());
      return;
    }
    msg.header = left_msg->header;
    observations_pub_.publish(msg);
    last_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    total_ms_ += last_ms_;
    ++tracked_frames_;
    for (int c = 0; c < 2; ++c) {
      const auto& boards = c == 0 ? msg.left : msg.right;
      boards_found_[c] = boards.size();
      corners_found_[c] = 0;
      for (const BoardObservation& b : boards) corners_found_[c] += b.corner_ids.size();
    }
  }

  // ---- window tracking (window_tracking)

  // Callback queue: a burst ended (the first settled light-off frame after it). One that ends
  // while teaching runs waits for the prior (it is usually the one taught on).
  void endBurst(EndedBurst ended) {
    if (teach_requested_ && teach_from_burst_ && ended.problem.empty()) {
      startTeachingFromBurst(ended.burst);
      if (window_tracking_) taught_burst_ = std::move(ended);  // tracked with the prior it teaches
      return;
    }
    if (state_ == PriorState::kTeaching && window_tracking_ && ended.problem.empty()) {
      taught_burst_ = std::move(ended);
      return;
    }
    if (!window_tracking_) {
      if (teach_requested_ && teach_from_burst_)
        NODELET_WARN_THROTTLE(5.0, "PatternTracker: cannot teach from the burst of %d light-on frames that ended: %s",
                              ended.light_on_frames, ended.problem.c_str());
      return;
    }
    std::string problem = ended.problem;
    if (problem.empty() && !window_tracker_) problem = "no prior to track with yet";
    if (problem.empty()) {
      WindowJob job;
      job.tracker = window_tracker_;
      job.light_off_before[0] = ended.burst.light_off_before.first;
      job.light_off_before[1] = ended.burst.light_off_before.second;
      job.light_off_after[0] = ended.burst.light_off_after.first;
      job.light_off_after[1] = ended.burst.light_off_after.second;
      for (const StereoImages& on : ended.burst.light_on) {
        job.light_on[0].push_back(on.first);
        job.light_on[1].push_back(on.second);
      }
      job.header = ended.burst.light_on.back().first->header;
      std::lock_guard<std::mutex> lock(window_mutex_);
      // While the worker tracks a burst, the newest one waits: after a change it is the one
      // that matters. A burst still waiting when a newer one ends is dropped.
      if (window_job_) {
        ++windows_dropped_;
        window_summary_ = "burst ending at " + std::to_string(window_job_->header.stamp.toSec()) +
                          " s dropped: a newer one ended while the worker was busy";
      }
      window_job_ = std::move(job);
    }
    if (problem.empty()) {
      window_cv_.notify_all();
      return;
    }
    char text[600];
    std::snprintf(text, sizeof(text), "burst of %d light-on frames ending at %.3f s dropped: %s", ended.light_on_frames,
                  ended.burst.light_off_after.first->header.stamp.toSec(),
                  problem.c_str());
    NODELET_WARN_THROTTLE(5.0, "PatternTracker: %s (window tracking, %s)", text,
                          window_observations_pub_.getTopic().c_str());
    std::lock_guard<std::mutex> lock(window_mutex_);
    ++windows_dropped_;
    window_summary_ = text;
  }

  // Window worker thread: tracks the bursts handed over, one at a time.
  void windowWorkerLoop() {
    while (true) {
      WindowJob job;
      {
        std::unique_lock<std::mutex> lock(window_mutex_);
        window_cv_.wait(lock, [this] { return window_stopping_ || window_job_.has_value(); });
        if (window_stopping_) return;
        job = std::move(*window_job_);
        window_job_.reset();
      }
      trackWindow(job);
    }
  }

  // Window worker thread.
  void trackWindow(const WindowJob& job) {
    const auto t0 = std::chrono::steady_clock::now();
    StereoPatternObservation msg;
    int corners = 0, saddle_failures = 0;
    std::string error, scene_problem;
    try {
      ecs::WindowFrames frames[2];
      for (int c = 0; c < 2; ++c) {
        frames[c].light_off_before.push_back(windowImage(job.light_off_before[c]));
        frames[c].light_off_after.push_back(windowImage(job.light_off_after[c]));
        for (const ImageConstPtr& m : job.light_on[c]) frames[c].light_on.push_back(windowImage(m));
      }
      const ecs::WindowTrack track = job.tracker->track(frames[0], frames[1], job.header.stamp.toSec());
      msg = toMsg(track.observation);
      saddle_failures = track.saddle_failures;
      scene_problem = track.scene_problem;
      for (const auto* side : {&msg.left, &msg.right})
        for (const BoardObservation& b : *side) corners += static_cast<int>(b.corner_ids.size());
    } catch (const std::exception& e) {
      error = e.what();
    }
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    char text[600];
    if (error.empty()) {
      msg.header = job.header;
      window_observations_pub_.publish(msg);
      std::snprintf(text, sizeof(text),
                    "burst of %zu light-on frames ending at %.3f s: %d corners (%d dropped by the saddle fit), "
                    "%zu scene correspondences, in %.0f ms",
                    job.light_on[0].size(), job.header.stamp.toSec(), corners, saddle_failures, msg.scene.size(), ms);
      if (!scene_problem.empty())
        NODELET_WARN_THROTTLE(30.0, "PatternTracker: %s (device_config %s)", scene_problem.c_str(),
                              device_config_.c_str());
    } else {
      std::snprintf(text, sizeof(text), "burst of %zu light-on frames ending at %.3f s not tracked: %s",
                    job.light_on[0].size(), job.header.stamp.toSec(), error.c_str());
      NODELET_ERROR_THROTTLE(5.0, "PatternTracker: %s (window tracking, %s)", text,
                             window_observations_pub_.getTopic().c_str());
    }
    std::lock_guard<std::mutex> lock(window_mutex_);
    window_summary_ = text;
    if (error.empty()) {
      ++windows_tracked_;
      window_last_ms_ = ms;
    } else {
      ++windows_dropped_;
    }
  }

  void stopWindowWorker() {
    {
      std::lock_guard<std::mutex> lock(window_mutex_);
      window_stopping_ = true;
    }
    window_cv_.notify_all();
    if (window_worker_.joinable()) window_worker_.join();
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    using diagnostic_msgs::DiagnosticStatus;
    switch (state_) {
      case PriorState::kLoaded:
        if (unwritten_prior_)
          status.summary(DiagnosticStatus::WARN, "tracking; prior file not written yet: " + prior_write_error_);
        else
          status.summary(DiagnosticStatus::OK, "tracking");
        break;
      case PriorState::kTeaching: status.summary(DiagnosticStatus::OK, "teaching"); break;
      case PriorState::kMissing:
        status.summary(teach_requested_ ? DiagnosticStatus::WARN : DiagnosticStatus::ERROR,
                       !teach_requested_   ? "prior missing: idle until teaching"
                       : teach_from_burst_ ? "prior missing: teaching at the next light burst"
                                           : "prior missing: teaching at the next settled light-on frame");
        break;
      case PriorState::kCorrupt:
      case PriorState::kTeachFailed:
        status.summary(teach_requested_ ? DiagnosticStatus::WARN : DiagnosticStatus::ERROR,
                       std::string(toString(state_)) + ": " + prior_error_);
        break;
    }
    status.add("prior file", prior_file_);
    status.add("prior state", toString(state_));
    status.add("prior file written", !unwritten_prior_);
    status.add("teach requested", teach_requested_);
    status.add("frames tracked", tracked_frames_);
    status.add("left boards found", boards_found_[0]);
    status.add("left corners found", corners_found_[0]);
    status.add("right boards found", boards_found_[1]);
    status.add("right corners found", corners_found_[1]);
    status.add("scene background", background_use_);
    status.add("last frame (ms)", last_ms_);
    status.add("mean frame (ms)", tracked_frames_ > 0 ? total_ms_ / tracked_frames_ : 0.0);
    if (!window_tracking_) {
      status.add("window tracking", "off");
      return;
    }
    std::lock_guard<std::mutex> lock(window_mutex_);
    status.add("window tracking", window_summary_);
    status.add("windows tracked", windows_tracked_);
    status.add("windows dropped", windows_dropped_);
    status.add("last window (ms)", window_last_ms_);
  }

  double stale_background_level_ = 0.0;  // parameter, see TrackerOptions
  bool teach_from_truth_ = false;         // parameter teach_from_ground_truth (tests only)
  bool teach_from_burst_ = true;          // parameter teach_from, false with teach_from_ground_truth
  // Teaching from a burst starts once it has this many settled light-on frames (or at its end):
  // a forced recalibration holds the light on until it has observations.
  static constexpr int kTeachLightOnFrames = 8;
  std::optional<EndedBurst> taught_burst_;  // ended while teaching ran: tracked once taught (window tracking)
  bool partial_teach_ = false;       // the teaching running is on a burst under way
  bool teach_at_burst_end_ = false;  // teach again, at the end of a burst only
  static constexpr size_t kTruthQueue = 5;  // frames kept while matching light-on frames to the truth
  ros::Subscriber truth_scene_sub_[2];
  std::deque<ImageConstPtr> truth_scenes_[2];
  std::deque<std::pair<ImageConstPtr, ImageConstPtr>> pending_light_on_;
  std::string background_use_ = "none yet";  // what the last tracked frame did with the background
  std::string prior_file_, device_config_;
  ecs::SimRigConfig device_;
  std::unique_ptr<FrameInput> input_;  // created in onInit, before any callback
  ros::Publisher observations_pub_;
  ros::ServiceServer teach_srv_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::WallTimer diagnostics_timer_;

  PriorState state_ = PriorState::kMissing;
  std::string prior_error_;
  bool teach_requested_ = false;
  std::future<TeachOutcome> teach_result_;
  static constexpr double kPriorRetryS = 3.0;  // s between writes of a prior that could not be written
  std::optional<ecs::PatternPrior> unwritten_prior_;  // taught, in use, not in the file yet
  std::string prior_write_error_;
  ros::WallTimer prior_retry_timer_;
  std::unique_ptr<ecs::PatternTracker> tracker_;
  ImageConstPtr light_off_left_, light_off_right_;  // latest settled light-off pair
  ros::Time background_stamp_;                      // stamp of the pair the tracker has as background
  uint64_t tracked_frames_ = 0;
  size_t boards_found_[2] = {0, 0}, corners_found_[2] = {0, 0};
  double last_ms_ = 0.0, total_ms_ = 0.0;

  // Window tracking (see the class comment for the threads).
  bool window_tracking_ = false;  // parameter
  ecs::WindowTrackerOptions window_options_;  // set in onInit
  std::shared_ptr<ecs::WindowTracker> window_tracker_;  // null without a prior; callback queue
  std::optional<LightBurstCollector> bursts_;           // set in onInit; callback queue
  ros::Publisher window_observations_pub_;
  std::thread window_worker_;
  std::mutex window_mutex_;  // guards everything below
  std::condition_variable window_cv_;
  std::optional<WindowJob> window_job_;  // handed over, not taken by the worker yet
  bool window_stopping_ = false;
  std::string window_summary_ = "no burst yet";  // the last burst: tracked (corners, ms) or why not
  uint64_t windows_tracked_ = 0, windows_dropped_ = 0;
  double window_last_ms_ = 0.0;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::PatternTrackerNodelet, nodelet::Nodelet)
