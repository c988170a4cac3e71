#include "embedded_calibration_stereo/core/driver/frame_pacer.h"

namespace embedded_calibration_stereo::core {

FramePacer::FramePacer(double fps, Clock::time_point start)
    : period_(std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / fps))), next_(start) {}

FramePacer::Clock::time_point FramePacer::next(Clock::time_point now) {
  next_ += period_;
  if (next_ < now - period_) next_ = now;
  return next_;
}

}  // namespace embedded_calibration_stereo::core
