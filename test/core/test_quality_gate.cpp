// Quality gate on solves of simulated observations (rig like the sim's, six virtual 8x6
// boards of 25 mm, 0.2 px corner noise): a good solve against a drifted calibration is
// accepted; solves that are not trustworthy, or that do not improve on a calibration that
// still fits, are rejected with a reason. The gate's limits are its defaults, chosen so that
// 10 frames of this layout pass (see GateOptions).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <opencv2/calib3d.hpp>
#include <Eigen/Core>  // before opencv2/core/eigen.hpp
#include <opencv2/core/eigen.hpp>
#include <random>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/quality_gate.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace embedded_calibration_stereo::core {
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

// A candidate that only confirms the calibration in force replaces it when it is clearly better
// known (refine_ratio): its predicted error against the one the calibration in force was
// committed with, at the ratio's edge on both sides.
TEST(QualityGate, AConfirmingSolveClearlyBetterKnownRefinesTheCalibrationInForce) {
  const Scenario s;
  const auto frames = s.observe(10, 2);
  const BundleAdjustmentSummary candidate = s.solve(frames, s.truth);
  const BundleAdjustmentSummary in_force = evaluateFixedCalibration(s.truth, frames, s.boards);
  const double p = QualityGate::predictedPx(candidate);
  ASSERT_GT(p, 0.0);
  GateOptions o;
  o.refine_ratio = 0.85;
  const QualityGate gate(o);
  const GateDecision refined = gate.evaluate(candidate, &in_force, p / 0.84);
  EXPECT_TRUE(refined.accepted) << refined.reason;
  EXPECT_TRUE(refined.refinement);
  EXPECT_FALSE(refined.in_force_confirmed);
  EXPECT_NEAR(refined.predicted_px, p, 1e-12);
  EXPECT_NE(refined.reason.find("refinement"), std::string::npos) << refined.reason;
  // Not clearly better known, no prediction of the calibration in force, or refinement off:
  // the calibration in force stands, confirmed.
  for (const GateDecision& d : {gate.evaluate(candidate, &in_force, p / 0.86), gate.evaluate(candidate, &in_force),
                                QualityGate(GateOptions{}).evaluate(candidate, &in_force, p / 0.5)}) {
    EXPECT_FALSE(d.accepted) << d.reason;
    EXPECT_TRUE(d.in_force_confirmed) << d.reason;
    EXPECT_FALSE(d.refinement);
  }
  // A candidate that fits clearly worse confirms nothing and refines nothing.
  BundleAdjustmentSummary worse = candidate;
  worse.rms_left_px = worse.rms_right_px = 1.2 * combinedRms(in_force);
  EXPECT_FALSE(gate.evaluate(worse, &in_force, p / 0.5).accepted);
  o.refine_ratio = 1.0;
  EXPECT_NE(o.validate().find("refine_ratio"), std::string::npos);
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
  // One frame: the Cramer-Rao bound of this geometry at 0.2 px on fx is above the default limit.
  const Scenario s;
  const BundleAdjustmentSummary candidate = s.solve(s.observe(1, 6), s.drifted());
  ASSERT_TRUE(candidate.success);
  const GateDecision d = QualityGate(GateOptions{}).evaluate(candidate, nullptr);
  EXPECT_FALSE(d.accepted);
  EXPECT_NE(d.reason.find("stddev"), std::string::npos) << d.reason;
}


// ---- Every branch of QualityGate::evaluate on summaries built directly ----------------------
// The gate is a pure function of the two summaries, so its rules and the edge of every limit
// are checked on hand-made values; the solves above and below show the same rules on real ones.

// A candidate that passes every check of the default options with room to spare.
BundleAdjustmentSummary passingCandidate() {
  BundleAdjustmentSummary c;
  c.success = c.converged = c.covariance_ok = true;
  c.message = "converged";
  c.rig = makeSimLikeStereoRig();
  c.corners_left = c.corners_right = 288;
  c.corners_used = 576;
  c.boards_left = c.boards_right = 6;
  c.rms_left_px = c.rms_right_px = 0.5;
  c.epipolar_rms_px = 0.5;
  for (CameraStddev* sd : {&c.left_stddev, &c.right_stddev}) {
    sd->fx = sd->fy = 1.0;  // ~0.15 % of fx
    sd->cx = sd->cy = 1.0;
    sd->dist = {{0.002, 0.002, 0.002, 0.002, 0.002}};
  }
  c.baseline_stddev_m = 0.0002;
  c.rotation_stddev_deg = 0.02;
  return c;
}

