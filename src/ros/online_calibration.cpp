#include "embedded_calibration_stereo/ros/online_calibration.h"

#include <nodelet/nodelet.h>  // the NODELET_ log macros (getName())

#include <chrono>
#include <cstdio>

#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/freed_memory.h"
#include "embedded_calibration_stereo/ros/stamp_guard.h"

namespace embedded_calibration_stereo {
namespace {

core::StampNs ns(const ros::Time& t) { return static_cast<core::StampNs>(t.toNSec()); }
double wallNow() { return ros::WallTime::now().toSec(); }

core::CalibrationWindowOptions windowOptions(const CalibratorParams& p) {
  core::CalibrationWindowOptions o;
  o.auto_calibrate = p.auto_calibrate;
  o.window_observations = p.window_observations;
  o.min_frames = p.min_frames;
  o.max_frames = p.max_frames;
  o.window_timeout_s = p.window_timeout_s;
  o.stamp_tolerance_s = p.stamp_tolerance_s;
  return o;
}

}  // namespace

OnlineCalibration::OnlineCalibration(std::string name, CalibratorParams params,
                                     std::unique_ptr<CalibrationSession> session, Topics topics, Publish publish)
    : name_(std::move(name)),
      params_(std::move(params)),
      session_(std::move(session)),
      topics_(std::move(topics)),
      publish_(std::move(publish)),
      windows_(windowOptions(params_)),
      paced_(params_.solve_pacing) {}

void OnlineCalibration::start() { worker_ = std::thread(&OnlineCalibration::workerLoop, this); }

void OnlineCalibration::stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  cv_.notify_all();
  if (worker_.joinable()) worker_.join();
  std::lock_guard<std::mutex> lock(mutex_);
  for (Job& job : jobs_)
    if (job.result) job.result->set_value(statusWithoutSolve("calibrator shutting down", epoch_));
  jobs_.clear();
  paced_.clear();
}

// The pair's geometry goes on /tf_static at once, so that tf (rviz, points2 users) has the right
// camera before the first commit, and again whenever the pair in force changes (a commit, or a
// calibration set from outside, such as the health monitor's rollback). A replay (commit:=none)
// never sees its camera_info change, so its solves stay on /tf_static.
void OnlineCalibration::onCameraInfo(bool left, const sensor_msgs::CameraInfoConstPtr& info, const std::string& topic,
                                     const std::string& other_topic) {
  CalibrationInForce::Stored stored;
  sensor_msgs::CameraInfoConstPtr left_info, right_info;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stored = in_force_.store(left, info, topic, other_topic);
    if (awaiting_commit_) cv_.notify_all();
    left_info = in_force_.left();
    right_info = in_force_.right();
  }
  if (!stored.problem.empty()) {
    if (info_errors_.shouldReport(stored.problem))
      NODELET_ERROR("OnlineCalibrator: camera_info dropped, the calibration in force is kept: %s",
                    stored.problem.c_str());
    return;
  }
  if (!stored.changed) return;
  core::StereoRig rig;
  std::string error;
  if (fromStereoCameraInfo(*left_info, *right_info, &rig, &error))
    session_->broadcastTransform(rig);
  else
    NODELET_WARN("OnlineCalibrator: no tf from the calibration in force yet: %s", error.c_str());
}

void OnlineCalibration::onHealth(const CalibrationHealth& health) {
  std::lock_guard<std::mutex> lock(mutex_);  // verdicts below GOOD: the rig changed since earlier windows
  windows_.noteHealthVerdict(health.state == CalibrationHealth::DEGRADED || health.state == CalibrationHealth::BAD,
                             health.header.stamp.toSec());
}

// The observation in `msg`; nothing when it has a defect, then *why says which and it is counted
// as dropped. The caller logs (a throttle per input).
std::optional<core::StereoObservation> OnlineCalibration::validObservation(const StereoPatternObservation& msg,
                                                                          std::string* why) {
  core::StereoObservation observation = fromMsg(msg);
  const std::vector<std::string> defects = observationDefects(observation, session_->boards());
  if (defects.empty()) return observation;
  why->clear();
  for (const std::string& d : defects) *why += (why->empty() ? "" : "; ") + d;
  std::lock_guard<std::mutex> lock(mutex_);
  ++dropped_messages_;
  return std::nullopt;
}

