#include "embedded_calibration_stereo/core/tracker/teaching_plan.h"

namespace embedded_calibration_stereo::core {

const char* toString(PriorState state) {
  switch (state) {
    case PriorState::kLoaded: return "loaded";
    case PriorState::kMissing: return "missing";
    case PriorState::kCorrupt: return "corrupt";
    case PriorState::kTeaching: return "teaching";
    case PriorState::kTeachFailed: return "teaching failed";
  }
  return "?";
}

void TeachingPlan::priorMissing(bool teach_on_start) {
  state_ = PriorState::kMissing;
  requested_ = teach_on_start;
}

void TeachingPlan::priorUnusable(const std::string& error) {
  state_ = PriorState::kCorrupt;
  error_ = error;
}

void TeachingPlan::tracking() {
  state_ = PriorState::kLoaded;
  error_.clear();
}

bool TeachingPlan::request() {
  if (state_ == PriorState::kTeaching) return false;
  requested_ = true;
  return true;
}

TeachingPlan::LightOnStep TeachingPlan::lightOn(int burst_light_on_frames, bool light_off_matches) const {
  if (!requested_) return LightOnStep::kNone;
  switch (from_) {
    case TeachFrom::kGroundTruth: return LightOnStep::kMatchGroundTruth;
    case TeachFrom::kBurst:
      // A prior that missed boards on a burst under way waits for a burst's end, with light-off
      // frames on both sides of its light-on frames.
      return !at_burst_end_ && burst_light_on_frames >= kTeachLightOnFrames ? LightOnStep::kTeachOnBurstUnderWay
                                                                            : LightOnStep::kWaitForBurst;
    case TeachFrom::kLightOff:
      // The scene must cancel: without a light-off frame most boards are missed.
      return light_off_matches ? LightOnStep::kTeachOnLightOff : LightOnStep::kWaitForLightOff;
  }
  return LightOnStep::kNone;
}

TeachingPlan::BurstStep TeachingPlan::burstEnded(bool usable, bool window_tracking) const {
  const bool teach_from_burst = requested_ && from_ == TeachFrom::kBurst;
  if (teach_from_burst && usable) return window_tracking ? BurstStep::kTeachThenTrack : BurstStep::kTeach;
  // Usually the burst being taught on: tracked with its prior once taught.
  if (state_ == PriorState::kTeaching && window_tracking && usable) return BurstStep::kTrackOncePrior;
  if (!window_tracking) return teach_from_burst ? BurstStep::kCannotTeach : BurstStep::kIgnore;
  if (!usable) return BurstStep::kDropUnusable;
  return state_ == PriorState::kLoaded ? BurstStep::kTrack : BurstStep::kDropNoPrior;
}

void TeachingPlan::teachingStarted(bool burst_under_way) {
  state_ = PriorState::kTeaching;
  requested_ = false;
  at_burst_end_ = false;
  partial_ = burst_under_way;
}

bool TeachingPlan::teachAgainIfBoardsMissing(size_t left_boards, size_t right_boards, size_t device_boards) {
  const bool partial = partial_;
  partial_ = false;
  // One-sided light pairs leave more scene in the device image than a whole burst's.
  if (!partial || (left_boards >= device_boards && right_boards >= device_boards)) return false;
  requested_ = true;
  at_burst_end_ = true;
  return true;
}

void TeachingPlan::teachFailed(const std::string& error) {
  state_ = PriorState::kTeachFailed;
  error_ = error;
  partial_ = false;
}

TeachingPlan::Summary TeachingPlan::summary(bool prior_unwritten, const std::string& write_error) const {
  const Level idle = requested_ ? Level::kWarn : Level::kError;
  switch (state_) {
    case PriorState::kLoaded:
      if (prior_unwritten) return {Level::kWarn, "tracking; prior file not written yet: " + write_error};
      return {Level::kOk, "tracking"};
    case PriorState::kTeaching: return {Level::kOk, "teaching"};
    case PriorState::kMissing:
      return {idle, requested_ ? std::string("prior missing: ") + teachesAt() : "prior missing: idle until teaching"};
    case PriorState::kCorrupt:
    case PriorState::kTeachFailed: break;
  }
  return {idle, std::string(toString(state_)) + ": " + error_};
}

std::string TeachingPlan::idleReason() const {
  if (state_ == PriorState::kMissing) return "is missing";
  if (state_ == PriorState::kTeachFailed) return "was not taught (" + error_ + ")";
  return "is unusable (" + error_ + ")";
}

const char* TeachingPlan::teachesAt() const {
  return from_ == TeachFrom::kBurst ? "teaching at the next light burst"
                                    : "teaching at the next settled light-on frame";
}

}  // namespace embedded_calibration_stereo::core