// evaluateFixedCalibration() of a calibration in force with the same RMS in both cameras.
BundleAdjustmentSummary inForceFit(double rms_px) {
  BundleAdjustmentSummary f = passingCandidate();
  f.rms_left_px = f.rms_right_px = rms_px;
  return f;
}

bool contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

TEST(QualityGateRules, ABetterFitReplacesACalibrationThatStillFits) {
  const BundleAdjustmentSummary candidate = passingCandidate();  // RMS 0.5 px
  // The calibration in force fits (0.8 px <= in_force_max_rms_px 1 px) but clearly worse.
  const BundleAdjustmentSummary in_force = inForceFit(0.8);
  const GateDecision d = QualityGate(GateOptions{}).evaluate(candidate, &in_force);
  EXPECT_TRUE(d.accepted) << d.reason;
  EXPECT_TRUE(contains(d.reason, "accepted: RMS 0.5 px vs 0.8 px")) << d.reason;
}

// min_change_in_predicted: a candidate that fits clearly better (the RMS rule accepts it) is kept
// out when it differs from the calibration in force by less than that many times its own
// predicted error for depth, and let in when the change is larger (a knock).
TEST(QualityGateRules, AChangeWithinTheCandidatesUncertaintyIsRejectedWhenAsked) {
  const StereoRig in_force_rig = makeSimLikeStereoRig();
  BundleAdjustmentSummary in_force = inForceFit(0.8);  // the RMS rule alone accepts 0.5 px
  in_force.rig = in_force_rig;
  BundleAdjustmentSummary candidate = passingCandidate();
  // The reported covariance (diagonal, the passing candidate's sd): rotation 0.02 deg, cx 1 px...
  RigParameters sd = RigParameters::Zero();
  for (int c = 0; c < 2; ++c) {
    for (int k = 0; k < 4; ++k) sd[9 * c + k] = 1.0;
    sd[9 * c + 4] = sd[9 * c + 5] = 0.002;
  }
  for (int k = 18; k < 21; ++k) sd[k] = 0.02 * M_PI / 180.0;
  for (int k = 21; k < 24; ++k) sd[k] = 0.0002;
  candidate.rig_covariance = sd.cwiseProduct(sd).asDiagonal();
  GateOptions o;
  o.min_change_in_predicted = 3.0;
  for (const double pan_deg : {0.01, 2.0}) {  // within the uncertainty / a hard knock
    candidate.rig = driftedRig(in_force_rig, 1.0, Eigen::Vector3d(0.0, pan_deg, 0.0));
    const GateDecision d = QualityGate(o).evaluate(candidate, &in_force);
    EXPECT_EQ(d.accepted, pan_deg > 1.0) << pan_deg << ": " << d.reason;
    if (d.accepted) {
      EXPECT_TRUE(contains(d.reason, "for the calibration in force; change for depth")) << d.reason;
    } else {
      EXPECT_TRUE(contains(d.reason, "within the new solve's uncertainty")) << d.reason;
      EXPECT_TRUE(d.in_force_confirmed) << d.reason;
      EXPECT_TRUE(d.change_too_small) << d.reason;
      EXPECT_EQ("rejected: " + d.detail, d.reason);
    }
    EXPECT_EQ(d.change_too_small, !d.accepted) << "only the change's size decides here";
    // Not asked (the default): the RMS rule decides.
    EXPECT_TRUE(QualityGate(GateOptions{}).evaluate(candidate, &in_force).accepted);
  }
  o.min_change_in_predicted = -1.0;
  EXPECT_TRUE(contains(QualityGate(o).evaluate(candidate, &in_force).reason, "min_change_in_predicted must be >= 0"));
}

TEST(QualityGateRules, NoSignificantImprovementIsRejected) {
  const BundleAdjustmentSummary candidate = passingCandidate();
  for (double in_force_rms : {0.4, 0.5, 0.51}) {  // worse, equal, 2 % better than in force
    const BundleAdjustmentSummary in_force = inForceFit(in_force_rms);
    const GateDecision d = QualityGate(GateOptions{}).evaluate(candidate, &in_force);
    EXPECT_FALSE(d.accepted) << in_force_rms << ": " << d.reason;
    EXPECT_TRUE(contains(d.reason, "no significant improvement")) << d.reason;
    EXPECT_TRUE(contains(d.reason, "needs 5% lower")) << d.reason;
  }
}