void OnlineCalibration::onObservation(const StereoPatternObservation& msg) {
  std::string why;
  std::optional<core::StereoObservation> valid = validObservation(msg, &why);
  if (!valid) {
    NODELET_ERROR_THROTTLE(5.0, "OnlineCalibrator: observation dropped on %s: %s", topics_.observations.c_str(),
                           why.c_str());
    return;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  core::StampNs previous = 0;
  if (windows_.addObservation(std::move(*valid), ns(msg.header.stamp), wallNow(), &previous) ==
      core::ObservationFate::kBackwards)
    NODELET_WARN_THROTTLE(5.0,
                          "OnlineCalibrator: observation dropped on %s: its stamp %.3f s is not after the "
                          "previous one (%.3f s); a replayed or restarted source?",
                          topics_.observations.c_str(), msg.header.stamp.toSec(), core::stampSeconds(previous));
  if (windows_.requestFull()) cv_.notify_all();
}

// It arrives seconds after its window, so it is neither matched with calibration_mode nor passed
// through the stamp guard (which would hold it against the other inputs' newer stamps).
void OnlineCalibration::onWindowObservation(const StereoPatternObservation& msg, const std::string& publisher) {
  std::string why;
  std::optional<core::StereoObservation> valid = validObservation(msg, &why);
  if (!valid) {
    NODELET_ERROR_THROTTLE(5.0, "OnlineCalibrator: window observation dropped on %s: %s",
                           topics_.window_observations.c_str(), why.c_str());
    return;
  }
  std::optional<core::StereoObservation> solve;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    core::StampNs previous = 0;
    const core::WindowObservationFate fate =
        windows_.addWindowObservation(std::move(*valid), ns(msg.header.stamp), &solve, &previous);
    if (fate == core::WindowObservationFate::kRepeated)
      NODELET_WARN_THROTTLE(5.0,
                            "OnlineCalibrator: window observation dropped on %s (from %s): a copy of one seen "
                            "before (the same corners and scene matches); it teaches nothing new",
                            topics_.window_observations.c_str(), publisher.c_str());
    if (fate == core::WindowObservationFate::kBackwards)
      NODELET_WARN_THROTTLE(5.0,
                            "OnlineCalibrator: window observation dropped on %s: its stamp %.3f s is not after "
                            "the previous one (%.3f s); a replayed or restarted source?",
                            topics_.window_observations.c_str(), msg.header.stamp.toSec(), core::stampSeconds(previous));
    if (fate == core::WindowObservationFate::kForRequest) cv_.notify_all();
    if (fate != core::WindowObservationFate::kSolve) return;
  }
  Job job;
  job.frames.push_back(std::move(*solve));
  job.window_observation = true;
  submit(std::move(job));
}

void OnlineCalibration::onMode(const CalibrationMode& mode) {
  core::ModeResult result;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    result = windows_.addMode({ns(mode.header.stamp), mode.light_on != 0, mode.settled != 0, mode.calibration_epoch},
                              wallNow());
    if (result.kind == core::ModeResult::Kind::kDuplicate) return;
    if (result.time_jump_from)
      NODELET_WARN("OnlineCalibrator: calibration_mode stamp went back from %.3f to %.3f s; window restarted",
                   core::stampSeconds(*result.time_jump_from), mode.header.stamp.toSec());
    if (result.kind == core::ModeResult::Kind::kCurrent) epoch_ = mode.calibration_epoch;
    if (awaiting_commit_ || windows_.requestFull()) cv_.notify_all();
  }
  if (result.solve) submit(Job{std::move(*result.solve), false, nullptr});
}

// An automatic window to which no settled frame was added for window_timeout_s (the light stuck
// on, the driver silent, frames never settling) ends, with a warning saying why.
void OnlineCalibration::endIdleWindow() {
  std::optional<core::IdleWindow> idle;
  char text[300];
  {
    std::lock_guard<std::mutex> lock(mutex_);
    idle = windows_.endIdleWindow(wallNow());
    if (!idle) return;
    static const char* const kWhy[] = {"solving them", "not solved (window observations are solved instead)",
                                       "fewer than min_frames: not solved", "not solved (auto_calibrate is off)"};
    std::snprintf(text, sizeof(text),
                  "calibration window ended: no settled light-on frame added for %.1f s (window_timeout_s); "
                  "%zu frames, %s",
                  idle->idle_s, idle->frames, kWhy[static_cast<int>(idle->end)]);
    last_window_end_ = text;
  }
  if (params_.auto_calibrate) NODELET_WARN("OnlineCalibrator: %s", text);
  if (idle->end == core::IdleWindowEnd::kSolving) submit(Job{std::move(idle->solve), false, nullptr});
}

