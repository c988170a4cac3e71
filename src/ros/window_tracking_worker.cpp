#include "embedded_calibration_stereo/ros/window_tracking_worker.h"

#include <chrono>
#include <cstdio>
#include <string>

#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/freed_memory.h"

namespace embedded_calibration_stereo {

WindowTrackingWorker::WindowTrackingWorker(ros::Publisher publisher, std::string logger, std::string device_config)
    : publisher_(std::move(publisher)),
      logger_(std::move(logger)),
      device_config_(std::move(device_config)),
      thread_(&WindowTrackingWorker::run, this) {}

WindowTrackingWorker::~WindowTrackingWorker() {
  jobs_.stop();
  if (thread_.joinable()) thread_.join();
}

void WindowTrackingWorker::submit(std::shared_ptr<core::WindowTracker> tracker, LightBurst burst) {
  std::optional<Job> replaced = jobs_.put(Job{std::move(tracker), std::move(burst)});
  if (!replaced) return;
  std::lock_guard<std::mutex> lock(mutex_);
  ++dropped_;
  summary_ = "burst ending at " + std::to_string(replaced->burst.light_on.back().first->header.stamp.toSec()) +
             " s dropped: a newer one ended while the worker was busy";
}

void WindowTrackingWorker::dropped(const EndedBurst& ended, const std::string& why) {
  char text[600];
  std::snprintf(text, sizeof(text), "burst of %d light-on frames ending at %.3f s dropped: %s", ended.light_on_frames,
                ended.burst.light_off_after.first->header.stamp.toSec(), why.c_str());
  ROS_WARN_THROTTLE_NAMED(5.0, logger_, "PatternTracker: %s (window tracking, %s)", text,
                          publisher_.getTopic().c_str());
  std::lock_guard<std::mutex> lock(mutex_);
  ++dropped_;
  summary_ = text;
}

namespace {
std::string boardsStill(double motion_px) {
  char text[120];
  std::snprintf(text, sizeof(text), ", not during the burst (no board moved by more than %.2f px between its first and last light-on frames)",
                motion_px);
  return text;
}
}  // namespace

void WindowTrackingWorker::run() {
  while (std::optional<Job> job = jobs_.take()) track(*job);
}

void WindowTrackingWorker::track(const Job& job) {
  const auto t0 = std::chrono::steady_clock::now();
  const std_msgs::Header header = job.burst.light_on.back().first->header;  // the last light-on frame's
  StereoPatternObservation msg;
  int corners = 0, saddle_failures = 0;
  std::string error, scene_problem;
  core::SceneConsistency scene_sides;
  bool boards_moved = false, board_motion_checked = false;
  double board_motion_px = 0.0;
  try {
    const core::WindowTrack track =
        job.tracker->track(windowFrames(job.burst, 0), windowFrames(job.burst, 1), header.stamp.toSec());
    msg = toMsg(track.observation);
    saddle_failures = track.saddle_failures;
    scene_problem = track.scene_problem;
    scene_sides = track.scene_sides;
    boards_moved = track.boards_moved;
    board_motion_checked = track.board_motion_checked;
    board_motion_px = track.board_motion_px;
    for (const auto* side : {&msg.left, &msg.right})
      for (const BoardObservation& b : *side) corners += static_cast<int>(b.corner_ids.size());
  } catch (const std::exception& e) {
    error = e.what();
  }
  releaseFreedMemory();  // the burst's learning freed tens of MB
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  const size_t frames = job.burst.light_on.size();
  char text[600];
  if (error.empty() && boards_moved) {
    // Learned from the whole burst, its boards would mix two rigs: no observation this time.
    std::snprintf(text, sizeof(text),
                  "burst of %zu light-on frames ending at %.3f s dropped: its boards moved during it (a board by "
                  "%.2f px between its first and last light-on frames: a zoom step or a knock); the next burst "
                  "calibrates",
                  frames, header.stamp.toSec(), board_motion_px);
    ROS_WARN_NAMED(logger_, "PatternTracker: %s", text);
  } else if (error.empty()) {
    msg.header = header;
    publisher_.publish(msg);
    std::snprintf(text, sizeof(text),
                  "burst of %zu light-on frames ending at %.3f s: %d corners (%d dropped by the saddle fit), "
                  "%zu scene correspondences, in %.0f ms",
                  frames, header.stamp.toSec(), corners, saddle_failures, msg.scene.size(), ms);
    ROS_INFO_NAMED(logger_, "PatternTracker: %s", text);
    if (!scene_sides.consistent)
      ROS_INFO_NAMED(logger_,
                     "PatternTracker: the scene's epipolar geometry changed between the light-off frames before "
                     "and after the burst ending at %.3f s (by %.2f px, +- %.2f px): the camera moved between them%s; "
                     "its window goes to the calibrator without scene correspondences",
                     header.stamp.toSec(), scene_sides.change_px, scene_sides.change_stddev_px,
                     board_motion_checked ? boardsStill(board_motion_px).c_str() : "");
    if (!scene_problem.empty())
      ROS_WARN_THROTTLE_NAMED(30.0, logger_, "PatternTracker: %s (device_config %s)", scene_problem.c_str(),
                              device_config_.c_str());
  } else {
    std::snprintf(text, sizeof(text), "burst of %zu light-on frames ending at %.3f s not tracked: %s", frames,
                  header.stamp.toSec(), error.c_str());
    ROS_ERROR_THROTTLE_NAMED(5.0, logger_, "PatternTracker: %s (window tracking, %s)", text,
                             publisher_.getTopic().c_str());
  }
  std::lock_guard<std::mutex> lock(mutex_);
  summary_ = text;
  if (error.empty() && !boards_moved) {
    ++tracked_;
    last_ms_ = ms;
  } else {
    ++dropped_;
  }
}

void WindowTrackingWorker::diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::lock_guard<std::mutex> lock(mutex_);
  status.add("window tracking", summary_);
  status.add("windows tracked", tracked_);
  status.add("windows dropped", dropped_);
  status.add("last window (ms)", last_ms_);
}

}  // namespace embedded_calibration_stereo
