#pragma once
// Which frames of a stream to measure, so that measurements come at a set rate whatever the
// frame rate: at 15 a second, every other frame at 30 fps, every frame at 15 fps, 3 of 4 at
// 20 fps. Each frame adds credit in proportion to the time since the previous one (by stamp);
// a frame is measured when a measurement's worth has built up, give or take a tenth (a
// driver's stamps jitter). After a gap (a stalled source, a bag played from a later point) at
// most half a measurement's credit is kept, so measurements do not come back to back to catch
// up. Stamps going back (a restarted source, a bag played again) start over.
//
// Threading: not thread-safe; one owner (e.g. a nodelet's frame callback).
#include <optional>

namespace embedded_calibration_stereo::core {

class MeasurementRate {
 public:
  // `rate_hz` > 0, finite (std::invalid_argument otherwise).
  explicit MeasurementRate(double rate_hz);
  // Whether the frame stamped `stamp_s` (seconds) is measured. The first frame is.
  bool take(double stamp_s);

 private:
  double rate_hz_;
  std::optional<double> previous_s_;
  double credit_ = 1.0;  // in measurements
};

}  // namespace embedded_calibration_stereo::core
