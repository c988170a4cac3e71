#include "embedded_calibration_stereo/core/calibration/measurement_rate.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace embedded_calibration_stereo::core {

namespace {
constexpr double kJitter = 0.1;      // a measurement is due this much before its whole credit
constexpr double kMaxCredit = 1.5;   // kept through a gap: one measurement and half the next
}  // namespace

MeasurementRate::MeasurementRate(double rate_hz) : rate_hz_(rate_hz) {
  if (!std::isfinite(rate_hz) || rate_hz <= 0.0) throw std::invalid_argument("measurement rate must be > 0");
}

bool MeasurementRate::take(double stamp_s) {
  if (previous_s_ && stamp_s >= *previous_s_)
    credit_ = std::min(credit_ + rate_hz_ * (stamp_s - *previous_s_), kMaxCredit);
  else
    credit_ = 1.0;  // the first frame, or stamps that went back: start over
  previous_s_ = stamp_s;
  if (credit_ < 1.0 - kJitter) return false;
  credit_ -= 1.0;
  return true;
}

}  // namespace embedded_calibration_stereo::core
