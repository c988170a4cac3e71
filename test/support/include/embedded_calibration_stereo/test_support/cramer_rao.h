#pragma once
// The Cramer-Rao bound of a stereo calibration from corner observations, computed independently
// of the bundle adjuster: the Fisher information sum J^T J / sigma^2 over every corner a data
// set sees, J from OpenCV's own projection Jacobians (cv::projectPoints, cv::composeRT) at the
// truth, inverted. Parameters: fx, fy, cx, cy, k1, k2 of each camera, right_from_left (rotation
// vector, translation) and one free pose per virtual board - what kSharedAcrossFrames estimates.
// Every frame of such a data set repeats the same information, so n frames have n times one
// frame's. The lowest standard deviation any unbiased estimator reaches with these parameters;
// a model with fewer (the rigid device) can only do better.
//
// Threading: a free function without shared state.
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"

namespace embedded_calibration_stereo::core {

struct CramerRaoBound {
  CameraStddev left_stddev, right_stddev;  // fx, fy, cx, cy, k1, k2 (p1, p2, k3 zero)
  double baseline_stddev_m = 0;            // along the baseline, as the adjuster reports it
  double rotation_stddev_deg = 0;          // sqrt of the largest eigenvalue, rotation vector
};

// `visible`: the corners the data set sees (a noise-free frame of it), board_id indexing
// `boards`; `sigma_px`: the corner noise per coordinate.
CramerRaoBound freePoseCramerRaoBound(const StereoRig& truth, const std::vector<VirtualBoard>& boards,
                                      const StereoObservation& visible, int frames, double sigma_px);

}  // namespace embedded_calibration_stereo::core
