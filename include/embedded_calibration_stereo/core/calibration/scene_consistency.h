#pragma once
// Whether the scene matches of the light-off frames before a burst and of those after it show the
// same epipolar geometry (ROS-free). A window's scene matches come from both sides of its burst
// and are solved as taken under one calibration; a knock between them (or during the burst)
// breaks that, and the solve then settles between the two rigs. Against a guide calibration (any
// close one: the differences cancel), each side's signed epipolar residuals are fitted by a
// quadratic surface over the image, robustly; the two surfaces' RMS difference at the matches
// (not beyond them, where a surface says nothing) is the change, and its standard deviation
// follows from the fits' covariances.
//
// Threading: free functions without shared state.
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

struct SceneConsistencyOptions {
  // A change is a change when larger than this (px, RMS at the matches) and than
  // significance_sigmas of its own standard deviation.
  double max_change_px = 0.15;
  double significance_sigmas = 4.0;
  int min_matches = 30;  // per side; fewer: not compared
  std::string validate() const;  // empty when usable
};

struct SceneConsistency {
  bool compared = false;     // both sides had min_matches
  bool consistent = true;    // false: the rig changed between the two sides
  double change_px = 0.0;    // RMS of the difference of the two fits at the matches' positions
  double change_stddev_px = 0.0;
};

// `guide`: the calibration the matches are measured against (its image size is the frames').
// Throws std::invalid_argument for unusable options.
SceneConsistency compareSceneSides(const std::vector<SceneMatch>& before, const std::vector<SceneMatch>& after,
                                   const StereoRig& guide, const SceneConsistencyOptions& options = {});

}  // namespace embedded_calibration_stereo::core
