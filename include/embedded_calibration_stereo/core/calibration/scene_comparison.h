#pragma once
// The scene's word on two calibrations of the same window (ROS-free). The boards all lie about
// 1.2 m away, where a small turn of a camera and a small shift of it move their corners alike:
// a calibration wrong by such a trade fits the boards as well as the right one, and only the
// scene's correspondences, at every depth, tell the two apart (scene_matches.h). The quality
// gate compares corner fits; this comparison is what it consults when the corners cannot decide.
//
// The figure is a likelihood ratio: the Sampson distances of the window's N scene matches to the
// epipolar lines of each calibration, clipped at clip_sigmas of the matches' robust spread at the
// candidate (a wrong match counts at most that), squared and summed (S), then N ln(S_in_force /
// S_candidate), the ratio with the matches' variance unknown. For a calibration in force as good
// as the candidate it is about a chi-square with the epipolar geometry's five degrees of freedom.
//
// Threading: free functions without shared state.
#include <vector>

#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

// Degrees of freedom of the epipolar geometry the scene constrains (a rotation and the
// direction of the baseline).
constexpr int kSceneComparisonDof = 5;

struct SceneComparison {
  int matches = 0;               // 0: not compared (no scene, or no calibration in force)
  double candidate_rms_px = 0;   // RMS of the clipped distances under the candidate
  double in_force_rms_px = 0;    // the same under the calibration in force
  double statistic = 0;          // N ln(in force's sum of clipped squares / candidate's)
};

// The signed Sampson distance (px, times focal_px) of each match to the epipolar line of `rig`.
std::vector<double> sceneEpipolarResiduals(const std::vector<SceneMatch>& matches, const StereoRig& rig,
                                           double focal_px);
// Their absolute values.
std::vector<double> sceneEpipolarDistances(const std::vector<SceneMatch>& matches, const StereoRig& rig,
                                           double focal_px);

// Both calibrations on the same matches, at the candidate's spread sigma_px (> 0).
SceneComparison compareOnScene(const std::vector<SceneMatch>& matches, const StereoRig& candidate,
                               const StereoRig& in_force, double sigma_px, double clip_sigmas);

}  // namespace embedded_calibration_stereo::core
