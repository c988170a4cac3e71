// The bundle adjuster's rigid device model (the default board-pose mode when the device is
// given) against simulated corner observations of the sim's head (config/sim_rig.yaml: truth
// rig and device; three 8x6 boards of 34 mm, two single-plane mirror copies, six virtual boards
// at 1.13-1.26 m). The nominal device given to the adjuster is the true one moved by
// manufacturing tolerances (1 mm, 0.5 deg: perturbDevice). Corner noise 0.2 px.
//
// The calibrator's bounds (fx, fy <= 0.05 %, cx, cy <= 0.3 px, k1 <= 0.005, baseline <= 0.1 %,
// rotation <= 0.01 deg, 1 to 10 frames; true error within 3 reported sd for >= 95 % of the
// parameters over 20 trials) against what this geometry supports (bench_calibrator --rig
// config/sim_rig.yaml --zero-tangential 1 --trials 20 --frames 1,10 prints the reported sd and
// the coverage of both board models; docs/figures.md).
// Met: the coverage (1 and 10 frames) and k1 at 10 frames.
// NOT met: fx/fy, cx, cy, baseline and rotation (their sd at 10 frames are above the bounds,
// or too close to them for the worst trial), nor k1 at 1 frame. All the boards are 1.13-1.26 m
// from the cameras, so the right camera's translation trades against its rotation and principal
// point, and the corner noise allows no more. The tests assert what is met and, for the rest,
// that the reported sd are real (the true errors' scatter over 20 trials) and below the
// free-pose Cramer-Rao bound of the same boards.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>

