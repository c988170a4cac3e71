// OnlineCalibrator nodelet: collects the board observations of each light-on window (frames
// whose calibration_mode is light_on && settled, matched by stamp), solves on a worker thread,
// and on acceptance commits through the driver's set_camera_info services and /tf_static
// (CalibrationSession). calibration/recalibrate switches the light on, collects, solves,
// commits unless dry_run or rejected, switches the light off and answers with the status; one
// request at a time (a second one is answered "busy" at once, naming the caller holding it),
// and nothing is solved or committed when set_light fails either way. A request is bounded:
// frames at most max_frames, timeout_s at most max_request_timeout_s (a non-finite one is
// refused), every driver service call at most service_timeout_s to appear and as much to
// answer, and a caller that goes away (killed) ends it early; the light is switched off on
// every way out. Inputs whose stamps lie far from the others' are dropped (stamp_guard.h), an
// observation is counted once per stamp, and an automatic window to which no settled frame was
// added for window_timeout_s ends (solved when it has min_frames). An accepted calibration the
// driver could not store is committed again every commit_retry_s while the calibration in force
// is unchanged and no later solve replaced it.
// With window_observations, the automatic windows come from the PatternTracker's
// calibration/window_observations instead (one observation per light burst, tracked as a whole,
// seconds after the burst): each one is solved as a window of one frame, and the windows of
// per-frame observations are not. calibration/recalibrate then holds the light for a whole
// burst (max_frames settled frames with boards by default) and solves the window observation
// of that burst, as the automatic windows are solved; only when none comes within
// kRequestWindowWaitS of the light going off are the burst's per-frame observations solved.
// Each window is solved again with what the earlier ones taught (prior_from_earlier_windows);
// a calibration/health verdict below GOOD since then (when a health nodelet runs) says the rig
// changed: the stereo rotation and focal lengths then get no prior.
// For a bag replay (launch/replay.launch: no driver, use_sim_time) the parameter commit:=none
// solves and gates every window as usual but commits nowhere except /tf_static; only header
// stamps (sim time) order the frames, and solve durations are wall time.
#include <diagnostic_updater/diagnostic_updater.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/callback_queue.h>
#include <ros/package.h>
#include <ros/ros.h>
#include <std_srvs/SetBool.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/core/calibration/repeated_observations.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/caller_probe.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/service_call.h"
#include "embedded_calibration_stereo/ros/stamp_guard.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

// Threads:
//  - the manager's single-threaded queue of this nodelet runs the subscribers (observations,
//    window observations, calibration_mode, camera_info), the diagnostics timer, the window age timer and the commit
//    retry timer (which only queues a job for the worker);
//  - calibration/recalibrate runs on this nodelet's own service queue and its two spinner
//    threads: a call blocks while the window fills and the worker solves (up to timeout_s), and
//    on the manager's shared pool it would hold one of its worker threads that long (with 4
//    threads, the tracker and the depth nodelets then fell behind and dropped frames during the
//    call); the second thread answers a call arriving meanwhile ("busy") instead of queueing it;
//    the running call probes its caller (CallerProbe) and the driver's services (callService:
//    a thread per call, detached if it does not answer in time) without holding mutex_;
//  - the worker thread (started in onInit, joined in the destructor) alone runs session_, and
//    after a commit waits for the driver's first frame carrying it (its epoch).
// Everything they share is guarded by mutex_; session_->boards() is immutable after onInit;
// guard_ (created before the subscribers) locks itself.
class OnlineCalibratorNodelet : public GuardedNodelet {
 public:
  OnlineCalibratorNodelet() : GuardedNodelet("OnlineCalibrator") {}
  ~OnlineCalibratorNodelet() override {
    stopWorker();  // a recalibrate call in progress sees stopping_ and returns
    if (service_spinner_) service_spinner_->stop();
    recalibrate_srv_.shutdown();
  }

 private:
  struct Job {
    std::vector<core::StereoObservation> frames;
    bool dry_run = false;
    std::shared_ptr<std::promise<CalibrationStatus>> result;  // null for automatic windows
    bool commit_again = false;  // no solve: commit uncommitted_ again
    bool window_observation = false;  // frames: one observation of a whole window
  };

  void releaseAfterFailedStart() override {
    // The manager frees a failed nodelet's callback queues first: unregister everything now.
    stopWorker();
    if (service_spinner_) service_spinner_->stop();
    recalibrate_srv_.shutdown();
    diagnostics_timer_.stop();
    window_timer_.stop();
    commit_retry_timer_.stop();
    for (ros::Subscriber* sub :
         {&observations_sub_, &window_observations_sub_, &mode_sub_, &left_info_sub_, &right_info_sub_, &health_sub_})
      sub->shutdown();
  }

  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const std::string package_path = ros::package::getPath("embedded_calibration_stereo");
    params_ = loadCalibratorParams(pnh, package_path.empty() ? "" : package_path + "/config/sim_rig.yaml");
    core::CalibrationDevice device;
    std::optional<core::StereoRig> nominal;
    try {
      cv::FileStorage fs = core::openYaml(params_.device_config);
      device = core::loadDevice(fs["device"], "device");
      if (!fs["rig"].empty()) nominal = core::loadStereoRig(fs["rig"], "rig");
    } catch (const std::exception& e) {
      throw core::ConfigError("device_config", "'" + params_.device_config + "': " + e.what());
    }
    session_ = std::make_unique<CalibrationSession>(nh, params_, device, nominal);
    paced_ = std::make_unique<core::PacedQueue<Job>>(params_.solve_pacing);
    guard_ = std::make_unique<StampGuard>(
        std::vector<std::string>{nh.resolveName("calibration_mode"), nh.resolveName("calibration/observations"),
                                 nh.resolveName("left/camera_info"), nh.resolveName("right/camera_info")},
        params_.stamp_tolerance_s, "OnlineCalibrator",
        [this](const std::string& text) { NODELET_WARN("%s", text.c_str()); });

