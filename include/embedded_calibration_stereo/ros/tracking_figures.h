#pragma once
// The PatternTracker's per-frame figures for its diagnostics: frames tracked, boards and corners
// found per camera in the last one, its time and the mean.
//
// Threading: not thread-safe (the nodelet's callback queue, where the diagnostics timer runs too).
#include <diagnostic_updater/DiagnosticStatusWrapper.h>

#include <cstddef>
#include <cstdint>

#include "embedded_calibration_stereo/StereoPatternObservation.h"

namespace embedded_calibration_stereo {

struct TrackingFigures {
  // One frame tracked into `msg` in `ms` milliseconds.
  void add(const StereoPatternObservation& msg, double ms);
  // Adds them to the diagnostics ("frames tracked", "left boards found", ...).
  void report(diagnostic_updater::DiagnosticStatusWrapper& status) const;

  uint64_t frames = 0;
  size_t boards[2] = {0, 0}, corners[2] = {0, 0};  // left, right, in the last frame
  double last_ms = 0.0, total_ms = 0.0;
};

}  // namespace embedded_calibration_stereo