#include "embedded_calibration_stereo/test_support/cramer_rao.h"
#include "embedded_calibration_stereo/test_support/solution_errors.h"
#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/core/calibration/quality_gate.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace embedded_calibration_stereo::core {
namespace {

struct SimScenario {
  StereoRig truth;
  CalibrationDevice device;  // the truth
  explicit SimScenario(bool keep_tangential = false) {
    cv::FileStorage fs = openYaml(ECS_SOURCE_DIR "/config/sim_rig.yaml");
    truth = loadStereoRig(fs["rig"], "rig");
    device = loadDevice(fs["device"], "device");
    // The default distortion model is k1, k2: a truth with p1, p2 would bias it.
    if (!keep_tangential)
      for (PinholeCamera* c : {&truth.left, &truth.right}) c->dist[2] = c->dist[3] = 0.0;
  }
  std::vector<StereoObservation> observe(int frames, double noise, uint64_t seed) const {
    SyntheticObservationOptions o;
    o.frames = frames;
    o.noise_sigma_px = noise;
    o.seed = seed;
    return generateSyntheticObservations(truth, device.virtualBoards(), o);
  }
  CalibrationDevice nominal(uint64_t seed) const { return perturbDevice(device, 0.001, 0.5, seed); }
  StereoRig drifted() const {  // 5 % zoom and a 0.3 deg knock of the right camera
    return driftedRig(truth, 1.05, Eigen::Vector3d(0.1, 0.3, -0.05).normalized() * 0.3);
  }
};

BundleAdjustmentSummary solve(const std::vector<StereoObservation>& frames,
                              const CalibrationDevice& device, std::optional<StereoRig> in_force,
                              BundleAdjustmentOptions options = {},
                              BundleAdjustmentConfig config = {}) {
  CalibrationInput input;
  input.frames = &frames;
  input.device = &device;
  input.image_width = 752;
  input.image_height = 480;
  input.in_force = std::move(in_force);
  return BundleAdjuster(options, config).Solve(input);
}

// A prior so loose that it only fixes the gauge: noise-free solves are then exact (the default
// prior pulls them slightly, see below).
BundleAdjustmentOptions withoutPrior() {
  BundleAdjustmentOptions o;
  o.device_prior_angle_deg = 5000.0;
  o.device_prior_position_m = 10.0;
  return o;
}

void expectExact(const BundleAdjustmentSummary& r, const StereoRig& truth) {
  const RigErrors e = compareRigs(r.rig, truth);
  for (int c = 0; c < 2; ++c) {
    EXPECT_LT(e.fx_rel[c], 1e-6) << "camera " << c;
    EXPECT_LT(e.fy_rel[c], 1e-6) << "camera " << c;
    EXPECT_LT(e.cx_px[c], 1e-3) << "camera " << c;
    EXPECT_LT(e.cy_px[c], 1e-3) << "camera " << c;
    EXPECT_LT(e.k1[c], 1e-5) << "camera " << c;
    EXPECT_LT(e.k2[c], 1e-5) << "camera " << c;
  }
  EXPECT_LT(e.baseline_rel, 1e-6);
  EXPECT_LT(e.rotation_deg, 1e-5);
}

// Largest distance between the estimated and the true virtual corners: the device pose and the
// planes have a gauge freedom (device_model_adjustment.h), the virtual boards do not.
double virtualCornerError(const BundleAdjustmentSummary& r, const CalibrationDevice& truth) {
  double worst = 0.0;
  for (const VirtualBoard& b : truth.virtualBoards())
    for (int id = 0; id < b.cornerCount(); ++id)
      worst = std::max(
          worst,
          (r.rig_from_board.at(b.virtual_id) * b.cornerInBoard(id) - b.cornerInRig(id)).norm());
  return worst;
}

TEST(DeviceModel, IsTheDefaultWhenTheDeviceIsGivenAndRecoversTheTruthWithoutNoise) {
  const SimScenario s;
  const auto frames = s.observe(2, 0.0, 1);
  const CalibrationDevice nominal = s.nominal(1);
  for (const std::optional<StereoRig>& in_force :
       {std::optional<StereoRig>(), std::optional<StereoRig>(s.drifted())}) {
    const BundleAdjustmentSummary r = solve(frames, nominal, in_force, withoutPrior());
    ASSERT_TRUE(r.success) << r.message;
    EXPECT_TRUE(r.converged) << r.message;
    EXPECT_EQ(r.board_poses, "device model");
    EXPECT_EQ(r.initialization, in_force ? "in force" : "zhang");
    EXPECT_LT(r.rms_left_px, 1e-3);
    EXPECT_LT(r.rms_right_px, 1e-3);
    expectExact(r, s.truth);
    ASSERT_TRUE(r.device.has_value());
    EXPECT_LT(virtualCornerError(r, s.device), 1e-6);
    // The default gauge prior pulls the solution slightly, far less than the 10-frame
    // standard deviation: the bounds below allow for it.
    const BundleAdjustmentSummary d = solve(frames, nominal, in_force);
    ASSERT_TRUE(d.success) << d.message;
    EXPECT_LT(compareRigs(d.rig, s.truth).fx_rel[0], 1e-5);
    EXPECT_LT(compareRigs(d.rig, s.truth).rotation_deg, 1e-4);
  }
}

TEST(DeviceModel, TangentialTermsOfTheSimTruthAreRecoveredWhenEstimated) {
  const SimScenario s(true);
  ASSERT_NE(s.truth.left.dist[2], 0.0);
  BundleAdjustmentConfig tangential;
  tangential.estimate_tangential = true;
  const BundleAdjustmentSummary exact =
      solve(s.observe(1, 0.0, 2), s.nominal(2), std::nullopt, withoutPrior(), tangential);
  ASSERT_TRUE(exact.success) << exact.message;
  expectExact(exact, s.truth);
  EXPECT_NEAR(exact.rig.left.dist[2], s.truth.left.dist[2], 2e-7);  // u, v are float32
  EXPECT_NEAR(exact.rig.right.dist[3], s.truth.right.dist[3], 2e-7);
  // With noise: within 4 reported sd, the tangential terms included.
  const BundleAdjustmentSummary noisy =
      solve(s.observe(10, 0.2, 3), s.nominal(3), s.drifted(), {}, tangential);
  ASSERT_TRUE(noisy.success && noisy.covariance_ok) << noisy.message;
  for (double z : errorsInReportedStddevs(noisy, s.truth)) EXPECT_LE(z, 4.0);
  EXPECT_GT(noisy.left_stddev.dist[2], 0.0);
  EXPECT_LE(std::abs(noisy.rig.left.dist[2] - s.truth.left.dist[2]), 4 * noisy.left_stddev.dist[2]);
  // The default model (k1, k2) cannot fit the sim truth exactly.
  const BundleAdjustmentSummary biased = solve(s.observe(1, 0.0, 2), s.nominal(2), std::nullopt);
  ASSERT_TRUE(biased.success);
  EXPECT_GT(std::max(biased.rms_left_px, biased.rms_right_px), 0.01);
}

// Reported sd against two independent references: the Cramer-Rao bound of the same virtual
// boards with free poses (cramer_rao.h, OpenCV's Jacobians at the truth), which the rigid model
// must beat - it estimates fewer parameters from the same corners - and, over 20 trials, the
// true errors (next test). Errors within 4 sd.
TEST(DeviceModel, NoisyFramesAreWithinTheReportedStddevsAndBelowTheFreePoseBound) {
  const SimScenario s;
  const StereoObservation visible = s.observe(1, 0.0, 1).front();
  for (int frames : {1, 10}) {
    SCOPED_TRACE(std::to_string(frames) + " frame(s)");
    const BundleAdjustmentSummary r = solve(s.observe(frames, 0.2, 4), s.nominal(4), s.drifted());
    ASSERT_TRUE(r.success) << r.message;
    ASSERT_TRUE(r.converged);
    ASSERT_TRUE(r.covariance_ok);
    EXPECT_EQ(r.boards_left, 6);
    EXPECT_EQ(r.boards_right, 6);
    EXPECT_NEAR(r.rms_left_px, 0.2 * std::sqrt(2.0), 0.03);
    EXPECT_NEAR(r.residual_sigma_px, 0.2, 0.02);
    for (double z : errorsInReportedStddevs(r, s.truth)) EXPECT_LE(z, 4.0);
    const CramerRaoBound free = freePoseCramerRaoBound(s.truth, s.device.virtualBoards(), visible, frames, 0.2);
    for (int c = 0; c < 2; ++c) {
      const CameraStddev& sd = c == 0 ? r.left_stddev : r.right_stddev;
      const CameraStddev& bound = c == 0 ? free.left_stddev : free.right_stddev;
      const char* side = c == 0 ? "left" : "right";
      EXPECT_LT(sd.fx, bound.fx) << side;
      EXPECT_LT(sd.fy, bound.fy) << side;
      EXPECT_LT(sd.cx, bound.cx) << side;
      EXPECT_LT(sd.cy, bound.cy) << side;
      EXPECT_LT(sd.dist[0], bound.dist[0]) << side;
      EXPECT_LT(sd.dist[1], bound.dist[1]) << side;
    }
    EXPECT_LT(r.baseline_stddev_m, free.baseline_stddev_m);
    EXPECT_LT(r.rotation_stddev_deg, free.rotation_stddev_deg);
    // The virtual boards are found to about a centimetre from one frame (each board's placement
    // is refined too), a few millimetres from ten.
    EXPECT_LT(virtualCornerError(r, s.device), frames == 1 ? 0.015 : 0.005);
    std::cout << frames << " frame(s): sd (free-pose Cramer-Rao bound) left fx "
              << r.left_stddev.fx / r.rig.left.fx << " (" << free.left_stddev.fx / s.truth.left.fx << ") cx "
              << r.left_stddev.cx << " (" << free.left_stddev.cx << ") cy " << r.left_stddev.cy << " ("
              << free.left_stddev.cy << ") k1 " << r.left_stddev.dist[0] << " (" << free.left_stddev.dist[0]
              << "), right fx " << r.right_stddev.fx / r.rig.right.fx << " cx " << r.right_stddev.cx << " cy "
              << r.right_stddev.cy << " k1 " << r.right_stddev.dist[0] << ", baseline "
              << r.baseline_stddev_m / r.rig.baseline() << " (" << free.baseline_stddev_m / s.truth.baseline()
              << ") rotation " << r.rotation_stddev_deg << " (" << free.rotation_stddev_deg << ") deg, k2 "
              << r.left_stddev.dist[1] << "; gate: " << QualityGate(GateOptions{}).evaluate(r, nullptr).reason
              << "\n";
  }
}

// The calibrator's coverage bound, and its k1 bound at 10 frames, over 20 trials; a fresh nominal
// device (1 mm, 0.5 deg off) per trial.
TEST(DeviceModel, AccuracyTargetsThatAreMetOverTwentyTrials) {
  const SimScenario s;
  for (int frames : {1, 10}) {
    int inside = 0, total = 0;
    double worst_k1 = 0.0;
    std::vector<double> sum_z2(14, 0.0);
    const int kTrials = 20;
    for (int trial = 0; trial < kTrials; ++trial) {
      const BundleAdjustmentSummary r =
          solve(s.observe(frames, 0.2, 100 + trial), s.nominal(200 + trial), s.truth);
      ASSERT_TRUE(r.success && r.covariance_ok) << r.message;
      const std::vector<double> zs = errorsInReportedStddevs(r, s.truth);
      ASSERT_EQ(zs.size(), sum_z2.size());
      for (size_t i = 0; i < zs.size(); ++i) {
        ++total;
        if (zs[i] <= 3.0) ++inside;
        sum_z2[i] += zs[i] * zs[i];
      }
      const RigErrors e = compareRigs(r.rig, s.truth);
      worst_k1 = std::max({worst_k1, e.k1[0], e.k1[1]});
    }
    std::cout << frames << " frame(s): within 3 reported stddevs " << inside << " of " << total
              << ", worst k1 error " << worst_k1 << "\n";
    // The reported sd is the true error's scatter, neither more nor less: if it is, the sum of
    // squared errors in sd over 20 trials is chi-square with 20 degrees of freedom, so the RMS
    // lies in [0.52, 1.50] with 99.9 % probability. The rotation is an angle (the norm of a 3D
    // error) over the sd of its worst axis: RMS between 1 and sqrt(3) times that.
    static const char* const kNames[14] = {"left fx", "left fy", "left cx", "left cy", "left k1", "left k2",
                                           "right fx", "right fy", "right cx", "right cy", "right k1", "right k2",
                                           "baseline", "rotation"};
    for (size_t i = 0; i < sum_z2.size(); ++i) {
      const double rms_z = std::sqrt(sum_z2[i] / kTrials);
      std::cout << "  " << kNames[i] << ": RMS error / reported sd " << rms_z << "\n";
      EXPECT_GE(rms_z, 0.5) << kNames[i] << ": reported sd too large for the true errors";
      EXPECT_LE(rms_z, i == 13 ? 1.5 * std::sqrt(3.0) : 1.5) << kNames[i] << ": reported sd too small";
    }
    EXPECT_GE(static_cast<double>(inside) / total, 0.95) << frames << " frame(s)";
    // k1 <= 0.005 holds at 10 frames; at 1 frame the sd is too close to it: not met.
    if (frames == 10) {
      EXPECT_LE(worst_k1, 0.005);
    }
  }
}

TEST(DeviceModel, IsMoreAccurateThanFreeBoardPosesOnTheSameObservations) {
  const SimScenario s;
  const auto frames = s.observe(10, 0.2, 5);
  const CalibrationDevice nominal = s.nominal(5);
  BundleAdjustmentOptions free_poses;
  free_poses.board_pose_mode = BoardPoseMode::kSharedAcrossFrames;
  const BundleAdjustmentSummary device = solve(frames, nominal, s.drifted());
  const BundleAdjustmentSummary free = solve(frames, nominal, s.drifted(), free_poses);
  ASSERT_TRUE(device.success && free.success);
  EXPECT_EQ(free.board_poses, "shared free poses");
  // The device model's fx and cx sd are several times smaller, its k1 sd about half
  // (bench_calibrator prints both).
  EXPECT_LT(device.left_stddev.fx, 0.5 * free.left_stddev.fx);
  EXPECT_LT(device.right_stddev.cx, 0.5 * free.right_stddev.cx);
  EXPECT_LT(device.left_stddev.dist[0], 0.7 * free.left_stddev.dist[0]);
  EXPECT_LT(device.baseline_stddev_m, free.baseline_stddev_m);
  // Fewer parameters: the fit is a little worse, never better.
  EXPECT_GE(device.rms_left_px, free.rms_left_px);
}

TEST(DeviceModel, ConsistentlyDisplacedCornersAreAbsorbedByTheRobustLoss) {
  // A tenth of the corners displaced by 5 px in every frame (mis-localised corners).
  const SimScenario s;
  auto frames = s.observe(10, 0.2, 9);
  std::mt19937_64 rng(99);
  std::bernoulli_distribution pick(0.1);
  std::vector<std::pair<size_t, size_t>> displaced;  // (list index, corner index) per side
  for (int side = 0; side < 2; ++side)
    for (size_t b = 0; b < frames[0].left.size(); ++b)
      for (size_t i = 0; i < frames[0].left[b].size(); ++i)
        if (pick(rng)) displaced.emplace_back(side * 100 + b, i);
  for (StereoObservation& f : frames)
    for (const auto& [key, i] : displaced) {
      auto& list = key >= 100 ? f.right : f.left;
      if (key % 100 >= list.size() || i >= list[key % 100].size()) continue;
      list[key % 100].u[i] += 5.0f;
    }
  const BundleAdjustmentSummary r = solve(frames, s.nominal(9), s.drifted());
  ASSERT_TRUE(r.success) << r.message;
  EXPECT_GT(r.outliers, 0);
  // Within 4 of the clean 10-frame sd (fx 0.083 %, cx 0.62 px, k1 0.0011; baseline 0.19 %).
  const RigErrors e = compareRigs(r.rig, s.truth);
  std::cout << displaced.size() << " corners displaced, " << r.outliers << " outliers; errors fx "
            << e.fx_rel[0] << " " << e.fx_rel[1] << " cx " << e.cx_px[0] << " " << e.cx_px[1]
            << " k1 " << e.k1[0] << " " << e.k1[1] << " baseline " << e.baseline_rel << "\n";
  for (int c = 0; c < 2; ++c) {
    EXPECT_LT(e.fx_rel[c], 0.0034) << c;
    EXPECT_LT(e.cx_px[c], 2.5) << c;
    EXPECT_LT(e.k1[c], 0.0045) << c;
  }
  EXPECT_LT(e.baseline_rel, 0.008);
}

TEST(DeviceModel, HeldPlanesFitOnlyWhenExact) {
  const SimScenario s;
  const auto frames = s.observe(1, 0.0, 6);
  BundleAdjustmentOptions held = withoutPrior();
  held.refine_mirror_planes = false;
  // Exact planes, device pose off by 1 mm / 0.5 deg: only the pose is estimated, exactly.
  CalibrationDevice exact_planes = s.nominal(6);
  exact_planes.copies = s.device.copies;
  const BundleAdjustmentSummary exact = solve(frames, exact_planes, std::nullopt, held);
  ASSERT_TRUE(exact.success) << exact.message;
  expectExact(exact, s.truth);
  // Planes 0.5 deg off and held: the copies are misplaced by ~1 deg, which no camera explains.
  const BundleAdjustmentSummary wrong = solve(frames, s.nominal(6), std::nullopt, held);
  ASSERT_TRUE(wrong.success) << wrong.message;
  EXPECT_GT(std::max(wrong.rms_left_px, wrong.rms_right_px), 0.5);
}

TEST(DeviceModel, MissingOrInvalidDeviceFailsWithAMessage) {
  const SimScenario s;
  const auto frames = s.observe(1, 0.2, 7);
  const std::vector<VirtualBoard> layout = s.device.virtualBoards();
  BundleAdjustmentOptions device_mode;
  device_mode.board_pose_mode = BoardPoseMode::kDeviceModel;
  CalibrationInput input;
  input.frames = &frames;
  input.boards = &layout;
  input.image_width = 752;
  input.image_height = 480;
  BundleAdjustmentSummary r = BundleAdjuster(device_mode, {}).Solve(input);
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.message.find("needs the device"), std::string::npos) << r.message;
  // kAuto without a device: free shared poses.
  r = BundleAdjuster({}, {}).Solve(input);
  ASSERT_TRUE(r.success) << r.message;
  EXPECT_EQ(r.board_poses, "shared free poses");
  CalibrationDevice broken = s.device;
  broken.copies.clear();
  input.device = &broken;
  r = BundleAdjuster({}, {}).Solve(input);
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.message.find("invalid device"), std::string::npos) << r.message;
  BundleAdjustmentOptions bad_prior;
  bad_prior.device_prior_angle_deg = 0.0;
  EXPECT_NE(solve(frames, s.device, std::nullopt, bad_prior).message.find("prior"),
            std::string::npos);
}

