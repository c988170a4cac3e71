// Quality gate on solves of simulated observations (rig like the sim's, six virtual 8x6
// boards of 25 mm, 0.2 px corner noise): a good solve against a drifted calibration is
// accepted; solves that are not trustworthy, or that do not improve on a calibration that
// still fits, are rejected with a reason. The gate's limits are its defaults, chosen so that
// 10 frames of this layout pass (see GateOptions).
#include <gtest/gtest.h>

#include <random>

#include "embedded_calibration_stereo/core/calibration/quality_gate.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace ecs {
namespace {

struct Scenario {
  StereoRig truth = makeSimLikeStereoRig();
  std::vector<VirtualBoard> boards = makeSpreadVirtualBoards(truth.left, {});

  std::vector<StereoObservation> observe(int frames, uint64_t seed,
                                         const std::vector<VirtualBoard>* only = nullptr) const {
    SyntheticObservationOptions o;
    o.frames = frames;
    o.noise_sigma_px = 0.2;
    o.seed = seed;
    return generateSyntheticObservations(truth, only ? *only : boards, o);
  }
  StereoRig drifted() const {  // 5 % zoom and a 0.3 deg knock
    return driftedRig(truth, 1.05, Eigen::Vector3d(0.0, 0.3, 0.0));
  }
  BundleAdjustmentSummary solve(const std::vector<StereoObservation>& frames,
                                const StereoRig& in_force) const {
    CalibrationInput input;
    input.frames = &frames;
    input.boards = &boards;
    input.in_force = in_force;
    return BundleAdjuster({}, {}).Solve(input);
  }
};

// Within the limits this layout supports with 10 frames (test_bundle_adjuster, bench).
bool withinGeometryLimits(const StereoRig& estimate, const StereoRig& truth) {
  const RigErrors e = compareRigs(estimate, truth);
  for (int c = 0; c < 2; ++c)
    if (e.fx_rel[c] > 0.015 || e.fy_rel[c] > 0.015 || e.cx_px[c] > 6 || e.cy_px[c] > 6 ||
        e.k1[c] > 0.012)
      return false;
  return e.baseline_rel < 0.015 && e.rotation_deg < 0.15;
}

TEST(QualityGate, GoodSolveReplacesADriftedCalibration) {
  const Scenario s;
  const auto frames = s.observe(10, 1);
  const BundleAdjustmentSummary candidate = s.solve(frames, s.drifted());
  const BundleAdjustmentSummary in_force = evaluateFixedCalibration(s.drifted(), frames, s.boards);
  const GateDecision d = QualityGate(GateOptions{}).evaluate(candidate, &in_force);
  EXPECT_TRUE(d.accepted) << d.reason;
  EXPECT_NE(d.reason.find("accepted"), std::string::npos);
  EXPECT_TRUE(withinGeometryLimits(candidate.rig, s.truth));
  // The first calibration has nothing to compare with.
  EXPECT_TRUE(QualityGate(GateOptions{}).evaluate(candidate, nullptr).accepted);
}

TEST(QualityGate, NoImprovementOverACalibrationThatStillFitsIsRejected) {
  const Scenario s;
  const auto frames = s.observe(10, 2);
  const BundleAdjustmentSummary candidate = s.solve(frames, s.truth);
  const BundleAdjustmentSummary in_force = evaluateFixedCalibration(s.truth, frames, s.boards);
  const GateDecision d = QualityGate(GateOptions{}).evaluate(candidate, &in_force);
  EXPECT_FALSE(d.accepted);
  EXPECT_NE(d.reason.find("no significant improvement"), std::string::npos) << d.reason;
  // Nothing to change: the calibration in force is confirmed.
  EXPECT_TRUE(d.in_force_confirmed);
  // A fresh solve that fits clearly worse than the calibration in force confirms nothing.
  BundleAdjustmentSummary worse = candidate;
  worse.rms_left_px = worse.rms_right_px = 1.2 * combinedRms(in_force);
  const GateDecision w = QualityGate(GateOptions{}).evaluate(worse, &in_force);
  EXPECT_FALSE(w.accepted);
  EXPECT_FALSE(w.in_force_confirmed) << w.reason;
}

TEST(QualityGate, SingleBoardSolveIsRejectedOrAccurate) {
  const Scenario s;
  const std::vector<VirtualBoard> one(s.boards.begin() + 1, s.boards.begin() + 2);
  const auto frames = s.observe(10, 3, &one);
  const BundleAdjustmentSummary candidate = s.solve(frames, s.drifted());
  const BundleAdjustmentSummary in_force = evaluateFixedCalibration(s.drifted(), frames, s.boards);
  const GateDecision d = QualityGate(GateOptions{}).evaluate(candidate, &in_force);
  EXPECT_TRUE(!d.accepted || withinGeometryLimits(candidate.rig, s.truth)) << d.reason;
  EXPECT_FALSE(d.accepted);  // what actually happens: too few boards
  EXPECT_NE(d.reason.find("boards seen: 1 left, 1 right"), std::string::npos) << d.reason;
}

// A tenth of the corners displaced by 5 px, either in every frame (a corner consistently
// mis-localised) or in one random frame each (a transient mis-detection).
std::vector<StereoObservation> displaceTenth(std::vector<StereoObservation> frames,
                                             bool same_in_every_frame, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> angle(0.0, 2 * M_PI);
  std::bernoulli_distribution pick(0.1);
  for (size_t f = 0; f < frames.size(); ++f) {
    std::mt19937_64 frame_rng(same_in_every_frame ? seed : rng());
    for (auto* list : {&frames[f].left, &frames[f].right})
      for (BoardCorners& b : *list)
        for (size_t i = 0; i < b.size(); ++i) {
          if (!pick(frame_rng)) continue;
          const double a = angle(frame_rng);
          b.u[i] += static_cast<float>(5.0 * std::cos(a));
          b.v[i] += static_cast<float>(5.0 * std::sin(a));
        }
  }
  return frames;
}

TEST(QualityGate, DisplacedCornersAreRejectedOrStillAccurate) {
  const Scenario s;
  for (bool same : {true, false}) {
    const auto frames = displaceTenth(s.observe(10, 4), same, 77);
    const BundleAdjustmentSummary candidate = s.solve(frames, s.drifted());
    const BundleAdjustmentSummary in_force =
        evaluateFixedCalibration(s.drifted(), frames, s.boards);
    ASSERT_TRUE(candidate.success) << candidate.message;
    const GateDecision d = QualityGate(GateOptions{}).evaluate(candidate, &in_force);
    EXPECT_TRUE(!d.accepted || withinGeometryLimits(candidate.rig, s.truth))
        << (same ? "same corners in every frame: " : "per frame: ") << d.reason;
    // The robust loss (consistent outliers) and the track median (transient ones) keep the
    // estimate accurate whatever the gate decides.
    EXPECT_TRUE(withinGeometryLimits(candidate.rig, s.truth)) << (same ? "same" : "per frame");
  }
}

TEST(QualityGate, EachCriterionRejectsWithItsReason) {
  const Scenario s;
  const auto frames = s.observe(10, 5);
  const BundleAdjustmentSummary good = s.solve(frames, s.drifted());
  const QualityGate gate{GateOptions{}};
  ASSERT_TRUE(gate.evaluate(good, nullptr).accepted);
  const auto reasonFor = [&](BundleAdjustmentSummary c, GateOptions o = {}) {
    const GateDecision d = QualityGate(o).evaluate(c, nullptr);
    EXPECT_FALSE(d.accepted);
    return d.reason;
  };
  BundleAdjustmentSummary c = good;
  c.converged = false;
  EXPECT_NE(reasonFor(c).find("did not converge"), std::string::npos);
  c = good;
  c.rms_right_px = 1.5;
  EXPECT_NE(reasonFor(c).find("RMS"), std::string::npos);
  c = good;
  c.epipolar_rms_px = 1.5;
  EXPECT_NE(reasonFor(c).find("epipolar"), std::string::npos);
  c = good;
  c.boards_right = 3;
  EXPECT_NE(reasonFor(c).find("boards seen"), std::string::npos);
  c = good;
  c.outliers = c.corners_used / 10;
  EXPECT_NE(reasonFor(c).find("outlier"), std::string::npos);
  c = good;
  c.covariance_ok = false;
  EXPECT_NE(reasonFor(c).find("covariance"), std::string::npos);
  c = good;
  c.right_stddev.fy = 0.02 * c.rig.right.fy;
  EXPECT_NE(reasonFor(c).find("right fy stddev"), std::string::npos);
  c = good;
  c.left_stddev.cy = 9.0;
  EXPECT_NE(reasonFor(c).find("principal point"), std::string::npos);
  c = good;
  c.left_stddev.dist[1] = 0.5;
  EXPECT_NE(reasonFor(c).find("k2 stddev"), std::string::npos);
  c = good;
  c.baseline_stddev_m = 0.01;
  EXPECT_NE(reasonFor(c).find("baseline"), std::string::npos);
  c = good;
  c.rotation_stddev_deg = 1.0;
  EXPECT_NE(reasonFor(c).find("rotation"), std::string::npos);
  c = good;
  c.success = false;
  c.message = "image size 640x480 differs";
  EXPECT_NE(reasonFor(c).find("640x480"), std::string::npos);
  GateOptions invalid;
  invalid.min_boards_per_camera = 0;
  EXPECT_NE(reasonFor(good, invalid).find("invalid gate options"), std::string::npos);
}

TEST(QualityGate, OneFrameOfThisLayoutIsTooUncertainForTheDefaultLimits) {
  // One frame: fx is known to ~1.4 % only (Cramer-Rao bound of this geometry at 0.2 px).
  const Scenario s;
  const BundleAdjustmentSummary candidate = s.solve(s.observe(1, 6), s.drifted());
  ASSERT_TRUE(candidate.success);
  const GateDecision d = QualityGate(GateOptions{}).evaluate(candidate, nullptr);
  EXPECT_FALSE(d.accepted);
  EXPECT_NE(d.reason.find("stddev"), std::string::npos) << d.reason;
}

}  // namespace
}  // namespace ecs
