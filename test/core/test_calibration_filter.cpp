// Carrying what earlier windows taught into the next window's solve (calibration_filter.h, the
// bundle adjuster's RigPrior), on the drive_photo head (its device, one window observation at
// the window tracker's corner noise and the scene's correspondences, both synthetic with known
// truth):
//  - the innovation test's limits are the chi-square quantiles of the tables;
//  - a zoom, a knock (a turn and a move of the right camera), a 0.05 deg turn about the vertical
//    axis (the weakest direction) and a 0.34 deg turn of the right camera about its centre are
//    each recognised as the change of the groups they move (a turn about the camera's centre
//    moves the stereo rotation, not the translation), and other groups are rarely taken as
//    changed (the test's level, 5 %);
//  - after a knock and after a turn, the window solved with the prior of the groups that did not
//    change (learned from three windows before it) is closer to the truth than the window alone,
//    and its covariance still predicts its errors (12 windows each, against the truth in a depth
//    user's terms, stereo_accuracy.h).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <set>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/calibration/calibration_filter.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"
#include "embedded_calibration_stereo/test_support/synthetic_window.h"

namespace embedded_calibration_stereo::core {
namespace {

constexpr double kWindowCornerNoisePx = 0.023 / M_SQRT2;  // test_window_tracker, per coordinate
constexpr double kSceneNoisePx = 0.06;                    // test_scene_constraints

// One window of `truth` solved as the calibrator does (the nominal device off by manufacturing
// tolerances, p1 and p2 estimated), with `prior` if given.
BundleAdjustmentSummary solveWindow(const ScenarioHead& head, const StereoRig& truth, int seed,
                                    const std::optional<RigPrior>& prior = std::nullopt) {
  SyntheticWindow w;
  w.corner_noise_px = kWindowCornerNoisePx;
  w.corner_seed = 3000 + seed;
  w.scene_matches = 600;
  w.scene_noise_px = kSceneNoisePx;
  w.scene_seed = 4000 + seed;
  w.in_force = head.truth;
  w.prior = prior;
  const BundleAdjustmentSummary r = solveSyntheticWindow(head, truth, w);
  EXPECT_TRUE(r.success && r.covariance_ok) << r.message;
  return r;
}

// A filter whose state has learned from `windows` windows of the truth (the first alone, each
// next one with the prior the filter gives it), as the calibrator's does while nothing changes.
CalibrationFilter learnedFilter(const ScenarioHead& head, int windows, int seed, const CalibrationFilterOptions& options) {
  CalibrationFilter filter(options);
  for (int w = 0; w < windows; ++w) {
    const BundleAdjustmentSummary alone = solveWindow(head, head.truth, seed + 100 * w);
    const std::optional<RigPrior> prior = filter.priorFor(alone, 5.0 * w);
    const BundleAdjustmentSummary solved = prior ? solveWindow(head, head.truth, seed + 100 * w, prior) : alone;
    filter.setState(solved.rig, solved.rig_covariance, 5.0 * w);
  }
  return filter;
}

StereoRig knocked(const StereoRig& truth) {
  StereoRig rig = truth;
  Eigen::Isometry3d knock = Eigen::Isometry3d::Identity();
  knock.linear() = Eigen::AngleAxisd(0.04 * M_PI / 180.0, Eigen::Vector3d(0.6, -0.45, 0.66).normalized())
                       .toRotationMatrix();
  knock.translation() = Eigen::Vector3d(0.0008, 0.0003, -0.0005);
  rig.right_from_left = knock * rig.right_from_left;
  return rig;
}

// The right camera turned about its centre as heat and a knock of drive_photo_live turn it.
StereoRig turnedRight(const StereoRig& truth) { return driftedRig(truth, 1.0, Eigen::Vector3d(0.2, -0.25, 0.1)); }

// The synthetic corners' noise is what the solves' covariances say.
CalibrationFilterOptions exactNoise() {
  CalibrationFilterOptions o;
  o.covariance_scale = 1.0;
  return o;
}

TEST(CalibrationFilter, ChiSquareQuantilesAreTheTables) {
  // Upper 0.1 % and 5 % points (any statistics table).
  EXPECT_NEAR(chiSquareQuantile(1e-3, 1), 10.828, 1e-3);
  EXPECT_NEAR(chiSquareQuantile(1e-3, 2), 13.816, 1e-3);
  EXPECT_NEAR(chiSquareQuantile(1e-3, 3), 16.266, 1e-3);
  EXPECT_NEAR(chiSquareQuantile(1e-3, 4), 18.467, 1e-3);
  EXPECT_NEAR(chiSquareQuantile(1e-3, 5), 20.515, 1e-3);
  EXPECT_NEAR(chiSquareQuantile(0.05, 2), 5.991, 1e-3);
  EXPECT_NEAR(chiSquareQuantile(0.05, 3), 7.815, 1e-3);
}

TEST(CalibrationFilter, ChangesAreTheGroupsTheyMove) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  struct Case {
    const char* name;
    StereoRig truth;
    std::set<std::string> expected;
  };
  StereoRig zoomed = head.truth;
  zoomed.left = zoomed.left.withFocalScale(1.05);
  zoomed.right = zoomed.right.withFocalScale(1.05);
  const std::vector<Case> cases = {
      {"nothing", head.truth, {}},
      {"5 % zoom", zoomed, {"left focal length", "right focal length"}},
      {"knock", knocked(head.truth), {"stereo rotation", "stereo translation"}},
      {"0.05 deg turn", driftedRig(head.truth, 1.0, Eigen::Vector3d(0.0, 0.05, 0.0)), {"stereo rotation"}},
      // Its translation turns with it (by 0.7 mm); its centre stays.
      {"0.34 deg turn", turnedRight(head.truth), {"stereo rotation"}},
  };
  const int seeds = 5;
  int unexpected = 0, tests = 0;
  for (int seed = 0; seed < seeds; ++seed) {
    const CalibrationFilter filter = learnedFilter(head, 3, 10 * seed, exactNoise());
    for (const Case& c : cases) {
      const BundleAdjustmentSummary window = solveWindow(head, c.truth, 10 * seed + 1);
      std::vector<std::string> changed;
      const std::optional<RigPrior> prior = filter.priorFor(window, 15.0, &changed);
      const std::set<std::string> flagged(changed.begin(), changed.end());
      for (const std::string& g : c.expected) EXPECT_EQ(flagged.count(g), 1u) << c.name << ", seed " << seed << ": " << g;
      for (const std::string& g : flagged) unexpected += c.expected.count(g) == 0;
      tests += static_cast<int>(calibrationGroupNames().size() - c.expected.size());
      ASSERT_TRUE(prior.has_value()) << c.name;
      // Every estimated parameter of the unflagged groups has a prior (k3 is held).
      int expected_active = 0;
      for (size_t g = 0; g < calibrationGroupNames().size(); ++g) {
        const std::string& name = calibrationGroupNames()[g];
        if (flagged.count(name)) continue;
        expected_active += name.find("focal") != std::string::npos || name.find("principal") != std::string::npos ? 2
                           : name.find("distortion") != std::string::npos                                          ? 4
                                                                                                                    : 3;
      }
      EXPECT_EQ(prior->activeCount(), expected_active) << c.name;
    }
  }
  std::printf("[ figures  ] %d of %d unchanged groups taken as changed\n", unexpected, tests);
  // What a zoom and a pan move are the groups a health verdict releases.
  EXPECT_EQ(std::set<std::string>(turnAndZoomGroups().begin(), turnAndZoomGroups().end()),
            (std::set<std::string>{"left focal length", "right focal length", "stereo rotation"}));
  // Binomial(tests, 0.05): mean 5 % of them; 12 % is beyond 3 of its standard deviations.
  EXPECT_LE(unexpected, 0.12 * tests);
}

// RMS over `trials` windows of `after` against its truth: alone, with the prior of the groups the
// filter did not take as changed, and the prediction of the latter's covariance (px).
struct PriorFigures {
  double alone_m = 0, alone_b = 0, fused_m = 0, fused_b = 0, fused_pm = 0, fused_pb = 0;
};

// filters[t] is window t's filter, learned from three earlier windows of the truth.
PriorFigures priorFigures(const ScenarioHead& head, const StereoRig& after, const std::vector<CalibrationFilter>& filters,
                          int* translation_priors) {
  PriorFigures out;
  *translation_priors = 0;
  const int trials = static_cast<int>(filters.size());
  for (int t = 0; t < trials; ++t) {
    const CalibrationFilter& filter = filters[t];
    const BundleAdjustmentSummary alone = solveWindow(head, after, 1001 + 10 * t);
    const std::optional<RigPrior> prior = filter.priorFor(alone, 15.0);
    EXPECT_TRUE(prior.has_value());
    if (!prior) return out;
    *translation_priors += prior->active[21] && prior->active[22] && prior->active[23];
    const BundleAdjustmentSummary fused = solveWindow(head, after, 1001 + 10 * t, prior);
    EXPECT_EQ(fused.prior_parameters, prior->activeCount());
    const StereoAccuracy a = evaluateStereoAccuracy(alone.rig, after), f = evaluateStereoAccuracy(fused.rig, after);
    const StereoAccuracy p = predictStereoAccuracy(fused.rig, fused.rig_covariance);
    out.alone_m += std::pow(a.misalignment_px.rms, 2) / trials;
    out.alone_b += std::pow(a.disparity_bias_px.rms, 2) / trials;
    out.fused_m += std::pow(f.misalignment_px.rms, 2) / trials;
    out.fused_b += std::pow(f.disparity_bias_px.rms, 2) / trials;
    out.fused_pm += std::pow(p.misalignment_px.rms, 2) / trials;
    out.fused_pb += std::pow(p.disparity_bias_px.rms, 2) / trials;
  }
  for (double* v : {&out.alone_m, &out.alone_b, &out.fused_m, &out.fused_b, &out.fused_pm, &out.fused_pb})
    *v = std::sqrt(*v);
  return out;
}

TEST(CalibrationFilter, ThePriorOfTheUnchangedGroupsBringsAKnockedWindowCloserAsPredicted) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  const int trials = 12;
  // The same earlier windows before either event.
  std::vector<CalibrationFilter> filters;
  for (int t = 0; t < trials; ++t) filters.push_back(learnedFilter(head, 3, 1000 + 10 * t, exactNoise()));
  struct Event {
    const char* name;
    StereoRig after;
    bool translation_kept;  // a turn about the camera's centre keeps the translation's prior
  };
  for (const Event& e : {Event{"knock (turn and move)", knocked(head.truth), false},
                         Event{"turn about the right camera's centre", turnedRight(head.truth), true}}) {
    int translation_priors = 0;
    const PriorFigures f = priorFigures(head, e.after, filters, &translation_priors);
    std::printf("[ figures  ] after a %s, RMS over %d windows: alone misalignment %.4f px, bias %.4f px; with the "
                "prior of the unchanged groups misalignment %.4f px (predicted %.4f), bias %.4f px (predicted %.4f); "
                "translation in the prior in %d\n",
                e.name, trials, f.alone_m, f.alone_b, f.fused_m, f.fused_pm, f.fused_b, f.fused_pb,
                translation_priors);
    // An unchanged group is taken as changed in 5 % of the windows.
    if (e.translation_kept)
      EXPECT_GE(translation_priors, trials - 2) << e.name;
    else
      EXPECT_EQ(translation_priors, 0) << e.name;
    EXPECT_LT(f.fused_b, 0.85 * f.alone_b) << e.name;
    EXPECT_LT(f.fused_m, 1.1 * f.alone_m) << e.name;
    // 12 windows scatter an RMS by about a fifth.
    EXPECT_LE(std::max(f.fused_b / f.fused_pb, f.fused_pb / f.fused_b), 1.5) << e.name;
    EXPECT_LE(std::max(f.fused_m / f.fused_pm, f.fused_pm / f.fused_m), 1.5) << e.name;
  }
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