TEST(DeviceModel, QualityGateAcceptsItAgainstADriftedCalibrationAndKeepsTheTruth) {
  const SimScenario s;
  const auto frames = s.observe(10, 0.2, 8);
  const CalibrationDevice nominal = s.nominal(8);
  const std::vector<VirtualBoard> layout = nominal.virtualBoards();
  const QualityGate gate{GateOptions{}};
  const BundleAdjustmentSummary candidate = solve(frames, nominal, s.drifted());
  const BundleAdjustmentSummary drifted_fit =
      evaluateFixedCalibration(s.drifted(), frames, layout, {}, &nominal);
  ASSERT_TRUE(drifted_fit.success) << drifted_fit.message;
  EXPECT_EQ(drifted_fit.board_poses, "device model");
  EXPECT_DOUBLE_EQ(drifted_fit.rig.left.fx, s.drifted().left.fx);  // cameras held
  const GateDecision accepted = gate.evaluate(candidate, &drifted_fit);
  EXPECT_TRUE(accepted.accepted) << accepted.reason;
  const BundleAdjustmentSummary truth_fit =
      evaluateFixedCalibration(s.truth, frames, layout, {}, &nominal);
  const BundleAdjustmentSummary again = solve(frames, nominal, s.truth);
  const GateDecision kept = gate.evaluate(again, &truth_fit);
  EXPECT_FALSE(kept.accepted);
  EXPECT_NE(kept.reason.find("no significant improvement"), std::string::npos) << kept.reason;
}

