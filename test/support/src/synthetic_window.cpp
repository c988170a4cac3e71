#include "embedded_calibration_stereo/test_support/synthetic_window.h"

#include <vector>

#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace embedded_calibration_stereo::core {

ScenarioHead loadScenarioHead(const std::string& config_path) {
  cv::FileStorage fs = openYaml(config_path);
  return {loadStereoRig(fs["rig"], "rig"), loadDevice(fs["device"], "device")};
}

SyntheticWindowData makeSyntheticWindow(const ScenarioHead& head, const StereoRig& truth,
                                        const SyntheticWindow& window) {
  SyntheticObservationOptions o;
  o.frames = window.frames;
  o.noise_sigma_px = window.corner_noise_px;
  o.seed = window.corner_seed;
  SyntheticWindowData data;
  data.frames = generateSyntheticObservations(truth, head.device.virtualBoards(), o);
  if (window.scene_matches > 0)
    data.frames[0].scene = generateSyntheticSceneMatches(truth, window.scene_matches, window.scene_noise_px,
                                                         window.scene_wrong, window.scene_seed, &data.scene_wrong);
  data.nominal = window.device_error_m > 0.0 || window.device_error_deg > 0.0
                     ? perturbDevice(head.device, window.device_error_m, window.device_error_deg, window.device_seed)
                     : head.device;
  return data;
}

BundleAdjustmentSummary solveSyntheticWindow(const ScenarioHead& head, const StereoRig& truth,
                                             const SyntheticWindow& window, int* scene_wrong_count) {
  const SyntheticWindowData data = makeSyntheticWindow(head, truth, window);
  if (scene_wrong_count) *scene_wrong_count = data.scene_wrong;
  CalibrationInput input;
  input.frames = &data.frames;
  input.device = &data.nominal;
  input.image_width = truth.left.width;
  input.image_height = truth.left.height;
  input.in_force = window.in_force ? *window.in_force : truth;
  input.rig_prior = window.prior;
  input.weights_from = window.weights_from;
  BundleAdjustmentConfig terms;
  terms.estimate_tangential = true;
  return BundleAdjuster({}, terms).Solve(input);
}

}  // namespace embedded_calibration_stereo::core
