#pragma once
// The PatternTracker's window tracking (window_tracking): a worker thread tracks each light burst
// handed over as a whole with the core WindowTracker and publishes one observation per burst
// (docs/nodelets.md#patterntracker). While it works, the newest burst waits (NewestJobSlot).
//
// Threading: submit() and dropped() on the nodelet's callback queue; the worker thread (started
// by the constructor, joined by the destructor) alone runs the trackers handed over and
// publishes; diagnose() on the diagnostics timer. mutex_ guards the figures.
#include <diagnostic_updater/DiagnosticStatusWrapper.h>
#include <ros/ros.h>

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "embedded_calibration_stereo/core/tracker/newest_job_slot.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"
#include "embedded_calibration_stereo/ros/light_burst.h"

namespace embedded_calibration_stereo {

class WindowTrackingWorker {
 public:
  // `publisher`: calibration/window_observations; `logger`: the nodelet's name (its log lines);
  // `device_config`: named when the scene correspondences fail.
  WindowTrackingWorker(ros::Publisher publisher, std::string logger, std::string device_config);
  ~WindowTrackingWorker();
  WindowTrackingWorker(const WindowTrackingWorker&) = delete;
  WindowTrackingWorker& operator=(const WindowTrackingWorker&) = delete;

  // Hands a burst (its frames kept) to the worker with the tracker in force (a new prior makes a
  // new tracker; the worker finishes with the one it got). A burst still waiting is dropped.
  void submit(std::shared_ptr<core::WindowTracker> tracker, LightBurst burst);
  // A burst that is not tracked, `why`: logged (throttled) and counted.
  void dropped(const EndedBurst& ended, const std::string& why);
  // Adds the window figures to the diagnostics.
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);

 private:
  struct Job {
    std::shared_ptr<core::WindowTracker> tracker;
    LightBurst burst;
  };
  void run();
  void track(const Job& job);

  ros::Publisher publisher_;
  const std::string logger_, device_config_;
  core::NewestJobSlot<Job> jobs_;
  std::mutex mutex_;                             // guards the figures below
  std::string summary_ = "no burst yet";         // the last burst: tracked (corners, ms) or why not
  uint64_t tracked_ = 0, dropped_ = 0;
  double last_ms_ = 0.0;
  std::thread thread_;  // last: starts once the rest is built
};

}  // namespace embedded_calibration_stereo