// A nominal device whose boards are placed off the truth by the housing's tolerance (1 mm and
// 0.3 deg per axis, as scripts/perturb_device.py sets up a cold start). With the placements
// refined, noise-free corners give back the cameras and the virtual boards exactly; held, no
// camera explains the misplaced corners. The default (tested) refines them here, and holds
// them for a device known exactly, where refining them would only widen the uncertainty.
TEST(DeviceModel, BoardPlacementOffByItsToleranceIsRefined) {
  const SimScenario s;
  BundleAdjustmentOptions held = withoutPrior(), refined = withoutPrior();
  held.board_placement = BoardPlacement::kHeld;
  refined.board_placement = BoardPlacement::kRefined;
  for (uint64_t seed : {31, 32, 33}) {
    const CalibrationDevice nominal = perturbBoardPlacement(s.nominal(seed), 0.001, 0.3, seed);
    const auto frames = s.observe(10, 0.0, seed);
    const BundleAdjustmentSummary r = solve(frames, nominal, s.drifted(), refined);
    const BundleAdjustmentSummary h = solve(frames, nominal, s.drifted(), held);
    ASSERT_TRUE(r.success && h.success) << r.message << " / " << h.message;
    const RigErrors eh = compareRigs(h.rig, s.truth);
    std::cout << "seed " << seed << ": placements refined, rms " << r.rms_left_px << " "
              << r.rms_right_px << "; held, rms " << h.rms_left_px << " " << h.rms_right_px
              << ", fx error " << eh.fx_rel[0] << " " << eh.fx_rel[1] << ", baseline "
              << eh.baseline_rel << "\n";
    EXPECT_TRUE(r.board_placement_refined);
    EXPECT_FALSE(h.board_placement_refined);
    EXPECT_LT(std::max(r.rms_left_px, r.rms_right_px), 1e-3);
    EXPECT_GT(std::min(h.rms_left_px, h.rms_right_px), 0.1);
    expectExact(r, s.truth);
    ASSERT_TRUE(r.device.has_value());
    EXPECT_LT(virtualCornerError(r, s.device), 1e-6);
  }
  // With corner noise: the test refines the placements of the drawing off by the tolerance and
  // holds those of a device known exactly; refining costs a little precision.
  const auto noisy = s.observe(10, 0.05, 37);
  const CalibrationDevice off = perturbBoardPlacement(s.nominal(37), 0.001, 0.3, 37);
  const BundleAdjustmentSummary tested_off = solve(noisy, off, s.drifted());
  const BundleAdjustmentSummary tested_exact = solve(noisy, s.nominal(37), s.drifted());
  BundleAdjustmentOptions refined_default;
  refined_default.board_placement = BoardPlacement::kRefined;
  const BundleAdjustmentSummary refined_exact = solve(noisy, s.nominal(37), s.drifted(), refined_default);
  ASSERT_TRUE(tested_off.covariance_ok && tested_exact.covariance_ok && refined_exact.covariance_ok);
  std::cout << "0.05 px, tested: placements off by the tolerance: statistic "
            << tested_off.placement_test_statistic << " (limit " << tested_off.placement_test_limit
            << "), refined " << tested_off.board_placement_refined << "; exact: statistic "
            << tested_exact.placement_test_statistic << ", refined " << tested_exact.board_placement_refined
            << "; fx sd refined " << refined_exact.left_stddev.fx << " held " << tested_exact.left_stddev.fx
            << ", baseline sd refined " << refined_exact.baseline_stddev_m << " m, held "
            << tested_exact.baseline_stddev_m << " m\n";
  EXPECT_TRUE(tested_off.board_placement_refined);
  EXPECT_FALSE(tested_exact.board_placement_refined);
  EXPECT_LT(refined_exact.left_stddev.fx, 1.33 * tested_exact.left_stddev.fx);
  EXPECT_LT(refined_exact.baseline_stddev_m, 1.33 * tested_exact.baseline_stddev_m);
  EXPECT_GT(refined_exact.baseline_stddev_m, tested_exact.baseline_stddev_m);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
