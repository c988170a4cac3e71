#pragma once
// The OnlineCalibrator's running state behind its topics and service: the calibration windows
// (core::CalibrationWindows), the calibration in force (CalibrationInForce), the solve jobs and
// the worker thread that runs them through CalibrationSession, the commit read-back and the
// commit again of a calibration the driver could not store. The nodelet reads the parameters,
// wires topics, timers and calibration/recalibrate to it. docs/nodelets.md, "OnlineCalibrator".
//
// Threading: the subscriber methods run on the nodelet's subscriber queue, the request methods
// on its service threads, the solves on the worker thread started by start() and joined by
// stop(); everything they share is guarded by one mutex. session().boards() is immutable.
#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/ros.h>

#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/core/calibration/calibration_windows.h"
#include "embedded_calibration_stereo/core/calibration/paced_queue.h"
#include "embedded_calibration_stereo/ros/calibration_in_force.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/caller_probe.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

class OnlineCalibration {
 public:
  // Resolved topic names, for the log lines.
  struct Topics {
    std::string observations, window_observations, mode;
  };
  using Publish = std::function<void(const CalibrationStatus&)>;

  // `name`: the nodelet's (its log lines' logger); `publish`: calibration/status.
  OnlineCalibration(std::string name, CalibratorParams params, std::unique_ptr<CalibrationSession> session,
                    Topics topics, Publish publish);
  ~OnlineCalibration() { stop(); }

  // Starts the worker thread.
  void start();
  // Stops and joins the worker; requests waiting for a solve are answered "calibrator shutting down".
  void stop();

  const CalibrationSession& session() const { return *session_; }
  // The calibration epoch of the newest frame.
  uint32_t epoch() const { return epoch_; }
  const std::string& getName() const { return name_; }  // for the NODELET_ log macros

  // Subscriber queue (after the nodelet's stamp guard where it applies).
  void onMode(const CalibrationMode& mode);
  void onObservation(const StereoPatternObservation& msg);
  // A whole window's observation, from `publisher`.
  void onWindowObservation(const StereoPatternObservation& msg, const std::string& publisher);
  // One side's camera_info (`topic`, the other side's `other_topic`); the pair in force goes on
  // /tf_static whenever it changes.
  void onCameraInfo(bool left, const sensor_msgs::CameraInfoConstPtr& info, const std::string& topic,
                    const std::string& other_topic);
  void onHealth(const CalibrationHealth& health);
  // Window age timer.
  void endIdleWindow();
  // Commit retry timer: a calibration the driver could not store is committed again on the
  // worker while the calibration in force is still the one it was gated against.
  void scheduleCommitAgain();
  // `stamp_guard_dropped`: the nodelet's stamp guard's count.
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status, uint64_t stamp_guard_dropped);

  // Service threads. Starts a request's collection of `frames` frames, or says why not ("busy":
  // one runs already).
  std::string claimRequest(const std::string& caller, size_t frames);
  // Waits until the request's window has `frames` frames or `timeout_s` passed, then moves it
  // to `*frames_out`. Returns why it ended early ("" when it did not): the caller went away
  // (probed every kProbePeriodS without the mutex held) or shutting down.
  std::string collectRequestWindow(size_t frames, double timeout_s, const CallerProbe& probe,
                                   std::vector<core::StereoObservation>* frames_out);
  // Window observations: waits up to kRequestWindowWaitS for the window observation of the
  // request's burst; true (and `*frames` is it) when it came.
  bool takeTheBurstsWindowObservation(std::vector<core::StereoObservation>* frames);
  // Solves (and commits unless `dry_run` or rejected) on the worker; blocks for the status.
  CalibrationStatus solveRequest(std::vector<core::StereoObservation> frames, bool dry_run, bool window_observation);
  // The request is over, however it ended.
  void requestDone();

  static constexpr double kProbePeriodS = 0.5;  // a running request looks for its caller this often
  static constexpr double kRequestWindowWaitS = 20.0;

 private:
  struct Job {
    std::vector<core::StereoObservation> frames;
    bool dry_run = false;
    std::shared_ptr<std::promise<CalibrationStatus>> result;  // null for automatic windows
    bool commit_again = false;  // no solve: commit uncommitted_ again
    bool window_observation = false;  // frames: one observation of a whole window
  };

  std::optional<core::StereoObservation> validObservation(const StereoPatternObservation& msg, std::string* why);
  void submit(Job job);
  bool nextJob(std::unique_lock<std::mutex>& lock, Job* job);
  void workerLoop();
  void noteSolve(const CalibrationStatus& status);
  void commitAgain();
  void readCommittedEpoch(const CommittedCalibration& committed, uint32_t before, CalibrationStatus* status);

  const std::string name_;
  const CalibratorParams params_;
  std::unique_ptr<CalibrationSession> session_;  // worker thread only (boards(): any thread)
  const Topics topics_;
  const Publish publish_;
  ErrorThrottle info_errors_{5.0};  // thread-safe

  std::mutex mutex_;  // guards everything below
  std::condition_variable cv_;  // jobs_, the request's window, stopping_, frames after a commit
  core::CalibrationWindows windows_;  // frames, windows, the request's window, health verdicts
  CalibrationInForce in_force_;  // the calibration in force, every frame's camera_info
  bool awaiting_commit_ = false;  // the worker waits for the driver's frame of a commit
  bool request_in_flight_ = false;  // a recalibrate call is running (from its start to its answer)
  std::string request_caller_;      // the node that made it
  std::string last_window_end_;     // why the last window ended without the light going off
  std::optional<UncommittedCalibration> uncommitted_;  // accepted, not stored by the driver: tried again
  bool commit_again_queued_ = false;
  std::atomic<uint32_t> epoch_{0};  // also read without mutex_ (statuses)
  std::deque<Job> jobs_;  // requests and commits again, first come first served
  core::PacedQueue<Job> paced_;  // automatic solves (params_.solve_pacing)
  bool stopping_ = false;
  std::optional<CalibrationStatus> last_solve_;
  ros::WallTime last_solve_time_, last_commit_time_;
  std::string last_rejection_;
  uint64_t dropped_messages_ = 0;
  std::thread worker_;
};

}  // namespace embedded_calibration_stereo