// scene_test_probability: the scene's matches decide only where the corners do not (a candidate
// that fits them no better and not clearly worse), and only when asked. test_scene_comparison
// shows the same on solved windows.
TEST(QualityGateRules, TheSceneDecidesOnlyWhereTheCornersCannot) {
  BundleAdjustmentSummary candidate = passingCandidate();  // corner RMS 0.5 px
  candidate.scene_vs_in_force.matches = 240;
  candidate.scene_vs_in_force.candidate_rms_px = 0.06;
  candidate.scene_vs_in_force.in_force_rms_px = 0.10;
  GateOptions asked;
  asked.scene_test_probability = 0.001;  // chi-square limit 20.5 with 5 degrees of freedom
  for (const double statistic : {20.0, 21.0, 300.0}) {
    candidate.scene_vs_in_force.statistic = statistic;
    const BundleAdjustmentSummary same = inForceFit(0.5);
    const GateDecision d = QualityGate(asked).evaluate(candidate, &same);
    EXPECT_EQ(d.accepted, statistic > 20.6) << statistic << ": " << d.reason;
    if (d.accepted) {
      EXPECT_TRUE(contains(d.reason, "accepted: the scene fits it better: 240 scene matches at RMS 0.06 px vs 0.1 px"))
          << d.reason;
    } else {
      EXPECT_TRUE(d.in_force_confirmed) << d.reason;
    }
    // Not asked (the default): the corners alone, which do not tell the two apart.
    EXPECT_FALSE(QualityGate(GateOptions{}).evaluate(candidate, &same).accepted);
    // A candidate clearly worse on the corners confirms nothing, whatever the scene says.
    const BundleAdjustmentSummary better_in_force = inForceFit(0.4);
    EXPECT_FALSE(QualityGate(asked).evaluate(candidate, &better_in_force).accepted);
  }
  // Without scene matches there is nothing to consult.
  candidate.scene_vs_in_force = SceneComparison{};
  const BundleAdjustmentSummary same = inForceFit(0.5);
  EXPECT_FALSE(QualityGate(asked).evaluate(candidate, &same).accepted);
}

TEST(QualityGateRules, ImprovementIsAcceptedFromExactlyTheRequiredFraction) {
  GateOptions o;
  o.min_rms_improvement_rel = 0.25;  // 0.5 px * 1.25 = 0.625 px, exact in binary
  const BundleAdjustmentSummary candidate = passingCandidate();
  ASSERT_EQ(combinedRms(candidate), 0.5);
  BundleAdjustmentSummary in_force = inForceFit(0.625);
  ASSERT_EQ(combinedRms(in_force), 0.625);
  GateDecision d = QualityGate(o).evaluate(candidate, &in_force);
  EXPECT_TRUE(d.accepted) << "equality is enough: " << d.reason;
  in_force = inForceFit(0.624);
  d = QualityGate(o).evaluate(candidate, &in_force);
  EXPECT_FALSE(d.accepted) << d.reason;
  EXPECT_TRUE(contains(d.reason, "no significant improvement")) << d.reason;
  // Without a required improvement, an equal fit is enough (<=), a worse one is not.
  o.min_rms_improvement_rel = 0.0;
  in_force = inForceFit(0.5);
  EXPECT_TRUE(QualityGate(o).evaluate(candidate, &in_force).accepted);
  in_force = inForceFit(0.49);
  EXPECT_FALSE(QualityGate(o).evaluate(candidate, &in_force).accepted);
}

// The improvement is judged on the RMS over both cameras weighted by their corner counts.
TEST(QualityGateRules, ImprovementIsJudgedOnTheCornerWeightedRmsOfBothCameras) {
  BundleAdjustmentSummary candidate = passingCandidate();
  candidate.rms_left_px = 0.3;
  candidate.rms_right_px = 0.9;
  candidate.corners_left = 300;
  candidate.corners_right = 100;
  const double expected = std::sqrt((0.09 * 300 + 0.81 * 100) / 400.0);
  EXPECT_NEAR(combinedRms(candidate), expected, 1e-12);
  BundleAdjustmentSummary in_force = inForceFit(0.0);
  in_force.rms_left_px = 0.6;  // the left camera alone would look like a clear improvement
  in_force.rms_right_px = 0.6;
  in_force.corners_left = 300;
  in_force.corners_right = 100;
  // expected ~0.52 px, 1.05 * 0.52 = 0.546 <= 0.6: accepted; with in force at 0.54 px not.
  EXPECT_TRUE(QualityGate(GateOptions{}).evaluate(candidate, &in_force).accepted);
  in_force.rms_left_px = in_force.rms_right_px = 0.54;
  EXPECT_FALSE(QualityGate(GateOptions{}).evaluate(candidate, &in_force).accepted);
  BundleAdjustmentSummary empty = passingCandidate();
  empty.corners_left = empty.corners_right = 0;
  EXPECT_EQ(combinedRms(empty), 0.0);
}

