#include "embedded_calibration_stereo/ros/tracking_figures.h"

namespace embedded_calibration_stereo {

void TrackingFigures::add(const StereoPatternObservation& msg, double ms) {
  last_ms = ms;
  total_ms += ms;
  ++frames;
  for (int c = 0; c < 2; ++c) {
    const auto& side = c == 0 ? msg.left : msg.right;
    boards[c] = side.size();
    corners[c] = 0;
    for (const BoardObservation& b : side) corners[c] += b.corner_ids.size();
  }
}

void TrackingFigures::report(diagnostic_updater::DiagnosticStatusWrapper& status) const {
  status.add("frames tracked", frames);
  status.add("left boards found", boards[0]);
  status.add("left corners found", corners[0]);
  status.add("right boards found", boards[1]);
  status.add("right corners found", corners[1]);
}

}  // namespace embedded_calibration_stereo
