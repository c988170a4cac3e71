#include "embedded_calibration_stereo/core/calibration/calibration_windows.h"

#include <algorithm>

namespace embedded_calibration_stereo::core {

double stampSeconds(StampNs stamp) {
  return static_cast<double>(stamp / 1000000000) + 1e-9 * static_cast<double>(stamp % 1000000000);
}

CalibrationWindows::CalibrationWindows(CalibrationWindowOptions options) : options_(options) {}

ModeResult CalibrationWindows::addMode(const FrameMode& mode, double now_s) {
  ModeResult result;
  for (const FrameSeen& seen : frames_)  // one frame per stamp
    if (seen.stamp == mode.stamp) {
      result.kind = ModeResult::Kind::kDuplicate;
      return result;
    }
  // Older than the newest frame: a time jump of the driver when by more than the stamp tolerance
  // (the nodelet's stamp guard lets such a jump through only once every input made it), otherwise
  // a late or stray message: kept for matching its observation, but it says nothing about the
  // light now.
  if (!frames_.empty() && mode.stamp < frames_.back().stamp) {
    if (stampSeconds(frames_.back().stamp) - stampSeconds(mode.stamp) > options_.stamp_tolerance_s) {
      result.time_jump_from = frames_.back().stamp;
      forgetAfterTimeJump();
    } else {
      result.kind = ModeResult::Kind::kLate;
    }
  }
  const bool late = result.kind == ModeResult::Kind::kLate;
  const FrameSeen seen{mode.stamp, mode.light_on && mode.settled, mode.epoch};
  if (late)
    frames_.insert(std::upper_bound(frames_.begin(), frames_.end(), mode.stamp,
                                    [](StampNs t, const FrameSeen& f) { return t < f.stamp; }),
                   seen);
  else
    frames_.push_back(seen);
  if (frames_.size() > options_.kept_frames) frames_.pop_front();
  for (auto it = pending_.begin(); it != pending_.end(); ++it)
    if (it->first == mode.stamp) {
      addToWindow(std::move(it->second), it->first, seen.calibrating, now_s);
      pending_.erase(it);
      break;
    }
  // The light went off: the window of the driver's schedule is complete.
  if (!late && !mode.light_on && !request_active_ && !window_.empty()) {
    window_closed_at_ = mode.stamp;
    if (solvesFrameWindows() && static_cast<int>(window_.size()) >= options_.min_frames)
      result.solve = std::move(window_);
    window_.clear();
  }
  return result;
}

ObservationFate CalibrationWindows::addObservation(StereoObservation observation, StampNs stamp, double now_s,
                                                   StampNs* previous) {
  if (previous) *previous = last_observation_;
  if (!stampAfterPrevious(stamp, &last_observation_)) return ObservationFate::kBackwards;  // one frame per stamp
  if (observation.left.empty() && observation.right.empty()) return ObservationFate::kNoBoard;
  for (const FrameSeen& frame : frames_)
    if (frame.stamp == stamp) {
      addToWindow(std::move(observation), stamp, frame.calibrating, now_s);
      return ObservationFate::kMatched;
    }
  pending_.emplace_back(stamp, std::move(observation));
  if (pending_.size() > options_.kept_frames) pending_.pop_front();
  return ObservationFate::kPending;
}

WindowObservationFate CalibrationWindows::addWindowObservation(StereoObservation observation, StampNs stamp,
                                                               std::optional<StereoObservation>* solve,
                                                               StampNs* previous) {
  if (previous) *previous = last_window_observation_;
  // Before the stamp: a copy must not move it on.
  if (repeated_windows_.repeats(observation)) return WindowObservationFate::kRepeated;
  if (!stampAfterPrevious(stamp, &last_window_observation_)) return WindowObservationFate::kBackwards;
  ++window_observations_;
  if (request_wants_window_ && stamp > request_started_) {  // the request's burst
    request_window_ = std::move(observation);
    return WindowObservationFate::kForRequest;
  }
  if (!options_.auto_calibrate || (observation.left.empty() && observation.right.empty()))
    return WindowObservationFate::kIgnored;
  *solve = std::move(observation);
  return WindowObservationFate::kSolve;
}

std::optional<IdleWindow> CalibrationWindows::endIdleWindow(double now_s) {
  if (request_active_ || window_.empty()) return std::nullopt;
  IdleWindow idle;
  idle.idle_s = now_s - last_window_frame_s_;
  if (idle.idle_s < options_.window_timeout_s) return std::nullopt;
  idle.frames = window_.size();
  if (solvesFrameWindows() && static_cast<int>(window_.size()) >= options_.min_frames)
    idle.end = IdleWindowEnd::kSolving;
  else if (options_.window_observations)
    idle.end = IdleWindowEnd::kWindowObservationsInstead;
  else if (options_.auto_calibrate)
    idle.end = IdleWindowEnd::kTooFewFrames;
  else
    idle.end = IdleWindowEnd::kAutoCalibrateOff;
  closeAtNewestFrame();
  if (idle.end == IdleWindowEnd::kSolving) idle.solve = std::move(window_);
  window_.clear();
  return idle;
}

void CalibrationWindows::startRequest(size_t frames) {
  request_active_ = true;
  request_frames_ = frames;
  window_.clear();
  closeAtNewestFrame();  // only frames from now on
  request_wants_window_ = options_.window_observations;
  request_started_ = window_closed_at_;
  request_window_.reset();
}

std::vector<StereoObservation> CalibrationWindows::endRequest() {
  std::vector<StereoObservation> frames = std::move(window_);
  window_.clear();
  closeAtNewestFrame();
  request_active_ = false;
  return frames;
}

std::optional<StereoObservation> CalibrationWindows::takeRequestWindow() {
  request_wants_window_ = false;
  std::optional<StereoObservation> window = std::move(request_window_);
  request_window_.reset();
  return window;
}

void CalibrationWindows::requestDone() {
  request_active_ = false;
  request_wants_window_ = false;
}

void CalibrationWindows::noteHealthVerdict(bool rig_changed, double stamp_s) {
  if (rig_changed) health_problem_s_ = std::max(health_problem_s_.value_or(0.0), stamp_s);
}

// A stamp not after the previous one (a replayed or restarted source, or the same message sent
// again) would put a frame in a window twice, or a frame of another timeline. A time jump of
// calibration_mode starts a new timeline.
bool CalibrationWindows::stampAfterPrevious(StampNs stamp, StampNs* last) {
  if (*last != 0 && stamp <= *last) {
    ++backwards_;
    return false;
  }
  *last = stamp;
  return true;
}

void CalibrationWindows::addToWindow(StereoObservation observation, StampNs stamp, bool calibrating, double now_s) {
  if (!calibrating || stamp <= window_closed_at_) return;
  const size_t cap = request_active_ ? request_frames_ : static_cast<size_t>(options_.max_frames);
  if (window_.size() >= cap) return;
  observation.stamp = stampSeconds(stamp);
  window_.push_back(std::move(observation));
  last_window_frame_s_ = now_s;
}

// Stamps went back (a bag replayed again, a restarted sim clock): the frames remembered so far
// belong to another timeline, and window_closed_at_ would hide every new frame.
void CalibrationWindows::forgetAfterTimeJump() {
  frames_.clear();
  pending_.clear();
  window_.clear();
  window_closed_at_ = 0;
  last_observation_ = 0;
  last_window_observation_ = 0;
}

void CalibrationWindows::closeAtNewestFrame() {
  if (!frames_.empty()) window_closed_at_ = frames_.back().stamp;
}

}  // namespace embedded_calibration_stereo::core