void OnlineCalibration::submit(Job job) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) {
      if (job.result) job.result->set_value(statusWithoutSolve("calibrator shutting down", epoch_));
      return;
    }
    if (job.result || job.commit_again) {
      jobs_.push_back(std::move(job));
    } else if (const std::optional<Job> dropped = paced_.push(std::move(job))) {
      NODELET_WARN_THROTTLE(5.0,
                            "OnlineCalibrator: %s dropped unsolved: more than %zu automatic solves waiting, "
                            "which start at least %.1f s apart (parameters solve_queue_size, "
                            "min_solve_interval_s); the newest are kept",
                            dropped->window_observation
                                ? "a window observation"
                                : ("a window of " + std::to_string(dropped->frames.size()) + " frames").c_str(),
                            paced_.options().capacity, paced_.options().min_interval_s);
    }
  }
  cv_.notify_all();
}

// Caller holds `lock` on mutex_: waits for the next job (requests and commits first, then the
// paced automatic solves when one may start); false when stopping.
bool OnlineCalibration::nextJob(std::unique_lock<std::mutex>& lock, Job* job) {
  while (!stopping_) {
    if (!jobs_.empty()) {
      *job = std::move(jobs_.front());
      jobs_.pop_front();
      return true;
    }
    const double now = steadySeconds(), ready_in = paced_.readyIn(now);
    if (ready_in == 0.0) {
      *job = std::move(*paced_.pop(now));
      return true;
    }
    if (ready_in < 0.0)
      cv_.wait(lock);
    else
      cv_.wait_for(lock, std::chrono::duration<double>(ready_in));
  }
  return false;
}

void OnlineCalibration::workerLoop() {
  while (true) {
    Job job;
    SolveRequest request;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      if (!nextJob(lock, &job)) return;
      request.left_info = in_force_.left();
      request.right_info = in_force_.right();
      request.epoch = epoch_;
      request.health_problem_s = windows_.healthProblemS();
    }
    if (job.commit_again) {
      commitAgain();
      continue;
    }
    const size_t frames = job.frames.size();
    request.frames = std::move(job.frames);
    request.dry_run = job.dry_run;
    SolveResult solved = session_->solve(request);
    releaseFreedMemory();  // a solve frees what its problem took
    CalibrationStatus& status = solved.status;
    if (solved.committed) readCommittedEpoch(*solved.committed, request.epoch, &status);
    if (!job.dry_run) {
      // The newest solve decides: a calibration not stored is tried again (scheduleCommitAgain);
      // a later one, committed, rejected or not stored either, replaces it.
      std::lock_guard<std::mutex> lock(mutex_);
      uncommitted_ = std::move(solved.uncommitted);
    }
    std::string input = job.window_observation ? "a window observation" : std::to_string(frames) + " frames";
    if (status.scene_matches_used > 0)
      input += " and " + std::to_string(status.scene_matches_used) + " scene correspondences";
    const std::string& prior = session_->priorNote();
    NODELET_INFO("OnlineCalibrator: %s, %s%s%s%s (rms %.3f / %.3f px, %.0f ms%s%s)", input.c_str(),
                 job.dry_run ? "dry run, " : "", status.accepted ? "accepted" : "not accepted",
                 status.reason.empty() ? "" : ": ", status.reason.c_str(), status.rms_left_px, status.rms_right_px,
                 status.solve_ms, prior.empty() ? "" : "; ", prior.c_str());
    {
      std::lock_guard<std::mutex> lock(mutex_);
      noteSolve(status);
    }
    if (!job.dry_run) publish_(status);  // a dry run is answered, not announced
    if (job.result) job.result->set_value(status);
  }
}

// Caller holds mutex_: the diagnostics' record of a solve's status.
void OnlineCalibration::noteSolve(const CalibrationStatus& status) {
  last_solve_ = status;
  last_solve_time_ = ros::WallTime::now();
  if (status.outcome == CalibrationStatus::OUTCOME_COMMITTED) last_commit_time_ = last_solve_time_;
  if (!status.accepted) last_rejection_ = status.reason;
}