TEST(QualityGateRules, ACalibrationInForceThatNoLongerFitsIsReplacedWithoutImprovementRule) {
  GateOptions o;
  o.in_force_max_rms_px = 0.5;
  BundleAdjustmentSummary candidate = passingCandidate();
  candidate.rms_left_px = candidate.rms_right_px = 0.5;
  // In force at 0.51 px: only 2 % worse than the candidate, but over in_force_max_rms_px.
  BundleAdjustmentSummary in_force = inForceFit(0.51);
  GateDecision d = QualityGate(o).evaluate(candidate, &in_force);
  EXPECT_TRUE(d.accepted) << d.reason;
  EXPECT_TRUE(contains(d.reason, "no longer fits (RMS 0.51 px > 0.5 px)")) << d.reason;
  // At the limit it still fits: the improvement rule decides (and 0 % is not enough).
  in_force = inForceFit(0.5);
  d = QualityGate(o).evaluate(candidate, &in_force);
  EXPECT_FALSE(d.accepted) << d.reason;
  EXPECT_TRUE(contains(d.reason, "no significant improvement")) << d.reason;
}

TEST(QualityGateRules, ACalibrationInForceThatCannotBeEvaluatedIsReplaced) {
  BundleAdjustmentSummary in_force = inForceFit(0.1);  // its RMS would say it fits well
  in_force.success = false;
  in_force.message = "image size 640x480 differs from the observations";
  const GateDecision d = QualityGate(GateOptions{}).evaluate(passingCandidate(), &in_force);
  EXPECT_TRUE(d.accepted) << d.reason;
  EXPECT_TRUE(contains(d.reason, "cannot explain the observations (image size 640x480")) << d.reason;
  // ... but only by a candidate that passes its own checks.
  BundleAdjustmentSummary bad = passingCandidate();
  bad.rms_left_px = 2.0;
  EXPECT_FALSE(QualityGate(GateOptions{}).evaluate(bad, &in_force).accepted);
}

TEST(QualityGateRules, TheFirstCalibrationNeedsOnlyItsOwnChecks) {
  const GateDecision d = QualityGate(GateOptions{}).evaluate(passingCandidate(), nullptr);
  EXPECT_TRUE(d.accepted) << d.reason;
  EXPECT_TRUE(contains(d.reason, "accepted: first calibration, RMS 0.5 px")) << d.reason;
  BundleAdjustmentSummary bad = passingCandidate();
  bad.converged = false;
  EXPECT_FALSE(QualityGate(GateOptions{}).evaluate(bad, nullptr).accepted);
}

// Each limit: a value exactly at it is accepted, one just beyond it is rejected with its
// reason. `set(c, beyond)` puts the candidate at the limit (false) or just beyond it (true).
struct Edge {
  std::string name, reason;
  std::function<void(BundleAdjustmentSummary*, bool beyond)> set;
};

