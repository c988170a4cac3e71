#pragma once
// One light window of a scenario's head, synthetic with known truth, solved as the calibrator
// solves it on a moving world (the device model, p1 and p2 estimated): the tests and benches of
// the calibration at the tracker's noise, the scene constraints and what earlier windows taught
// use this one set-up.
//
// Threading: free functions without shared state.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

// A scenario's true rig and device (the config's `rig` and `device`).
struct ScenarioHead {
  StereoRig truth;
  CalibrationDevice device;
};
ScenarioHead loadScenarioHead(const std::string& config_path);

struct SyntheticWindow {
  int frames = 1;                   // observations (1: a window tracker's one per window)
  double corner_noise_px = 0.0;     // per coordinate
  uint64_t corner_seed = 1;
  int scene_matches = 0;            // scene correspondences (generateSyntheticSceneMatches); 0: none
  double scene_noise_px = 0.06, scene_wrong = 0.0;
  uint64_t scene_seed = 2;
  // The nominal device given to the solve: the true one moved by these tolerances (seeded).
  double device_error_m = 0.001, device_error_deg = 0.5;
  uint64_t device_seed = 1800;
  std::optional<StereoRig> in_force;  // the calibration in force (default: the truth)
  std::optional<RigPrior> prior;
  const BundleAdjustmentSummary* weights_from = nullptr;
};

// The window of `truth` as the solve is given it: its observations (the scene's matches on the
// first), the nominal device, and how many wrong scene matches are among them.
struct SyntheticWindowData {
  std::vector<StereoObservation> frames;
  CalibrationDevice nominal;
  int scene_wrong = 0;
};
SyntheticWindowData makeSyntheticWindow(const ScenarioHead& head, const StereoRig& truth,
                                        const SyntheticWindow& window);

// The window of `truth` (the head's device seen by that rig) solved; *scene_wrong_count
// (optional): how many wrong scene matches it was given.
BundleAdjustmentSummary solveSyntheticWindow(const ScenarioHead& head, const StereoRig& truth,
                                             const SyntheticWindow& window, int* scene_wrong_count = nullptr);

}  // namespace embedded_calibration_stereo::core