// A calibration the driver could not store (a full disk, a driver restarting).
void OnlineCalibration::scheduleCommitAgain() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!uncommitted_ || commit_again_queued_) return;
    if (!in_force_.stillInForce(*uncommitted_)) {
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
void OnlineCalibration::commitAgain() {
  std::optional<UncommittedCalibration> calibration;
  uint32_t before;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    commit_again_queued_ = false;
    if (uncommitted_ && in_force_.stillInForce(*uncommitted_)) calibration = uncommitted_;
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
  setOutcome(&status, core::CalibrationOutcome::kCommitted);
  status.reason.clear();
  readCommittedEpoch(calibration->infos, before, &status);
  NODELET_INFO("OnlineCalibrator: the accepted calibration the driver could not store before is committed now "
               "(epoch %u)",
               status.epoch);
  {
    std::lock_guard<std::mutex> lock(mutex_);  // no solve ran meanwhile: the worker runs one job at a time
    uncommitted_.reset();
    noteSolve(status);
  }
  publish_(status);
}

// Worker thread. Waits (bounded by service_timeout_s: the driver publishes the new calibration
// with its next frame) for the driver's first frame carrying `committed` and puts its epoch in
// `status`; without such a frame in time, the newest epoch seen, said so in the reason (the
// calibration was committed all the same).
void OnlineCalibration::readCommittedEpoch(const CommittedCalibration& committed, uint32_t before,
                                           CalibrationStatus* status) {
  std::optional<uint32_t> seen;
  uint32_t newest;
  {
    std::unique_lock<std::mutex> lock(mutex_);
    awaiting_commit_ = true;
    cv_.wait_for(lock, std::chrono::duration<double>(params_.service_timeout_s), [&] {
      return stopping_ || (seen = in_force_.epochCarrying(committed, before, windows_.frames())).has_value();
    });
    awaiting_commit_ = false;
    newest = epoch_;
  }
  status->epoch = seen.value_or(newest);
  if (seen) return;
  char text[200];
  std::snprintf(text, sizeof(text),
                "committed, but no frame with it on %s within %.1f s: epoch %u is the newest one seen",
                topics_.mode.c_str(), params_.service_timeout_s, newest);
  status->reason = text;
  NODELET_WARN("OnlineCalibrator: %s", text);
}

// Answered at once (the nodelet's second service thread): a queued request would switch the
// light and clear the window of the one running.
std::string OnlineCalibration::claimRequest(const std::string& caller, size_t frames) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (request_in_flight_) return "busy: a recalibration is already running (requested by " + request_caller_ + ")";
  request_in_flight_ = true;
  request_caller_ = caller;
  windows_.startRequest(frames);
  return "";
}

std::string OnlineCalibration::collectRequestWindow(size_t frames, double timeout_s, const CallerProbe& probe,
                                                    std::vector<core::StereoObservation>* frames_out) {
  using Clock = std::chrono::steady_clock;
  const auto deadline =
      Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeout_s));
  const auto probe_period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(kProbePeriodS));
  std::string abandoned;
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    if (stopping_) {
      abandoned = "the calibrator is shutting down";
      break;
    }
    const auto now = Clock::now();
    if (windows_.windowSize() >= frames || now >= deadline) break;
    if (cv_.wait_until(lock, std::min(deadline, now + probe_period),
                       [&] { return stopping_ || windows_.windowSize() >= frames; }))
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
  *frames_out = windows_.endRequest();
  return abandoned;
}

// The tracker tracks the burst as a whole after it ended.
bool OnlineCalibration::takeTheBurstsWindowObservation(std::vector<core::StereoObservation>* frames) {
  std::unique_lock<std::mutex> lock(mutex_);
  cv_.wait_for(lock, std::chrono::duration<double>(kRequestWindowWaitS),
               [this] { return stopping_ || windows_.hasRequestWindow(); });
  std::optional<core::StereoObservation> window = windows_.takeRequestWindow();
  if (!window) {
    NODELET_WARN("OnlineCalibrator: recalibrate: no window observation of the burst on %s within %.0f s; solving "
                 "its %zu per-frame observations",
                 topics_.window_observations.c_str(), kRequestWindowWaitS, frames->size());
    return false;
  }
  *frames = {std::move(*window)};
  return true;
}

CalibrationStatus OnlineCalibration::solveRequest(std::vector<core::StereoObservation> frames, bool dry_run,
                                                  bool window_observation) {
  Job job;
  job.frames = std::move(frames);
  job.dry_run = dry_run;
  job.window_observation = window_observation;
  job.result = std::make_shared<std::promise<CalibrationStatus>>();
  std::future<CalibrationStatus> result = job.result->get_future();
  submit(std::move(job));
  return result.get();  // the solve and commit are bounded (service calls: callService)
}

void OnlineCalibration::requestDone() {
  std::lock_guard<std::mutex> lock(mutex_);
  request_in_flight_ = false;
  request_caller_.clear();
  windows_.requestDone();
}

void OnlineCalibration::diagnose(diagnostic_updater::DiagnosticStatusWrapper& status, uint64_t stamp_guard_dropped) {
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
  status.add("frames in window", windows_.windowSize());
  status.add("dropped observation messages", dropped_messages_);
  status.add("observations dropped for a stamp going back", windows_.backwards());
  if (params_.window_observations) status.add("window observations received", windows_.windowObservations());
  status.add("messages dropped for a stamp far from the others", stamp_guard_dropped);
  status.add("last window ended early", last_window_end_);
  status.add("accepted calibration waiting to be committed again", uncommitted_.has_value());
}

}  // namespace embedded_calibration_stereo