TEST(QualityGateRules, EveryLimitAcceptsItsEdgeAndRejectsJustBeyond) {
  const GateOptions o;
  const double kBeyond = 1.0 + 1e-6;
  const auto focal = [&](CameraStddev BundleAdjustmentSummary::*sd, double PinholeCamera::*f,
                         PinholeCamera StereoRig::*cam, double CameraStddev::*field) {
    return [=](BundleAdjustmentSummary* c, bool beyond) {
      (c->*sd).*field = o.max_focal_stddev_rel * (c->rig.*cam).*f * (beyond ? kBeyond : 1.0);
    };
  };
  std::vector<Edge> edges = {
      {"max_rms_px left", "RMS 1 / 0.5 px > 1 px",
       [&](BundleAdjustmentSummary* c, bool b) { c->rms_left_px = o.max_rms_px * (b ? kBeyond : 1.0); }},
      {"max_rms_px right", "RMS 0.5 / 1 px > 1 px",
       [&](BundleAdjustmentSummary* c, bool b) { c->rms_right_px = o.max_rms_px * (b ? kBeyond : 1.0); }},
      {"max_epipolar_rms_px", "epipolar RMS",
       [&](BundleAdjustmentSummary* c, bool b) {
         c->epipolar_rms_px = o.max_epipolar_rms_px * (b ? kBeyond : 1.0);
       }},
      // 0.02 * 500 = 10 outliers allowed, 11 not.
      {"max_outlier_fraction", "11 outlier corners of 500 (max fraction 0.02)",
       [&](BundleAdjustmentSummary* c, bool b) {
         c->corners_used = 500;
         c->outliers = b ? 11 : 10;
       }},
      {"min_boards_per_camera left", "boards seen: 3 left, 6 right; at least 4",
       [&](BundleAdjustmentSummary* c, bool b) { c->boards_left = o.min_boards_per_camera - b; }},
      {"min_boards_per_camera right", "boards seen: 6 left, 3 right",
       [&](BundleAdjustmentSummary* c, bool b) { c->boards_right = o.min_boards_per_camera - b; }},
      {"left fx", "left fx stddev",
       focal(&BundleAdjustmentSummary::left_stddev, &PinholeCamera::fx, &StereoRig::left, &CameraStddev::fx)},
      {"left fy", "left fy stddev",
       focal(&BundleAdjustmentSummary::left_stddev, &PinholeCamera::fy, &StereoRig::left, &CameraStddev::fy)},
      {"right fx", "right fx stddev",
       focal(&BundleAdjustmentSummary::right_stddev, &PinholeCamera::fx, &StereoRig::right, &CameraStddev::fx)},
      {"right fy", "right fy stddev",
       focal(&BundleAdjustmentSummary::right_stddev, &PinholeCamera::fy, &StereoRig::right, &CameraStddev::fy)},
      {"baseline", "baseline stddev",
       [&](BundleAdjustmentSummary* c, bool b) {
         c->baseline_stddev_m = o.max_baseline_stddev_rel * c->rig.baseline() * (b ? kBeyond : 1.0);
       }},
      {"rotation", "rotation stddev",
       [&](BundleAdjustmentSummary* c, bool b) {
         c->rotation_stddev_deg = o.max_rotation_stddev_deg * (b ? kBeyond : 1.0);
       }},
  };
  for (const char* side : {"left", "right"}) {
    const bool left = std::string(side) == "left";
    for (const char* axis : {"cx", "cy"})
      edges.push_back({std::string(side) + " " + axis, std::string(side) + " principal point stddev",
                       [=](BundleAdjustmentSummary* c, bool b) {
                         CameraStddev& sd = left ? c->left_stddev : c->right_stddev;
                         (std::string(axis) == "cx" ? sd.cx : sd.cy) =
                             o.max_principal_point_stddev_px * (b ? kBeyond : 1.0);
                       }});
    static const char* const kTerms[5] = {"k1", "k2", "p1", "p2", "k3"};
    for (int i = 0; i < 5; ++i)
      edges.push_back({std::string(side) + " " + kTerms[i], std::string(side) + " " + kTerms[i] + " stddev",
                       [=](BundleAdjustmentSummary* c, bool b) {
                         (left ? c->left_stddev : c->right_stddev).dist[i] =
                             o.max_distortion_stddev * (b ? kBeyond : 1.0);
                       }});
  }
  const QualityGate gate(o);
  for (const Edge& e : edges) {
    BundleAdjustmentSummary c = passingCandidate();
    e.set(&c, false);
    GateDecision d = gate.evaluate(c, nullptr);
    EXPECT_TRUE(d.accepted) << e.name << " at the limit: " << d.reason;
    c = passingCandidate();
    e.set(&c, true);
    d = gate.evaluate(c, nullptr);
    EXPECT_FALSE(d.accepted) << e.name << " just beyond the limit";
    EXPECT_EQ(d.reason.rfind("rejected: ", 0), 0u) << e.name << ": " << d.reason;
    EXPECT_TRUE(contains(d.reason, e.reason)) << e.name << ": " << d.reason;
    // A candidate over a limit is rejected whatever the calibration in force.
    const BundleAdjustmentSummary in_force = inForceFit(5.0);
    EXPECT_FALSE(gate.evaluate(c, &in_force).accepted) << e.name;
  }
  // Not-a-number is beyond every limit.
  BundleAdjustmentSummary c = passingCandidate();
  c.rms_left_px = std::nan("");
  EXPECT_FALSE(gate.evaluate(c, nullptr).accepted);
  c = passingCandidate();
  c.left_stddev.fx = std::nan("");
  EXPECT_FALSE(gate.evaluate(c, nullptr).accepted);
  // No corners at all: no outlier fraction can be computed.
  c = passingCandidate();
  c.corners_used = 0;
  EXPECT_TRUE(contains(gate.evaluate(c, nullptr).reason, "outlier corners of 0")) << gate.evaluate(c, nullptr).reason;
}

