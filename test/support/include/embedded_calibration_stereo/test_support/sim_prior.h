#pragma once
// The stereo pattern prior of a simulated head, taught as at the factory: the light-on frame
// minus a light-off frame of the same scene, for each camera, with the sim's device and nominal
// cameras identifying the boards. The one teach step of the tracker and health tests and benches.
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/tracker/board_prior.h"

namespace embedded_calibration_stereo::core {

PatternPrior teachSimPrior(const SimRig& sim, const SimFrame& light_on, const SimFrame& light_off);

// Renders the light-on (noise seed 1) and light-off (seed 2) frames at scene time `time_s`.
PatternPrior teachSimPrior(const SimRig& sim, double time_s);

}  // namespace embedded_calibration_stereo::core
