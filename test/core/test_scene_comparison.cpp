// The scene's word on a calibration in force (scene_comparison.h) and the quality gate's use of
// it (quality_gate.h, scene_test_probability), on a window of the drive_photo head (its device,
// the window tracker's corner noise, scene matches at the matcher's noise with wrong ones among
// them):
//  - the distances against OpenCV's rectification of the same calibration (an independent
//    model): a vertical offset d between rectified points is a Sampson distance of d / sqrt(2);
//  - a calibration in force wrong by a turn of the right camera that a shift of it hides from
//    the boards (about 1.2 m away): the corners fit it as well as the new solve, the truth says
//    it is misaligned, the scene says so too, and the gate lets the new solve in;
//  - a sound calibration in force is not replaced on the scene's word, window after window;
//  - a wrong match moves the figure by at most its clip.
#include <gtest/gtest.h>

#include <Eigen/Core>  // before opencv2/core/eigen.hpp
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/calibration/calibration_filter.h"
#include "embedded_calibration_stereo/core/calibration/quality_gate.h"
#include "embedded_calibration_stereo/core/calibration/scene_comparison.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"
#include "embedded_calibration_stereo/test_support/synthetic_window.h"

namespace embedded_calibration_stereo::core {
namespace {

// The window tracker's corner RMS on drive_photo (test_window_tracker), per coordinate, and the
// matcher's spread about the true epipolar lines (test_scene_constraints).
constexpr double kWindowCornerNoisePx = 0.023 / M_SQRT2;
constexpr double kSceneNoisePx = 0.06;
constexpr double kBoardDepthM = 1.2;  // the virtual boards lie 1.13-1.26 m away
// About 0.15 px of vertical misalignment in the distant scene, the size the demo once ended with.
constexpr double kTurnRad = 2.6e-4;

// The right camera turned about its x axis and shifted along its y axis so that a point
// kBoardDepthM away projects where it did: the boards barely see the change, the distant scene
// does.
StereoRig turnedForShift(const StereoRig& truth, double turn_rad) {
  Eigen::Isometry3d change = Eigen::Isometry3d::Identity();
  change.linear() = Eigen::AngleAxisd(turn_rad, Eigen::Vector3d::UnitX()).toRotationMatrix();
  change.translation() = Eigen::Vector3d(0.0, turn_rad * kBoardDepthM, 0.0);
  StereoRig rig = truth;
  rig.right_from_left = change * truth.right_from_left;
  return rig;
}

SyntheticWindow windowOf(int seed, const StereoRig& in_force) {
  SyntheticWindow w;
  w.corner_noise_px = kWindowCornerNoisePx;
  w.corner_seed = 2100 + seed;
  w.scene_matches = 240;  // what a burst's light-off frames give on drive_photo
  w.scene_noise_px = kSceneNoisePx;
  w.scene_wrong = 0.05;
  w.scene_seed = 2200 + seed;
  w.device_seed = 2300 + seed;
  w.in_force = in_force;
  return w;
}

struct Judged {
  BundleAdjustmentSummary candidate, in_force_fit;
  GateDecision without_scene, with_scene;
};

Judged judge(const ScenarioHead& head, const SyntheticWindow& window) {
  const SyntheticWindowData data = makeSyntheticWindow(head, head.truth, window);
  Judged j;
  j.candidate = solveSyntheticWindow(head, head.truth, window);
  j.in_force_fit = evaluateFixedCalibration(*window.in_force, data.frames, data.nominal.virtualBoards(),
                                            BundleAdjustmentOptions(), &data.nominal);
  GateOptions o;
  j.without_scene = QualityGate(o).evaluate(j.candidate, &j.in_force_fit);
  o.scene_test_probability = 0.001;
  j.with_scene = QualityGate(o).evaluate(j.candidate, &j.in_force_fit);
  return j;
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

TEST(SceneComparison, DistancesAreTheRectifiedVerticalOffsetsOverRootTwo) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  const std::vector<SceneMatch> matches = generateSyntheticSceneMatches(head.truth, 300, 0.0, 0.0, 7);
  const StereoRig rig = turnedForShift(head.truth, 4 * kTurnRad);  // offsets well above the float rounding
  const std::vector<double> distances = sceneEpipolarDistances(matches, rig, rig.right.fy);
  const auto K = [](const PinholeCamera& c) { return cv::Matx33d(c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1); };
  const auto D = [](const PinholeCamera& c) { return cv::Mat(std::vector<double>(c.dist.begin(), c.dist.end()), true); };
  cv::Mat R, t, R1, R2, P1, P2, Q;
  cv::eigen2cv(Eigen::Matrix3d(rig.right_from_left.linear()), R);
  cv::eigen2cv(Eigen::Vector3d(rig.right_from_left.translation()), t);
  const cv::Size size(rig.left.width, rig.left.height);
  cv::stereoRectify(K(rig.left), D(rig.left), K(rig.right), D(rig.right), size, R, t, R1, R2, P1, P2, Q, 0, -1);
  std::vector<cv::Point2f> l, r, lr, rr;
  for (const SceneMatch& m : matches) {
    l.emplace_back(m.left_u, m.left_v);
    r.emplace_back(m.right_u, m.right_v);
  }
  cv::undistortPoints(l, lr, K(rig.left), D(rig.left), R1, P1);
  cv::undistortPoints(r, rr, K(rig.right), D(rig.right), R2, P2);
  // The rectified cameras' focal length is OpenCV's choice: back to the right camera's fy.
  const double scale = rig.right.fy / P2.at<double>(1, 1);
  double sum_ours = 0.0, sum_opencv = 0.0;
  for (size_t i = 0; i < matches.size(); ++i) {
    const double opencv = std::abs(lr[i].y - rr[i].y) * scale / M_SQRT2;
    sum_ours += distances[i] * distances[i];
    sum_opencv += opencv * opencv;
    EXPECT_NEAR(distances[i], opencv, 0.1 * opencv + 0.005) << "match " << i;
  }
  const double ours = std::sqrt(sum_ours / matches.size()), opencv = std::sqrt(sum_opencv / matches.size());
  std::printf("[ figures  ] RMS distance %.4f px, OpenCV's rectified offsets over sqrt(2) %.4f px\n", ours, opencv);
  EXPECT_NEAR(ours, opencv, 0.05 * opencv);
  EXPECT_GT(opencv, 0.3);
}

TEST(SceneComparison, ATurnTheBoardsTakeForAShiftIsCaught) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  const StereoRig in_force = turnedForShift(head.truth, kTurnRad);
  const double in_force_misalignment = evaluateStereoAccuracy(in_force, head.truth).misalignment_px.rms;
  for (int seed = 0; seed < 3; ++seed) {
    const Judged j = judge(head, windowOf(seed, in_force));
    ASSERT_TRUE(j.candidate.success && j.in_force_fit.success) << j.candidate.message << j.in_force_fit.message;
    const double candidate_misalignment = evaluateStereoAccuracy(j.candidate.rig, head.truth).misalignment_px.rms;
    const SceneComparison& s = j.candidate.scene_vs_in_force;
    std::printf("[ figures  ] window %d: misalignment %.4f px in force, %.4f px new; corners %.4f / %.4f px; "
                "scene %d matches at %.4f / %.4f px, test %.1f\n",
                seed, in_force_misalignment, candidate_misalignment, combinedRms(j.in_force_fit),
                combinedRms(j.candidate), s.matches, s.in_force_rms_px, s.candidate_rms_px, s.statistic);
    EXPECT_GT(in_force_misalignment, 0.1);
    EXPECT_LT(candidate_misalignment, in_force_misalignment / 3);
    // The boards cannot tell: on corners alone the calibration in force stands.
    EXPECT_TRUE(j.without_scene.in_force_confirmed) << j.without_scene.reason;
    // The scene can.
    EXPECT_GT(s.matches, 200);
    EXPECT_GT(s.in_force_rms_px, 1.5 * s.candidate_rms_px);
    EXPECT_TRUE(j.with_scene.accepted) << j.with_scene.reason;
    EXPECT_TRUE(contains(j.with_scene.reason, "accepted: the scene fits it better")) << j.with_scene.reason;
  }
}

TEST(SceneComparison, ASoundCalibrationInForceIsNotReplacedOnTheScenesWord) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  const double limit = chiSquareQuantile(0.001, kSceneComparisonDof);
  double sum = 0.0, worst = 0.0;
  constexpr int kWindows = 12;
  for (int seed = 0; seed < kWindows; ++seed) {
    const Judged j = judge(head, windowOf(100 + seed, head.truth));
    ASSERT_TRUE(j.candidate.success) << j.candidate.message;
    const SceneComparison& s = j.candidate.scene_vs_in_force;
    EXPECT_GT(s.matches, 200);
    EXPECT_FALSE(contains(j.with_scene.reason, "the scene fits it better")) << j.with_scene.reason;
    EXPECT_EQ(j.with_scene.accepted, j.without_scene.accepted) << j.with_scene.reason;
    sum += s.statistic;
    worst = std::max(worst, s.statistic);
  }
  std::printf("[ figures  ] the truth in force, %d windows: test mean %.2f, max %.2f (limit %.1f)\n", kWindows,
              sum / kWindows, worst, limit);
  // About a chi-square with kSceneComparisonDof degrees of freedom: its mean, with room for 12 draws.
  EXPECT_LT(sum / kWindows, 2.0 * kSceneComparisonDof);
}

TEST(SceneComparison, AWrongMatchCountsAtMostItsClip) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  std::vector<SceneMatch> matches = generateSyntheticSceneMatches(head.truth, 200, kSceneNoisePx, 0.0, 9);
  const StereoRig in_force = turnedForShift(head.truth, kTurnRad);
  const double sigma = kSceneNoisePx, clip = 5.0;
  const SceneComparison before = compareOnScene(matches, head.truth, in_force, sigma, clip);
  SceneMatch wild = matches.front();
  wild.right_v += 40.0f;  // far off any epipolar line
  matches.push_back(wild);
  const SceneComparison after = compareOnScene(matches, head.truth, in_force, sigma, clip);
  EXPECT_EQ(after.matches, before.matches + 1);
  EXPECT_LE(std::abs(after.statistic - before.statistic), clip * clip + 1e-9);
  EXPECT_GT(before.statistic, 50.0);
  // The same rig on both sides says nothing.
  EXPECT_EQ(compareOnScene(matches, in_force, in_force, sigma, clip).statistic, 0.0);
  EXPECT_THROW(compareOnScene(matches, in_force, in_force, 0.0, clip), std::invalid_argument);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