TEST(QualityGateRules, UnsolvedUnconvergedOrUndeterminedCandidatesAreRejected) {
  const QualityGate gate{GateOptions{}};
  const BundleAdjustmentSummary in_force = inForceFit(5.0);  // would accept any valid candidate
  BundleAdjustmentSummary c = passingCandidate();
  c.success = false;
  c.message = "no corners";
  EXPECT_TRUE(contains(gate.evaluate(c, &in_force).reason, "rejected: no solution (no corners)"));
  c = passingCandidate();
  c.converged = false;
  c.message = "no convergence";
  EXPECT_TRUE(contains(gate.evaluate(c, &in_force).reason, "did not converge (no convergence)"));
  c = passingCandidate();
  c.covariance_ok = false;
  EXPECT_TRUE(contains(gate.evaluate(c, &in_force).reason, "covariance unavailable"));
  EXPECT_TRUE(gate.evaluate(passingCandidate(), &in_force).accepted);
}

TEST(QualityGateRules, InvalidOptionsRejectEveryCandidateWithTheProblem) {
  const auto with = [](const std::function<void(GateOptions*)>& change) {
    GateOptions o;
    change(&o);
    return o;
  };
  const double nan = std::nan("");
  const std::vector<std::pair<GateOptions, std::string>> invalid = {
      {with([](GateOptions* o) { o->max_rms_px = 0; }), "RMS limits must be > 0"},
      {with([&](GateOptions* o) { o->max_rms_px = nan; }), "RMS limits must be > 0"},
      {with([](GateOptions* o) { o->max_epipolar_rms_px = -1; }), "RMS limits must be > 0"},
      {with([](GateOptions* o) { o->max_outlier_fraction = -0.01; }), "max_outlier_fraction"},
      {with([](GateOptions* o) { o->max_outlier_fraction = 1.01; }), "max_outlier_fraction"},
      {with([](GateOptions* o) { o->min_boards_per_camera = 0; }), "min_boards_per_camera"},
      {with([](GateOptions* o) { o->max_focal_stddev_rel = 0; }), "standard deviation limits"},
      {with([](GateOptions* o) { o->max_principal_point_stddev_px = 0; }), "standard deviation limits"},
      {with([](GateOptions* o) { o->max_distortion_stddev = 0; }), "standard deviation limits"},
      {with([](GateOptions* o) { o->max_baseline_stddev_rel = 0; }), "standard deviation limits"},
      {with([](GateOptions* o) { o->max_rotation_stddev_deg = 0; }), "standard deviation limits"},
      {with([](GateOptions* o) { o->min_rms_improvement_rel = -0.01; }), "min_rms_improvement_rel"},
      {with([&](GateOptions* o) { o->min_rms_improvement_rel = nan; }), "min_rms_improvement_rel"},
      {with([](GateOptions* o) { o->in_force_max_rms_px = 0; }), "in_force_max_rms_px"},
      {with([](GateOptions* o) { o->scene_test_probability = -0.01; }), "scene_test_probability"},
      {with([](GateOptions* o) { o->scene_test_probability = 1.0; }), "scene_test_probability"},
      {with([&](GateOptions* o) { o->scene_test_probability = nan; }), "scene_test_probability"},
  };
  const BundleAdjustmentSummary in_force = inForceFit(5.0);
  for (const auto& [options, problem] : invalid) {
    EXPECT_TRUE(contains(options.validate(), problem)) << problem << ": " << options.validate();
    for (const BundleAdjustmentSummary* fit : {static_cast<const BundleAdjustmentSummary*>(nullptr), &in_force}) {
      const GateDecision d = QualityGate(options).evaluate(passingCandidate(), fit);
      EXPECT_FALSE(d.accepted) << problem;
      EXPECT_TRUE(contains(d.reason, "rejected: invalid gate options: " + problem)) << d.reason;
    }
  }
  // The edges of the valid ranges are usable.
  for (const GateOptions& valid : {with([](GateOptions* o) { o->max_outlier_fraction = 0; }),
                                   with([](GateOptions* o) { o->max_outlier_fraction = 1; }),
                                   with([](GateOptions* o) { o->min_boards_per_camera = 1; }),
                                   with([](GateOptions* o) { o->min_rms_improvement_rel = 0; })}) {
    EXPECT_EQ(valid.validate(), "");
    EXPECT_TRUE(QualityGate(valid).evaluate(passingCandidate(), nullptr).accepted);
  }
}

