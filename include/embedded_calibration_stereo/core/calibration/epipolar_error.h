#pragma once
// Epipolar consistency of stereo corner observations with a calibration: the square root of the
// mean squared distance of the right corners to the epipolar lines of the matching left corners
// (same frame, board and corner id), in right-image pixels. Independent of any board model, so
// it judges the extrinsics alone.
//
// Threading: a pure function, safe from any thread.
#include <vector>

#include "embedded_calibration_stereo/core/calibration/observation_validator.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

double epipolarRms(const StereoRig& rig, const std::vector<BoardView>& views);

}  // namespace embedded_calibration_stereo::core