    status_pub_ = nh.advertise<CalibrationStatus>("calibration/status", 1, /*latch=*/true);
    observations_sub_ = nh.subscribe("calibration/observations", 10, &OnlineCalibratorNodelet::onObservation, this);
    if (params_.window_observations)
      window_observations_sub_ = nh.subscribe("calibration/window_observations", 10,
                                              &OnlineCalibratorNodelet::onWindowObservation, this);
    mode_sub_ = nh.subscribe("calibration_mode", 10, &OnlineCalibratorNodelet::onMode, this);
    left_info_sub_ = nh.subscribe<sensor_msgs::CameraInfo>(
        "left/camera_info", 1, [this](const sensor_msgs::CameraInfoConstPtr& m) { storeInfo(true, m); });
    right_info_sub_ = nh.subscribe<sensor_msgs::CameraInfo>(
        "right/camera_info", 1, [this](const sensor_msgs::CameraInfoConstPtr& m) { storeInfo(false, m); });
    // The health's verdicts below GOOD say that the rig changed since earlier windows.
    health_sub_ = nh.subscribe<CalibrationHealth>("calibration/health", 10, [this](const CalibrationHealthConstPtr& h) {
      if (h->state != CalibrationHealth::DEGRADED && h->state != CalibrationHealth::BAD) return;
      std::lock_guard<std::mutex> lock(mutex_);
      health_problem_s_ = std::max(health_problem_s_.value_or(0.0), h->header.stamp.toSec());
    });
    set_light_client_ = nh.serviceClient<std_srvs::SetBool>("set_light");  // exists() only: calls are bounded
    diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
    diagnostics_->setHardwareID("online_calibrator");
    diagnostics_->add("online_calibrator", this, &OnlineCalibratorNodelet::diagnose);
    diagnostics_timer_ = nh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
      diagnostics_->update();
    });
    window_timer_ = nh.createWallTimer(ros::WallDuration(0.25), [this](const ros::WallTimerEvent&) { endIdleWindow(); });
    if (params_.commit_retry_s > 0)
      commit_retry_timer_ = nh.createWallTimer(ros::WallDuration(params_.commit_retry_s),
                                               [this](const ros::WallTimerEvent&) { scheduleCommitAgain(); });
    worker_ = std::thread(&OnlineCalibratorNodelet::workerLoop, this);
    ros::NodeHandle service_nh(nh);
    service_nh.setCallbackQueue(&service_queue_);
    recalibrate_srv_ = service_nh.advertiseService("calibration/recalibrate", &OnlineCalibratorNodelet::recalibrate, this);
    service_spinner_ = std::make_unique<ros::AsyncSpinner>(2, &service_queue_);  // see the class comment
    service_spinner_->start();
    const std::string automatic =
        !params_.auto_calibrate       ? "solving on request only"
        : params_.window_observations ? "solving every window observation on " + window_observations_sub_.getTopic()
                                      : std::string("solving every light-on window");
    NODELET_INFO("OnlineCalibrator: device from %s (%zu virtual boards), observations on %s, %s, commit to %s",
                 params_.device_config.c_str(), session_->boards().size(), observations_sub_.getTopic().c_str(),
                 automatic.c_str(), params_.commit == CommitTarget::kDriver ? "the driver" : "none (tf_static only)");
  }

  void stopWorker() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopping_ = true;
    }
    cv_.notify_all();
    if (worker_.joinable()) worker_.join();
    std::lock_guard<std::mutex> lock(mutex_);
    for (Job& job : jobs_)
      if (job.result) job.result->set_value(rejectedStatus("calibrator shutting down"));
    jobs_.clear();
    if (paced_) paced_->clear();
  }

  // Keeps the latest valid CameraInfo pair: a side that fails the consumers' checks, or that
  // does not form a rectified pair with the other side of its stamp, is dropped with an error
  // (the pair in force stays); when the other side of its stamp has not arrived yet it waits.
  // The pair's geometry goes on /tf_static at once, so that tf (rviz, points2 users) has the
  // right camera before the first commit, and again whenever the pair in force changes (a commit,
  // or a calibration set from outside, such as the health monitor's rollback). A replay
  // (commit:=none) never sees its camera_info change, so its solves stay on /tf_static.
  void storeInfo(bool left, const sensor_msgs::CameraInfoConstPtr& info) {
    if (!guard_->admit(left ? kLeftInfoInput : kRightInfoInput, info->header.stamp)) return;
    const std::string topic = (left ? left_info_sub_ : right_info_sub_).getTopic();
    const std::string other_topic = (left ? right_info_sub_ : left_info_sub_).getTopic();
    std::string problem = checkCameraInfo(*info, topic, info->width, info->height);
    sensor_msgs::CameraInfoConstPtr left_info, right_info;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      auto& recent = left ? recent_left_infos_ : recent_right_infos_;  // every frame's, for the commit read-back
      recent.push_back(info);
      if (recent.size() > kKeptInfos) recent.pop_front();
      if (awaiting_commit_) cv_.notify_all();
      (left ? latest_left_info_ : latest_right_info_) = problem.empty() ? info : nullptr;
      const sensor_msgs::CameraInfoConstPtr other = left ? latest_right_info_ : latest_left_info_;
      if (problem.empty() && other) {
        const std::string mismatch = left ? checkRectifiedPair(*info, topic, *other, other_topic)
                                          : checkRectifiedPair(*other, other_topic, *info, topic);
        if (mismatch.empty()) {
          left_info_ = left ? info : other;
          right_info_ = left ? other : info;
          std::vector<double> key(left_info_->R.begin(), left_info_->R.end());
          key.insert(key.end(), right_info_->R.begin(), right_info_->R.end());
          key.insert(key.end(), right_info_->P.begin(), right_info_->P.end());
          if (key != in_force_tf_key_) {
            in_force_tf_key_ = std::move(key);
            left_info = left_info_;
            right_info = right_info_;
          }
        } else if (other->header.stamp == info->header.stamp) {
          problem = mismatch;  // the two sides of one frame disagree
        }
      }
    }
    if (!problem.empty()) {
      if (info_errors_.shouldReport(problem))
        NODELET_ERROR("OnlineCalibrator: camera_info dropped, the calibration in force is kept: %s", problem.c_str());
      return;
    }
    if (!left_info) return;
    core::StereoRig rig;
    std::string error;
    if (fromStereoCameraInfo(*left_info, *right_info, &rig, &error))
      session_->broadcastTransform(rig);
    else
      NODELET_WARN("OnlineCalibrator: no tf from the calibration in force yet: %s", error.c_str());
  }

  // Subscriber queue. The observation in `msg`; nothing when it has a defect, then *why says
  // which and it is counted as dropped. The caller logs (a throttle per input).
  std::optional<core::StereoObservation> validObservation(const StereoPatternObservation& msg, std::string* why) {
    core::StereoObservation observation = fromMsg(msg);
    const std::vector<std::string> defects = observationDefects(observation, session_->boards());
    if (defects.empty()) return observation;
    why->clear();
    for (const std::string& d : defects) *why += (why->empty() ? "" : "; ") + d;
    std::lock_guard<std::mutex> lock(mutex_);
    ++dropped_messages_;
    return std::nullopt;
  }

  // Caller holds mutex_. Whether `stamp` is after *last (then it becomes *last); otherwise it is
  // counted as backwards. A stamp not after the previous one (a replayed or restarted source, or
  // the same message sent again) would put a frame in a window twice, or a frame of another
  // timeline. A time jump of the driver's calibration_mode (forgetFramesAfterTimeJump) starts a
  // new timeline.
  bool stampAfterPrevious(const ros::Time& stamp, ros::Time* last) {
    if (!last->isZero() && stamp <= *last) {
      ++backwards_messages_;
      return false;
    }
    *last = stamp;
    return true;
  }

  void onObservation(const StereoPatternObservationConstPtr& msg) {
    if (!guard_->admit(kObservationInput, msg->header.stamp)) return;
    std::string why;
    std::optional<core::StereoObservation> valid = validObservation(*msg, &why);
    if (!valid) {
      NODELET_ERROR_THROTTLE(5.0, "OnlineCalibrator: observation dropped on %s: %s",
                             observations_sub_.getTopic().c_str(), why.c_str());
      return;
    }
    core::StereoObservation observation = std::move(*valid);
    std::lock_guard<std::mutex> lock(mutex_);
    const ros::Time previous = last_observation_stamp_;
    if (!stampAfterPrevious(msg->header.stamp, &last_observation_stamp_)) {  // one frame per stamp in a window
      NODELET_WARN_THROTTLE(5.0,
                            "OnlineCalibrator: observation dropped on %s: its stamp %.3f s is not after the "
                            "previous one (%.3f s); a replayed or restarted source?",
                            observations_sub_.getTopic().c_str(), msg->header.stamp.toSec(), previous.toSec());
      return;
    }
    if (observation.left.empty() && observation.right.empty()) return;  // no board in this frame
    for (const ModeSeen& mode : modes_) {
      if (mode.stamp == msg->header.stamp) {
        addToWindow(std::move(observation), msg->header.stamp, mode.calibrating);
        return;
      }
    }
    pending_.emplace_back(msg->header.stamp, std::move(observation));  // its mode is not here yet
    if (pending_.size() > kKeptFrames) pending_.pop_front();
  }

  // A whole window's observation (window_observations): solved at once when auto_calibrate. It
  // arrives seconds after its window, so it is neither matched with calibration_mode nor passed
  // through the stamp guard (which would hold it against the other inputs' newer stamps).
  void onWindowObservation(const ros::MessageEvent<StereoPatternObservation const>& event) {
    const StereoPatternObservationConstPtr msg = event.getMessage();
    const std::string& publisher = event.getPublisherName();
    std::string why;
    std::optional<core::StereoObservation> valid = validObservation(*msg, &why);
    if (!valid) {
      NODELET_ERROR_THROTTLE(5.0, "OnlineCalibrator: window observation dropped on %s: %s",
                             window_observations_sub_.getTopic().c_str(), why.c_str());
      return;
    }
    core::StereoObservation observation = std::move(*valid);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (repeated_windows_.repeats(observation)) {  // before the stamp: a copy must not move it on
        NODELET_WARN_THROTTLE(5.0,
                              "OnlineCalibrator: window observation dropped on %s (from %s): a copy of one seen "
                              "before (the same corners and scene matches); it teaches nothing new",
                              window_observations_sub_.getTopic().c_str(), publisher.c_str());
        return;
      }
      const ros::Time previous = last_window_observation_stamp_;
      if (!stampAfterPrevious(msg->header.stamp, &last_window_observation_stamp_)) {
        NODELET_WARN_THROTTLE(5.0,
                              "OnlineCalibrator: window observation dropped on %s: its stamp %.3f s is not after "
                              "the previous one (%.3f s); a replayed or restarted source?",
                              window_observations_sub_.getTopic().c_str(), msg->header.stamp.toSec(),
                              previous.toSec());
        return;
      }
      ++window_observations_;
      if (request_wants_window_ && msg->header.stamp > request_started_) {  // the request's burst
        request_window_ = std::move(observation);
        cv_.notify_all();
        return;
      }
    }
    if (!params_.auto_calibrate || (observation.left.empty() && observation.right.empty())) return;
    Job job;
    job.frames.push_back(std::move(observation));
    job.window_observation = true;
    submit(std::move(job));
  }

  void onMode(const CalibrationModeConstPtr& mode) {
    if (!guard_->admit(kModeInput, mode->header.stamp)) return;
    const bool calibrating = mode->light_on && mode->settled;
    std::optional<Job> job;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      const ros::Time& stamp = mode->header.stamp;
      // One frame per stamp: a second message of a stamp is ignored.
      for (const ModeSeen& seen : modes_)
        if (seen.stamp == stamp) return;
      // Older than the newest frame: a time jump of the driver when by more than the stamp
      // tolerance (the stamp guard lets such a jump through only once every input made it),
      // otherwise a late or stray message: kept for matching its observation, but it says
      // nothing about the light now.
      bool late = false;
      if (!modes_.empty() && stamp < modes_.back().stamp) {
        if (modes_.back().stamp.toSec() - stamp.toSec() > params_.stamp_tolerance_s)
          forgetFramesAfterTimeJump(stamp);
        else
          late = true;
      }
      const ModeSeen seen{stamp, calibrating, mode->calibration_epoch};
      if (late) {
        modes_.insert(std::upper_bound(modes_.begin(), modes_.end(), stamp,
                                       [](const ros::Time& t, const ModeSeen& m) { return t < m.stamp; }),
                      seen);
      } else {
        epoch_ = mode->calibration_epoch;
        modes_.push_back(seen);
      }
      if (modes_.size() > kKeptFrames) modes_.pop_front();
      if (awaiting_commit_) cv_.notify_all();
      for (auto it = pending_.begin(); it != pending_.end(); ++it) {
        if (it->first == mode->header.stamp) {
          addToWindow(std::move(it->second), it->first, calibrating);
          pending_.erase(it);
          break;
        }
      }
      // The light went off: the window of the driver's schedule is complete.
      if (!late && !mode->light_on && !request_active_ && !window_.empty()) {
        window_closed_at_ = mode->header.stamp;
        if (solvesFrameWindows() && static_cast<int>(window_.size()) >= params_.min_frames)
          job = Job{std::move(window_), false, nullptr};
        window_.clear();
      }
    }
    if (job) submit(std::move(*job));
  }

  // Window age timer (subscriber queue). An automatic window to which no settled frame was
  // added for window_timeout_s (the light stuck on, the driver silent, frames never settling)
  // ends: solved when it has min_frames, dropped otherwise, with a warning saying why.
  void endIdleWindow() {
    std::optional<Job> job;
    char text[300];
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (request_active_ || window_.empty()) return;
      const double idle_s = (ros::WallTime::now() - last_window_frame_wall_).toSec();
      if (idle_s < params_.window_timeout_s) return;
      const bool solve = solvesFrameWindows() && static_cast<int>(window_.size()) >= params_.min_frames;
      std::snprintf(text, sizeof(text),
                    "calibration window ended: no settled light-on frame added for %.1f s (window_timeout_s); "
                    "%zu frames, %s",
                    idle_s, window_.size(),
                    solve                           ? "solving them"
                    : params_.window_observations ? "not solved (window observations are solved instead)"
                    : params_.auto_calibrate       ? "fewer than min_frames: not solved"
                                                   : "not solved (auto_calibrate is off)");
      last_window_end_ = text;
      if (!modes_.empty()) window_closed_at_ = modes_.back().stamp;
      if (solve) job = Job{std::move(window_), false, nullptr};
      window_.clear();
    }
    if (params_.auto_calibrate) NODELET_WARN("OnlineCalibrator: %s", text);
    if (job) submit(std::move(*job));
  }

  // Caller holds mutex_. Stamps went backwards (a bag replayed again, a restarted sim clock):
  // the frames remembered so far belong to another timeline and window_closed_at_ would hide
  // every new frame.
  void forgetFramesAfterTimeJump(const ros::Time& stamp) {
    NODELET_WARN("OnlineCalibrator: calibration_mode stamp went back from %.3f to %.3f s; window restarted",
                 modes_.back().stamp.toSec(), stamp.toSec());
    modes_.clear();
    pending_.clear();
    window_.clear();
    window_closed_at_ = ros::Time();
    last_observation_stamp_ = ros::Time();
    last_window_observation_stamp_ = ros::Time();
  }

  // The automatic windows of per-frame observations are solved (not when window observations are).
  bool solvesFrameWindows() const { return params_.auto_calibrate && !params_.window_observations; }

  // Caller holds mutex_. The epoch of the driver's first frame whose left and right camera_info
  // carry `committed`, among frames of another epoch than `before` (the one in force at the
  // solve). Read, not predicted: how the driver counts set_camera_info calls is its business.
  std::optional<uint32_t> epochCarrying(const CommittedCalibration& committed, uint32_t before) const {
    const auto at = [](const std::deque<sensor_msgs::CameraInfoConstPtr>& infos, const ros::Time& stamp) {
      for (const auto& info : infos)
        if (info->header.stamp == stamp) return info;
      return sensor_msgs::CameraInfoConstPtr();
    };
    for (const ModeSeen& mode : modes_) {
      if (mode.epoch == before) continue;
      const auto left = at(recent_left_infos_, mode.stamp), right = at(recent_right_infos_, mode.stamp);
      if (left && right && carriesCalibration(*left, committed.left) && carriesCalibration(*right, committed.right))
        return mode.epoch;
    }
    return std::nullopt;
  }

  // Caller holds mutex_.
  void addToWindow(core::StereoObservation observation, const ros::Time& stamp, bool calibrating) {
    if (!calibrating || stamp <= window_closed_at_) return;
    const size_t cap = request_active_ ? request_frames_ : static_cast<size_t>(params_.max_frames);
    if (window_.size() >= cap) return;
    observation.stamp = stamp.toSec();
    window_.push_back(std::move(observation));
    last_window_frame_wall_ = ros::WallTime::now();
    if (request_active_ && window_.size() >= request_frames_) cv_.notify_all();
  }

  void submit(Job job) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stopping_) {
        if (job.result) job.result->set_value(rejectedStatus("calibrator shutting down"));
        return;
      }
      if (job.result || job.commit_again) {
        jobs_.push_back(std::move(job));
      } else if (const std::optional<Job> dropped = paced_->push(std::move(job))) {
        NODELET_WARN_THROTTLE(5.0,
                              "OnlineCalibrator: %s dropped unsolved: more than %zu automatic solves waiting, "
                              "which start at least %.1f s apart (parameters solve_queue_size, "
                              "min_solve_interval_s); the newest are kept",
                              dropped->window_observation ? "a window observation"
                                                          : ("a window of " + std::to_string(dropped->frames.size()) +
                                                             " frames").c_str(),
                              paced_->options().capacity, paced_->options().min_interval_s);
      }
    }
    cv_.notify_all();
  }

  // Caller holds `lock` on mutex_: waits for the next job (requests and commits first, then the
  // paced automatic solves when one may start); false when stopping.
  bool nextJob(std::unique_lock<std::mutex>& lock, Job* job) {
    while (!stopping_) {
      if (!jobs_.empty()) {
        *job = std::move(jobs_.front());
        jobs_.pop_front();
        return true;
      }
      const double now = steadySeconds(), ready_in = paced_->readyIn(now);
      if (ready_in == 0.0) {
        *job = std::move(*paced_->pop(now));
        return true;
      }
      if (ready_in < 0.0)
        cv_.wait(lock);
      else
        cv_.wait_for(lock, std::chrono::duration<double>(ready_in));
    }
    return false;
  }

  void workerLoop() {
    while (true) {
      Job job;
      sensor_msgs::CameraInfoConstPtr left, right;
      uint32_t epoch;
      std::optional<double> health_problem_s;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        if (!nextJob(lock, &job)) return;
        left = left_info_;
        right = right_info_;
        epoch = epoch_;
        health_problem_s = health_problem_s_;
      }
      if (job.commit_again) {
        commitAgain();
        continue;
      }
      std::optional<CommittedCalibration> committed;
      std::optional<UncommittedCalibration> uncommitted;
      CalibrationStatus status =
          session_->solve(job.frames, left.get(), right.get(), epoch, job.dry_run, &committed, &uncommitted,
                          health_problem_s);
      if (committed) readCommittedEpoch(*committed, epoch, &status);
      if (!job.dry_run) {
        // The newest solve decides: a calibration not stored is tried again (scheduleCommitAgain);
        // a later one, committed, rejected or not stored either, replaces it.
        std::lock_guard<std::mutex> lock(mutex_);
        uncommitted_ = std::move(uncommitted);
      }
      std::string input =
          job.window_observation ? "a window observation" : std::to_string(job.frames.size()) + " frames";
      if (status.scene_matches_used > 0)
        input += " and " + std::to_string(status.scene_matches_used) + " scene correspondences";
      const std::string& prior = session_->priorNote();
      NODELET_INFO("OnlineCalibrator: %s, %s%s%s%s (rms %.3f / %.3f px, %.0f ms%s%s)", input.c_str(),
                   job.dry_run ? "dry run, " : "", status.accepted ? "accepted" : "not accepted",
                   status.reason.empty() ? "" : ": ", status.reason.c_str(), status.rms_left_px,
                   status.rms_right_px, status.solve_ms, prior.empty() ? "" : "; ", prior.c_str());
      {
        std::lock_guard<std::mutex> lock(mutex_);
        last_solve_ = status;
        last_solve_time_ = ros::WallTime::now();
        if (status.accepted && !job.dry_run && params_.commit == CommitTarget::kDriver)
          last_commit_time_ = last_solve_time_;
        if (!status.accepted) last_rejection_ = status.reason;
      }
      if (!job.dry_run) status_pub_.publish(status);  // a dry run is answered, not announced
      if (job.result) job.result->set_value(status);
    }
  }

  // Caller holds mutex_. The driver still publishes the calibration `u` was gated against (its
  // epoch may have moved: a failed commit puts the left calibration back).
  bool stillInForce(const UncommittedCalibration& u) const {
    return left_info_ && right_info_ && carriesCalibration(*left_info_, u.left_in_force) &&
           carriesCalibration(*right_info_, u.right_in_force);
  }

  // Commit retry timer (subscriber queue): a calibration the driver could not store (a full
  // disk, a driver restarting) is committed again every commit_retry_s, on the worker, while
  // the calibration in force is still the one it was gated against.
  void scheduleCommitAgain() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!uncommitted_ || commit_again_queued_) return;
      if (!stillInForce(*uncommitted_)) {
        NODELET_WARN("OnlineCalibrator: the calibration in force changed: the calibration the driver could not "
                     "store is not committed again");
        uncommitted_.reset();
        return;
      }
      commit_again_queued_ = true;
    }
    Job job;
    job.commit_again = true;
    submit(std::move(job));
  }

  // Worker thread.
  void commitAgain() {
    std::optional<UncommittedCalibration> calibration;
    uint32_t before;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      commit_again_queued_ = false;
      if (uncommitted_ && stillInForce(*uncommitted_)) calibration = uncommitted_;
      before = epoch_;
    }
    if (!calibration) return;
    const std::string error = session_->commitAgain(*calibration);
    if (!error.empty()) {
      NODELET_WARN_THROTTLE(60.0, "OnlineCalibrator: the accepted calibration is still not committed: %s; trying "
                            "again every %.0f s",
                            error.c_str(), params_.commit_retry_s);
      return;
    }
    CalibrationStatus status = calibration->status;
    status.header.stamp = ros::Time::now();
    status.accepted = true;
    status.reason.clear();
    readCommittedEpoch(calibration->infos, before, &status);
    NODELET_INFO("OnlineCalibrator: the accepted calibration the driver could not store before is committed now "
                 "(epoch %u)",
                 status.epoch);
    {
      std::lock_guard<std::mutex> lock(mutex_);  // no solve ran meanwhile: the worker runs one job at a time
      uncommitted_.reset();
      last_solve_ = status;
      last_solve_time_ = last_commit_time_ = ros::WallTime::now();
    }
    status_pub_.publish(status);
  }

  // Worker thread. Waits (bounded by service_timeout_s: the driver publishes the new
  // calibration with its next frame) for the driver's first frame carrying `committed` and
  // puts its epoch in `status`; without such a frame in time, the newest epoch seen, said so
  // in the reason (the calibration was committed all the same).
  void readCommittedEpoch(const CommittedCalibration& committed, uint32_t before, CalibrationStatus* status) {
    std::optional<uint32_t> seen;
    uint32_t newest;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      awaiting_commit_ = true;
      cv_.wait_for(lock, std::chrono::duration<double>(params_.service_timeout_s),
                   [&] { return stopping_ || (seen = epochCarrying(committed, before)).has_value(); });
      awaiting_commit_ = false;
      newest = epoch_;
    }
    if (seen) {
      status->epoch = *seen;
      return;
    }
    char text[200];
    snprintf(text, sizeof(text),
             "committed, but no frame with it on %s within %.1f s: epoch %u is the newest one seen",
             mode_sub_.getTopic().c_str(), params_.service_timeout_s, newest);
    status->epoch = newest;
    status->reason = text;
    NODELET_WARN("OnlineCalibrator: %s", text);
  }

  bool recalibrate(ros::ServiceEvent<Recalibrate::Request, Recalibrate::Response>& event) {
    const Recalibrate::Request& req = event.getRequest();
    Recalibrate::Response& res = event.getResponse();
    const std::string caller = event.getCallerName();
    const BoundedRequest bounded = boundRecalibrateRequest(req.frames, req.timeout_s, params_);
    if (!bounded.refusal.empty()) {
      NODELET_WARN("OnlineCalibrator: recalibrate from %s %s", caller.c_str(), bounded.refusal.c_str());
      return answer(&res, false, bounded.refusal);
    }
    if (!bounded.note.empty())
      NODELET_WARN("OnlineCalibrator: recalibrate from %s: %s", caller.c_str(), bounded.note.c_str());
    const size_t frames = bounded.frames;
    const double timeout_s = bounded.timeout_s;
    // Every answer says what was limited.
    const auto noted = [&bounded](std::string message) {
      return bounded.note.empty() ? message : message + " (" + bounded.note + ")";
    };
    if (const std::string busy = claimRequest(caller, frames); !busy.empty()) return answer(&res, false, busy);
    struct InFlight {  // cleared on every return
      OnlineCalibratorNodelet* self;
      ~InFlight() {
        std::lock_guard<std::mutex> lock(self->mutex_);
        self->request_in_flight_ = false;
        self->request_active_ = false;
        self->request_wants_window_ = false;
        self->request_caller_.clear();
      }
    } in_flight{this};
    const CallerProbe probe(caller);
    std::string error;
    if (!setLight(true, &error)) {
      // The driver may have switched the light on all the same (an answer lost in a timeout, or
      // success=false after acting): switch it off, unless the service is not there at all.
      std::string message = "cannot switch the light on: " + error;
      std::string off_error;
      if (set_light_client_.exists() && !setLight(false, &off_error))
        message += "; switching it off failed too: " + off_error;
      NODELET_ERROR("OnlineCalibrator: recalibrate: %s", message.c_str());
      return answer(&res, false, noted(message + "; nothing solved or committed"));
    }
    Job job;
    job.dry_run = req.dry_run;
    const std::string abandoned = collectRequestWindow(frames, timeout_s, probe, &job.frames);
    // From here on the light goes off whatever happened: an early end, a shutdown, a timeout.
    if (!setLight(false, &error)) {
      // The head is not back in its normal state (the boards may still be over the scene):
      // nothing is committed on its behalf.
      const std::string message = (abandoned.empty() ? "" : abandoned + "; ") + "cannot switch the light off: " +
                                  error + "; nothing solved or committed";
      NODELET_ERROR("OnlineCalibrator: recalibrate: %s", message.c_str());
      return answer(&res, false, noted(message));
    }
    if (!abandoned.empty()) {
      const std::string message = abandoned + ": light switched off, nothing solved or committed";
      NODELET_WARN("OnlineCalibrator: recalibrate: %s", message.c_str());
      return answer(&res, false, noted(message));
    }
    if (job.frames.size() < frames) {
      char text[160];
      if (job.frames.empty())
        snprintf(text, sizeof(text), "timeout: no boards seen in %.1f s with the light on", timeout_s);
      else
        snprintf(text, sizeof(text), "timeout: only %zu of %zu frames with boards in %.1f s", job.frames.size(),
                 frames, timeout_s);
      return answer(&res, false, noted(text));
    }
    if (params_.window_observations) useTheBurstsWindowObservation(&job);
    job.result = std::make_shared<std::promise<CalibrationStatus>>();
    std::future<CalibrationStatus> result = job.result->get_future();
    submit(std::move(job));
    res.status = result.get();  // the solve and commit are bounded (service calls: callService)
    // A solve that fits no better than the calibration in force confirms it: nothing to change.
    const bool confirmed = res.status.in_force_confirmed;
    res.success = res.status.accepted || confirmed;
    // An accepted status has an empty reason only when committed to the driver.
    res.message = noted(res.status.accepted && res.status.reason.empty() ? "committed" : res.status.reason);
    return true;
  }

  // Service thread: starts a request's collection, or says why not (one runs already). Answered
  // at once (the second service thread): a queued request would switch the light and clear the
  // window of the one running.
  std::string claimRequest(const std::string& caller, size_t frames) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (request_in_flight_) return "busy: a recalibration is already running (requested by " + request_caller_ + ")";
    request_in_flight_ = true;
    request_caller_ = caller;
    request_active_ = true;
    request_frames_ = frames;
    window_.clear();
    if (!modes_.empty()) window_closed_at_ = modes_.back().stamp;  // only frames from now on
    request_wants_window_ = params_.window_observations;
    request_started_ = window_closed_at_;
    request_window_.reset();
    return "";
  }

  // Service thread. Waits until the request's window has `frames` frames or `timeout_s` passed,
  // then moves the window to `*frames_out` and ends the request's collection. Returns why it
  // ended early ("" when it did not): the caller went away (probed every kProbePeriodS without
  // mutex_ held) or the calibrator is shutting down.
  std::string collectRequestWindow(size_t frames, double timeout_s, const CallerProbe& probe,
                                   std::vector<core::StereoObservation>* frames_out) {
    using Clock = std::chrono::steady_clock;
    const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeout_s));
    const auto probe_period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(kProbePeriodS));
    std::string abandoned;
    std::unique_lock<std::mutex> lock(mutex_);
    while (true) {
      if (stopping_) {
        abandoned = "the calibrator is shutting down";
        break;
      }
      const auto now = Clock::now();
      if (window_.size() >= frames || now >= deadline) break;
      if (cv_.wait_until(lock, std::min(deadline, now + probe_period),
                         [&] { return stopping_ || window_.size() >= frames; }))
        continue;
      if (Clock::now() >= deadline) continue;
      lock.unlock();
      const CallerState caller = probe.check();
      lock.lock();
      if (caller == CallerState::kGone) {
        abandoned = "the caller " + probe.callerId() + " went away";
        break;
      }
    }
    *frames_out = std::move(window_);
    window_.clear();
    if (!modes_.empty()) window_closed_at_ = modes_.back().stamp;
    request_active_ = false;
    return abandoned;
  }

  // Service thread, window observations: waits up to kRequestWindowWaitS for the window
  // observation of the request's burst (the tracker tracks it as a whole after it ended) and
  // solves it instead of the burst's per-frame observations.
  void useTheBurstsWindowObservation(Job* job) {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_for(lock, std::chrono::duration<double>(kRequestWindowWaitS),
                 [this] { return stopping_ || request_window_.has_value(); });
    request_wants_window_ = false;
    if (!request_window_) {
      NODELET_WARN("OnlineCalibrator: recalibrate: no window observation of the burst on %s within %.0f s; solving "
                   "its %zu per-frame observations", window_observations_sub_.getTopic().c_str(), kRequestWindowWaitS,
                   job->frames.size());
      return;
    }
    job->frames = {std::move(*request_window_)};
    job->window_observation = true;
    request_window_.reset();
  }

  bool answer(Recalibrate::Response* res, bool success, const std::string& message) {
    res->success = success;
    res->message = message;
    res->status = rejectedStatus(message);
    return true;
  }

  // Safe with or without mutex_ held.
  CalibrationStatus rejectedStatus(const std::string& reason) const {
    CalibrationStatus status;
    status.header.stamp = ros::Time::now();
    status.epoch = epoch_;
    status.reason = reason;
    return status;
  }

  // Bounded: service_timeout_s for set_light to appear, as much for its answer.
  bool setLight(bool on, std::string* error) {
    std_srvs::SetBool srv;
    srv.request.data = on;
    if (!callService(getNodeHandle(), "set_light", &srv, params_.service_timeout_s, error)) return false;
    if (!srv.response.success) {
      *error = set_light_client_.getService() + " refused: " + srv.response.message;
      return false;
    }
    return true;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    std::lock_guard<std::mutex> lock(mutex_);
    const ros::WallTime now = ros::WallTime::now();
    if (!last_solve_) {
      status.summary(diagnostic_msgs::DiagnosticStatus::OK, "no solve yet");
    } else if (last_solve_->accepted) {
      status.summary(diagnostic_msgs::DiagnosticStatus::OK, "last solve accepted");
    } else {
      status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "last solve rejected: " + last_solve_->reason);
    }
    status.add("last solve age (s)", last_solve_ ? (now - last_solve_time_).toSec() : -1.0);
    status.add("calibration age (s)", last_commit_time_.isZero() ? -1.0 : (now - last_commit_time_).toSec());
    status.add("rms left (px)", last_solve_ ? last_solve_->rms_left_px : 0.0);
    status.add("rms right (px)", last_solve_ ? last_solve_->rms_right_px : 0.0);
    status.add("solve (ms)", last_solve_ ? last_solve_->solve_ms : 0.0);
    status.add("last rejection reason", last_rejection_);
    status.add("calibration epoch", epoch_.load());
    status.add("frames in window", window_.size());
    status.add("dropped observation messages", dropped_messages_);
    status.add("observations dropped for a stamp going back", backwards_messages_);
    if (params_.window_observations) status.add("window observations received", window_observations_);
    status.add("messages dropped for a stamp far from the others", guard_->dropped());
    status.add("last window ended early", last_window_end_);
    status.add("accepted calibration waiting to be committed again", uncommitted_.has_value());
  }

  static constexpr size_t kKeptFrames = 64;  // modes / unmatched observations remembered
  static constexpr size_t kKeptInfos = 16;   // camera_info per side (the commit's epoch)
  static constexpr double kProbePeriodS = 0.5;  // a running request looks for its caller this often
  // guard_'s inputs.
  static constexpr size_t kModeInput = 0, kObservationInput = 1, kLeftInfoInput = 2, kRightInfoInput = 3;

  struct ModeSeen {
    ros::Time stamp;
    bool calibrating;  // light_on && settled
    uint32_t epoch;
  };

  CalibratorParams params_;
  std::unique_ptr<CalibrationSession> session_;  // worker thread only (boards(): any thread)
  ros::Publisher status_pub_;
  ros::Subscriber observations_sub_, window_observations_sub_, mode_sub_, left_info_sub_, right_info_sub_, health_sub_;
  std::optional<double> health_problem_s_;  // newest health verdict below GOOD (stamp, s); mutex_
  ros::ServiceServer recalibrate_srv_;
  ros::CallbackQueue service_queue_;  // calibration/recalibrate only (see the class comment)
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;
  ros::ServiceClient set_light_client_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::WallTimer diagnostics_timer_, window_timer_, commit_retry_timer_;
  std::unique_ptr<StampGuard> guard_;
  ErrorThrottle info_errors_{5.0};  // thread-safe

  std::mutex mutex_;  // guards everything below
  std::condition_variable cv_;  // jobs_, window_ (request), stopping_, frames after a commit
  std::deque<ModeSeen> modes_;  // recent frames
  std::deque<sensor_msgs::CameraInfoConstPtr> recent_left_infos_, recent_right_infos_;
  bool awaiting_commit_ = false;  // the worker waits for the driver's frame of a commit
  ros::Time last_observation_stamp_;  // newest observation accepted (zero: none yet)
  ros::Time last_window_observation_stamp_;  // newest window observation accepted (zero: none yet)
  core::RepeatedObservations repeated_windows_;  // the latest window observations' contents
  uint64_t window_observations_ = 0;         // accepted
  std::deque<std::pair<ros::Time, core::StereoObservation>> pending_;
  std::vector<core::StereoObservation> window_;
  ros::Time window_closed_at_;  // frames up to this stamp belong to a finished window
  bool request_active_ = false;      // a recalibrate call is collecting its window
  bool request_in_flight_ = false;   // a recalibrate call is running (from its start to its answer)
  std::string request_caller_;       // the node that made it
  ros::WallTime last_window_frame_wall_;  // when a frame was last added to window_
  std::string last_window_end_;      // why the last window ended without the light going off
  std::optional<UncommittedCalibration> uncommitted_;  // accepted, not stored by the driver: tried again
  bool commit_again_queued_ = false;
  size_t request_frames_ = 0;
  // Window observations: the request waits for its burst's (stamped after request_started_).
  static constexpr double kRequestWindowWaitS = 20.0;
  bool request_wants_window_ = false;
  ros::Time request_started_;
  std::optional<core::StereoObservation> request_window_;
  sensor_msgs::CameraInfoConstPtr left_info_, right_info_;  // the latest valid pair (storeInfo)
  sensor_msgs::CameraInfoConstPtr latest_left_info_, latest_right_info_;  // the latest valid side
  // The rectification (left R, right R and P) of the pair in force last put on /tf_static by
  // storeInfo: a pair set from outside the calibrator (a rollback, rosservice) goes there too.
  std::vector<double> in_force_tf_key_;
  std::atomic<uint32_t> epoch_{0};  // also read without mutex_ (statuses)
  std::deque<Job> jobs_;                       // requests and commits again, first come first served
  std::unique_ptr<core::PacedQueue<Job>> paced_;  // automatic solves (params_.solve_pacing)
  bool stopping_ = false;
  std::optional<CalibrationStatus> last_solve_;
  ros::WallTime last_solve_time_, last_commit_time_;
  std::string last_rejection_;
  uint64_t dropped_messages_ = 0;
  uint64_t backwards_messages_ = 0;
  std::thread worker_;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::OnlineCalibratorNodelet, nodelet::Nodelet)