// Epipolar error (px, RMS) of true correspondences under a rig: points 1.2-3 m in front of the
// left camera, projected into both cameras by the truth with cv::projectPoints, undistorted
// with the rig's own K and D and measured against the rig's epipolar lines (F = K_r^-T [t]x R
// K_l^-1). A ground-truth measure of how well a calibration explains the scene that does not
// depend on how its parameters trade against each other (a right-camera tilt against cy).
double trueEpipolarRmsPx(const StereoRig& rig, const StereoRig& truth) {
  const auto K = [](const PinholeCamera& c) { return cv::Matx33d(c.fx, c.skew, c.cx, 0, c.fy, c.cy, 0, 0, 1); };
  const auto D = [](const PinholeCamera& c) { return cv::Mat(cv::Matx<double, 1, 5>(c.dist.data()), true); };
  std::vector<cv::Point3d> in_left;
  for (double z : {1.2, 3.0})
    for (double x = -0.4; x <= 0.4; x += 0.1)
      for (double y = -0.25; y <= 0.25; y += 0.05) in_left.emplace_back(x * z, y * z, z);
  cv::Mat r_truth;
  cv::eigen2cv(Eigen::Matrix3d(truth.right_from_left.linear()), r_truth);
  cv::Rodrigues(r_truth.clone(), r_truth);
  const Eigen::Vector3d t_truth = truth.right_from_left.translation();
  std::vector<cv::Point2d> left_px, right_px;
  cv::projectPoints(in_left, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K(truth.left), D(truth.left), left_px);
  cv::projectPoints(in_left, r_truth, cv::Vec3d(t_truth.x(), t_truth.y(), t_truth.z()), K(truth.right),
                    D(truth.right), right_px);
  std::vector<cv::Point2d> left_ideal, right_ideal;
  cv::undistortPoints(left_px, left_ideal, K(rig.left), D(rig.left), cv::noArray(), K(rig.left),
                      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
  cv::undistortPoints(right_px, right_ideal, K(rig.right), D(rig.right), cv::noArray(), K(rig.right),
                      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
  const Eigen::Vector3d t = rig.right_from_left.translation();
  Eigen::Matrix3d tx;
  tx << 0, -t.z(), t.y(), t.z(), 0, -t.x(), -t.y(), t.x(), 0;
  Eigen::Matrix3d Kl, Kr;
  cv::cv2eigen(cv::Mat(K(rig.left)), Kl);
  cv::cv2eigen(cv::Mat(K(rig.right)), Kr);
  const Eigen::Matrix3d F = Kr.inverse().transpose() * tx * rig.right_from_left.linear() * Kl.inverse();
  double sum = 0;
  int n = 0;
  for (size_t i = 0; i < in_left.size(); ++i) {
    if (!truth.left.inImage(Eigen::Vector2d(left_px[i].x, left_px[i].y)) ||
        !truth.right.inImage(Eigen::Vector2d(right_px[i].x, right_px[i].y)))
      continue;
    const Eigen::Vector3d line = F * Eigen::Vector3d(left_ideal[i].x, left_ideal[i].y, 1.0);
    const double d = line.dot(Eigen::Vector3d(right_ideal[i].x, right_ideal[i].y, 1.0)) / line.head<2>().norm();
    sum += d * d;
    ++n;
  }
  EXPECT_GT(n, 100);
  return std::sqrt(sum / n);
}

// End to end, no knock: the calibration in force is a little off (right camera tilted by
// 0.05 deg) and still fits the fresh observations (0.2 px noise) under in_force_max_rms_px;
// only the better-fit rule can accept the new solve, and the new solve explains true
// correspondences better than the calibration in force.
TEST(QualityGate, ASolveThatFitsClearlyBetterReplacesACalibrationThatStillFits) {
  const Scenario s;
  const StereoRig slightly_off = driftedRig(s.truth, 1.0, Eigen::Vector3d(0.05, 0.0, 0.0));
  const auto frames = s.observe(10, 8);
  const BundleAdjustmentSummary candidate = s.solve(frames, slightly_off);
  const BundleAdjustmentSummary in_force = evaluateFixedCalibration(slightly_off, frames, s.boards);
  ASSERT_TRUE(candidate.success && in_force.success) << candidate.message << in_force.message;
  const GateOptions o;
  const double epipolar_in_force = trueEpipolarRmsPx(slightly_off, s.truth);
  const double epipolar_candidate = trueEpipolarRmsPx(candidate.rig, s.truth);
  std::printf("[ figures  ] right camera tilted 0.05 deg: in force RMS %.3f px, new solve %.3f px; "
              "epipolar error of true correspondences %.3f px vs %.3f px\n",
              combinedRms(in_force), combinedRms(candidate), epipolar_in_force, epipolar_candidate);
  // The calibration in force still fits: the "no longer fits" rule does not decide.
  ASSERT_LE(combinedRms(in_force), o.in_force_max_rms_px);
  const GateDecision d = QualityGate(o).evaluate(candidate, &in_force);
  EXPECT_TRUE(d.accepted) << d.reason;
  EXPECT_TRUE(contains(d.reason, "accepted: RMS")) << d.reason;
  EXPECT_TRUE(withinGeometryLimits(candidate.rig, s.truth));
  EXPECT_LT(epipolar_candidate, 0.5 * epipolar_in_force);
  // The same observations against the truth itself: nothing to improve, rejected.
  const BundleAdjustmentSummary truth_fit = evaluateFixedCalibration(s.truth, frames, s.boards);
  EXPECT_FALSE(QualityGate(o).evaluate(s.solve(frames, s.truth), &truth_fit).accepted);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core

// The gate's decision as a value: each way out of evaluate() names its outcome, and the flags
// agree with it.
namespace embedded_calibration_stereo::core {
namespace {

TEST(QualityGateRules, EachDecisionNamesItsOutcome) {
  BundleAdjustmentSummary candidate = passingCandidate();  // RMS 0.5 px
  RigParameters sd = RigParameters::Constant(1e-3);  // a covariance: a predicted error for depth
  candidate.rig_covariance = sd.cwiseProduct(sd).asDiagonal();
  const QualityGate gate{GateOptions{}};
  const auto outcome = [](const GateDecision& d) {
    EXPECT_EQ(d.accepted, d.outcome == GateOutcome::kAccepted || d.outcome == GateOutcome::kRefinement) << d.reason;
    EXPECT_EQ(d.in_force_confirmed,
              d.outcome == GateOutcome::kInForceConfirmed || d.outcome == GateOutcome::kChangeTooSmall)
        << d.reason;
    return d.outcome;
  };
  EXPECT_EQ(outcome(gate.evaluate(candidate, nullptr)), GateOutcome::kAccepted);  // the first calibration
  const BundleAdjustmentSummary drifted = inForceFit(0.8), same = inForceFit(0.5), better = inForceFit(0.4);
  EXPECT_EQ(outcome(gate.evaluate(candidate, &drifted)), GateOutcome::kAccepted);
  EXPECT_EQ(outcome(gate.evaluate(candidate, &same)), GateOutcome::kInForceConfirmed);
  EXPECT_EQ(outcome(gate.evaluate(candidate, &better)), GateOutcome::kRejected);  // clearly worse: confirms nothing
  BundleAdjustmentSummary unsolved = candidate;
  unsolved.success = false;
  EXPECT_EQ(outcome(gate.evaluate(unsolved, &same)), GateOutcome::kRejected);
  // Confirming, but clearly better known than the calibration in force: a refinement.
  GateOptions refine;
  refine.refine_ratio = 0.85;
  const double p = QualityGate::predictedPx(candidate);
  ASSERT_GT(p, 0.0);
  EXPECT_EQ(outcome(QualityGate(refine).evaluate(candidate, &same, p / 0.84)), GateOutcome::kRefinement);
  EXPECT_EQ(outcome(QualityGate(refine).evaluate(candidate, &same, p / 0.86)), GateOutcome::kInForceConfirmed);
  // A better fit that changes less than its own uncertainty.
  GateOptions significance;
  significance.min_change_in_predicted = 1e6;
  EXPECT_EQ(outcome(QualityGate(significance).evaluate(candidate, &drifted)), GateOutcome::kChangeTooSmall);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
