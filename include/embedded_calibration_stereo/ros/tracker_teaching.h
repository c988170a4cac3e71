#pragma once
// Teaching step of the PatternTracker nodelet: teaches both cameras of the device from one
// light-on stereo frame (with a light-off frame when available), or from one light burst, and
// stores the prior file atomically, so a reader never sees a half-written prior.
//
// Threading: a pure function of its arguments (called on the nodelet's worker thread); the two
// cameras are taught concurrently.
#include <string>

#include "embedded_calibration_stereo/core/tracker/board_teacher.h"
#include "embedded_calibration_stereo/core/tracker/window_teacher.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo {

// What teaching hands back: a stereo prior (left, right), written to the file unless
// write_error says why not, or an error.
struct TeachOutcome {
  ecs::PatternPrior prior;
  std::string error;        // empty when taught
  std::string write_error;  // taught, but the file could not be written (a full disk): empty when written
  std::string notes;  // the teacher's notes of both cameras
  double ms = 0.0;    // wall time of teaching and writing
};

// Teaches left and right with the device's virtual boards seen by the nominal cameras of
// `device` (as track_pattern teach --device does), then writes `path` (writeStereoPrior). Never
// throws.
TeachOutcome teachStereoPrior(const ecs::TeachFrame& left, const ecs::TeachFrame& right, ecs::ColorOrder order,
                              const ecs::SimRigConfig& device, const std::string& path);

// The same from one light burst of each camera (frames in BGR order when in colour): each taught
// on the device image learned from the burst's light pairs (core/tracker/window_teacher.h), no
// covered or still scene needed. The images taught on are written beside the prior
// (taughtOnImagePath; a failure is only noted).
TeachOutcome teachStereoPriorFromBurst(const ecs::WindowFrames& left, const ecs::WindowFrames& right,
                                       const ecs::SimRigConfig& device, const std::string& path);

// Writes `prior` to `path` through a temporary file in the same directory and a rename
// (creating missing directories). Returns "" on success, otherwise why not. Never throws.
std::string writeStereoPrior(const std::string& path, const ecs::PatternPrior& prior);

// PRIOR_left_device.png for PRIOR.yaml and camera "left".
std::string taughtOnImagePath(const std::string& prior_path, const std::string& camera_name);

// $ROS_HOME/ecs_pattern_prior.yaml, or ~/.ros/ecs_pattern_prior.yaml without ROS_HOME.
std::string defaultPatternPriorFile();

}  // namespace embedded_calibration_stereo
