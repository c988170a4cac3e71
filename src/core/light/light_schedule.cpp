#include "embedded_calibration_stereo/core/light/light_schedule.h"

#include <algorithm>
#include <cmath>

namespace embedded_calibration_stereo::core {

std::string LightScheduleConfig::validate() const { return problem().text(); }

ConfigProblem LightScheduleConfig::problem() const {
  const auto nonNegative = [](double v) { return std::isfinite(v) && v >= 0.0; };
  if (!nonNegative(period_s)) return {"calibration_period_s", "must be >= 0"};
  if (calibration_frames < 0) return {"calibration_frames", "must be >= 0 (0: calibration_duration_s decides)"};
  if (!nonNegative(calibration_duration_s)) return {"calibration_duration_s", "must be >= 0"};
  if (calibration_frames == 0 && calibration_duration_s <= 0.0)
    return {"calibration_duration_s", "must be > 0 when calibration_frames is 0"};
  if (settle_frames < 0) return {"settle_frames", "must be >= 0"};
  if (!nonNegative(min_interval_s)) return {"min_calibration_interval_s", "must be >= 0"};
  if (!nonNegative(verification_period_s)) return {"verification_period_s", "must be >= 0"};
  if (!nonNegative(first_burst_delay_s)) return {"first_burst_delay_s", "must be >= 0"};
  return {};
}

LightSchedule::LightSchedule(const LightScheduleConfig& config) : config_(config) {}

void LightSchedule::request(bool on) {
  hold_on_ = on;
  if (!on) burst_frames_left_ = 0;
}

void LightSchedule::startBurst(double time_s) {
  if (burst_frames_left_ == 0) {
    // A timed burst holds at least one frame beyond settling until countBurstFrame ends it.
    burst_frames_left_ = config_.settle_frames + std::max(config_.calibration_frames, 1);
    burst_frame_index_ = 0;
    burst_start_s_ = time_s;
  }
  flash_frames_left_ = 0;  // the burst's frames verify as well
  last_burst_end_s_ = time_s;  // moved to its last lit frame when it gets there
  if (config_.verification_period_s > 0.0) next_flash_s_ = time_s + config_.verification_period_s;
}

void LightSchedule::calibrationInForce(uint32_t epoch) {
  if (epoch_ && *epoch_ != epoch) verifySoon();
  epoch_ = epoch;
}

LightState LightSchedule::step(double time_s) {
  if (!started_) {
    started_ = true;
    previous_step_s_ = time_s;
    next_burst_s_ = time_s + config_.first_burst_delay_s;
    next_flash_s_ = time_s + config_.verification_period_s;
    // The first burst first_burst_delay_s after the first frame when there is a period; on
    // demand, as soon as demanded after that.
    last_burst_end_s_ = time_s + config_.first_burst_delay_s - config_.min_interval_s;
  }
  startBurstIfDue(time_s);
  startFlashIfDue(time_s);
  const bool flash = burst_frames_left_ == 0 && flash_frames_left_ > 0;
  const bool commanded_on = hold_on_ || burst_frames_left_ > 0 || flash;
  if (burst_frames_left_ > 0) countBurstFrame(time_s);
  if (flash) --flash_frames_left_;
  previous_step_s_ = time_s;
  LightState state = advance(commanded_on);
  state.verification = flash && !hold_on_;
  return state;
}

void LightSchedule::countBurstFrame(double time_s) {
  const int64_t index = burst_frame_index_++;
  if (config_.calibration_frames == 0 && index >= config_.settle_frames) {
    if (index == config_.settle_frames) burst_settled_s_ = time_s;
    // The frame interval: the burst's mean so far, or the one before it on its first frame.
    const double interval = index > 0 ? (time_s - burst_start_s_) / index : time_s - previous_step_s_;
    // n settled frames cover n intervals; stop at the n nearest the duration.
    const double covered = time_s - burst_settled_s_ + interval;
    burst_frames_left_ = covered + 0.5 * interval >= config_.calibration_duration_s ? 1 : 2;
  }
  if (--burst_frames_left_ == 0) last_burst_end_s_ = time_s;
}

void LightSchedule::startBurstIfDue(double time_s) {
  const bool on_demand = config_.trigger == CalibrationTrigger::kOnDemand;
  if (config_.period_s > 0.0 && time_s >= next_burst_s_) {
    startBurst(time_s);
    // Skip bursts missed while the driver was stalled instead of firing them back to back.
    while (next_burst_s_ <= time_s) next_burst_s_ += config_.period_s;
  } else if (on_demand && demand_ && burst_frames_left_ == 0 && time_s - last_burst_end_s_ >= config_.min_interval_s) {
    startBurst(time_s);
    if (config_.period_s > 0.0) next_burst_s_ = time_s + config_.period_s;  // the safety net restarts
  }
}

void LightSchedule::startFlashIfDue(double time_s) {
  // A burst, a hold or a flash still to reach its settled frame verifies already.
  if (burst_frames_left_ > 0 || hold_on_ || flash_frames_left_ > 0) {
    verify_soon_ = false;
    return;
  }
  if (config_.verification_period_s > 0.0 && (verify_soon_ || time_s >= next_flash_s_)) {
    verify_soon_ = false;
    flash_frames_left_ = config_.settle_frames + 1;
    while (next_flash_s_ <= time_s) next_flash_s_ += config_.verification_period_s;
  }
}

LightState LightSchedule::follow(bool light_on) { return advance(light_on); }

LightState LightSchedule::advance(bool commanded_on) {
  LightState state;
  state.light_on = commanded_on;
  state.switched = commanded_on != previous_on_;
  if (state.switched) frames_since_switch_ = 0;
  previous_on_ = commanded_on;

  const int settle = config_.settle_frames;
  state.settled = frames_since_switch_ >= settle;
  if (state.settled) {
    state.light_level = commanded_on ? 1.0 : 0.0;
  } else {
    // Linear ramp over the settling frames, never reaching the end value before settling.
    const double progress = static_cast<double>(frames_since_switch_ + 1) / (settle + 1);
    state.light_level = commanded_on ? progress : 1.0 - progress;
  }
  frames_since_switch_ = std::min<int64_t>(frames_since_switch_ + 1, int64_t(1) << 30);
  return state;
}

}  // namespace embedded_calibration_stereo::core
