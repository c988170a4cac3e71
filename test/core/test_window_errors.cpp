// The calibrator's reported uncertainty when a window's frames share their corner errors.
//
// On a moving scene the boards stay put in the image while the scene behind them moves: the
// tracker's corners of one window then share most of their error across the window's frames
// (docs/figures.md, bench_calibrate_moving). The bundle adjuster averages each corner's track
// and weights the mean by the track length, which is right only for independent errors; with
// shared errors it must report the larger uncertainty the track means show. Checked against the
// truth over seeded trials: the true errors, in reported standard deviations, have a mean square
// near 1 both with independent and with shared errors.
#include <gtest/gtest.h>

#include <cstdio>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/test_support/solution_errors.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace embedded_calibration_stereo::core {
namespace {

// Adds the difference `noisy - exact` (one frame, same corners in the same order) to every frame.
void addSharedError(const StereoObservation& noisy, const StereoObservation& exact,
                    std::vector<StereoObservation>* frames) {
  for (StereoObservation& f : *frames)
    for (int side = 0; side < 2; ++side) {
      std::vector<BoardCorners>& boards = side == 0 ? f.left : f.right;
      const std::vector<BoardCorners>& n = side == 0 ? noisy.left : noisy.right;
      const std::vector<BoardCorners>& e = side == 0 ? exact.left : exact.right;
      ASSERT_EQ(boards.size(), n.size());
      for (size_t b = 0; b < boards.size(); ++b) {
        ASSERT_EQ(boards[b].size(), n[b].size());
        for (size_t i = 0; i < boards[b].size(); ++i) {
          boards[b].u[i] += n[b].u[i] - e[b].u[i];
          boards[b].v[i] += n[b].v[i] - e[b].v[i];
        }
      }
    }
}

// Mean over trials and estimated parameters of (error / reported sd)^2, and the fraction within
// 3 reported sd. shared_px: per-corner error common to the 10 frames; independent_px: per frame.
void meanSquareInStddevs(double shared_px, double independent_px, double* mean_z2, double* within3) {
  const StereoRig truth = makeSimLikeStereoRig();
  cv::FileStorage fs = openYaml(ECS_SOURCE_DIR "/config/sim_rig.yaml");
  const CalibrationDevice device = loadDevice(fs["device"], "device");
  constexpr int kTrials = 8;
  double z2 = 0;
  int n = 0, inside = 0;
  for (int trial = 0; trial < kTrials; ++trial) {
    SyntheticObservationOptions o;
    o.frames = 10;
    o.noise_sigma_px = independent_px;
    o.seed = 700 + trial;
    std::vector<StereoObservation> frames = generateSyntheticObservations(truth, device.virtualBoards(), o);
    if (shared_px > 0) {
      SyntheticObservationOptions one;
      one.noise_sigma_px = shared_px;
      one.seed = 800 + trial;
      const StereoObservation noisy = generateSyntheticObservations(truth, device.virtualBoards(), one)[0];
      one.noise_sigma_px = 0.0;
      const StereoObservation exact = generateSyntheticObservations(truth, device.virtualBoards(), one)[0];
      addSharedError(noisy, exact, &frames);
    }
    const CalibrationDevice nominal = perturbDevice(device, 0.001, 0.5, 900 + trial);
    CalibrationInput input;
    input.frames = &frames;
    input.device = &nominal;
    input.image_width = truth.left.width;
    input.image_height = truth.left.height;
    input.in_force = truth;
    const BundleAdjustmentSummary r = BundleAdjuster({}, {}).Solve(input);
    EXPECT_TRUE(r.success && r.covariance_ok) << r.message;
    for (double z : errorsInReportedStddevs(r, truth)) {
      z2 += z * z;
      inside += z <= 3.0;
      ++n;
    }
  }
  *mean_z2 = z2 / n;
  *within3 = static_cast<double>(inside) / n;
  std::printf("[ figures  ] shared %.3f px, independent %.3f px per frame: mean (error / reported sd)^2 %.2f, "
              "within 3 sd %.1f %% (%d parameter errors)\n",
              shared_px, independent_px, *mean_z2, 100 * *within3, n);
}

TEST(WindowErrors, IndependentErrorsKeepTheReportedStddev) {
  double z2 = 0, within = 0;
  meanSquareInStddevs(0.0, 0.1, &z2, &within);
  // Raised wrongly, the sd would leave the errors far inside (mean square well below 1).
  EXPECT_NEAR(z2, 1.0, 0.45);
  EXPECT_GE(within, 0.95);
}

TEST(WindowErrors, ErrorsSharedByTheFramesWidenTheReportedStddev) {
  double z2 = 0, within = 0;
  meanSquareInStddevs(0.1, 0.02, &z2, &within);
  // Weighted as independent, the sd would be ~3x too small: mean square ~9.
  EXPECT_NEAR(z2, 1.0, 0.45);
  EXPECT_GE(within, 0.95);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
