#pragma once
// When the CameraDriver takes its next frame (docs/nodelets.md#cameradriver): every 1/fps on the
// steady clock, keeping the cadence through small delays; after a frame later than a whole
// period (a stalled backend, a slow disk) the cadence restarts instead of taking the missed
// frames back to back.
//
// Threading: plain values; used by one thread (the capture thread).
#include <chrono>

namespace embedded_calibration_stereo::core {

class FramePacer {
 public:
  using Clock = std::chrono::steady_clock;

  /// `fps` > 0; the first deadline is `start`.
  FramePacer(double fps, Clock::time_point start);

  /// The deadline of the next frame, the previous one having finished at `now`.
  Clock::time_point next(Clock::time_point now);

 private:
  Clock::duration period_;
  Clock::time_point next_;
};

}  // namespace embedded_calibration_stereo::core
