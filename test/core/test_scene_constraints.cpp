// Scene correspondences as epipolar constraints of the calibration (scene_matches.h,
// scene_epipolar_cost.h, bundle_adjuster.h):
//  - the cost: zero on true correspondences of a distorted rig, derivatives as central
//    differences give them (the undistortion's one Newton step carries the implicit function's
//    derivative);
//  - the solve: one light window of the drive_photo head (its device, the window tracker's
//    corner noise), with and without scene matches at every depth (synthetic, with wrong
//    matches among them), judged against the truth in a depth user's terms (stereo_accuracy.h):
//    the matches separate the stereo rotation from the translation, so the vertical
//    misalignment falls several times, the wrong matches are dropped, and the covariance still
//    predicts the true errors (each kind of observation weighed at its own noise);
//  - the matcher on rendered drive_photo light-off frames (the head driving, movers), against the
//    simulator's true calibration through OpenCV's rectification (an independent model): the
//    matches' vertical offset after rectification.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <Eigen/Core>  // before opencv2/core/eigen.hpp
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>
#include <memory>
#include <random>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/calibration/scene_epipolar_cost.h"
#include "embedded_calibration_stereo/core/calibration/scene_matches.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"
#include "embedded_calibration_stereo/test_support/synthetic_window.h"

namespace embedded_calibration_stereo::core {
namespace {

// The window tracker's corner RMS on drive_photo (test_window_tracker), per coordinate.
constexpr double kWindowCornerNoisePx = 0.023 / M_SQRT2;
// The matcher's spread about the true epipolar line on drive_photo (bench_calibrate_moving
// --scene 1 prints it), per coordinate, and the share of wrong matches injected.
constexpr double kSceneNoisePx = 0.06;
constexpr double kWrongShare = 0.05;

std::array<double, 9> block(const PinholeCamera& c) {
  return {{c.fx, c.fy, c.cx, c.cy, c.dist[0], c.dist[1], c.dist[2], c.dist[3], c.dist[4]}};
}
std::array<double, 6> block(const Eigen::Isometry3d& t) {
  const Eigen::AngleAxisd aa(t.linear());
  const Eigen::Vector3d r = aa.angle() * aa.axis(), p = t.translation();
  return {{r.x(), r.y(), r.z(), p.x(), p.y(), p.z()}};
}

TEST(SceneEpipolarCost, ZeroOnTrueCorrespondencesAndDerivativesAsCentralDifferences) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  const std::vector<SceneMatch> matches = generateSyntheticSceneMatches(head.truth, 200, 0.0, 0.0, 3);
  std::array<double, 9> left = block(head.truth.left), right = block(head.truth.right);
  std::array<double, 6> extrinsics = block(head.truth.right_from_left);
  const double unit = 1.0;
  double worst = 0.0;
  for (const SceneMatch& m : matches) {
    double r = 1.0;
    ASSERT_TRUE(SceneEpipolarCost(m, head.truth.right.fy, &unit)(left.data(), right.data(), extrinsics.data(), &r));
    worst = std::max(worst, std::abs(r));
  }
  // float pixel coordinates: ~3e-5 px of rounding.
  EXPECT_LT(worst, 2e-4) << "px on true correspondences";

  // Autodiff (the Newton step's derivative) against central differences of the double residual,
  // at a rig off the truth so that the residuals and their slopes are not special.
  left[kFx] *= 1.01;
  right[kK1] += 0.01;
  extrinsics[1] += 0.002;
  double* blocks[3] = {left.data(), right.data(), extrinsics.data()};
  const int sizes[3] = {9, 9, 6};
  std::unique_ptr<ceres::CostFunction> cost(SceneEpipolarCost::Create(matches[7], head.truth.right.fy, &unit));
  double residual = 0.0, j_left[9], j_right[9], j_extrinsics[6];
  double* jacobians[3] = {j_left, j_right, j_extrinsics};
  ASSERT_TRUE(cost->Evaluate(blocks, &residual, jacobians));
  for (int b = 0; b < 3; ++b)
    for (int i = 0; i < sizes[b]; ++i) {
      if (b < 2 && i == kK3) continue;  // k3 unused by the head, but differentiable all the same
      const double step = std::max(1e-7, 1e-6 * std::abs(blocks[b][i]));
      const double keep = blocks[b][i];
      double plus = 0.0, minus = 0.0;
      blocks[b][i] = keep + step;
      SceneEpipolarCost(matches[7], head.truth.right.fy, &unit)(left.data(), right.data(), extrinsics.data(), &plus);
      blocks[b][i] = keep - step;
      SceneEpipolarCost(matches[7], head.truth.right.fy, &unit)(left.data(), right.data(), extrinsics.data(), &minus);
      blocks[b][i] = keep;
      const double numeric = (plus - minus) / (2.0 * step);
      EXPECT_NEAR(jacobians[b][i], numeric, 1e-5 * std::max(1.0, std::abs(numeric)))
          << "block " << b << " parameter " << i;
    }
}

struct WindowResult {
  double misalignment = 0, bias = 0, predicted_misalignment = 0, predicted_bias = 0;
  int used = 0, dropped = 0;
  double sigma = 0;
};

WindowResult solveWindow(const ScenarioHead& head, int trial, int scene_count, double scene_noise_px,
                         int* wrong = nullptr) {
  SyntheticWindow window;
  window.corner_noise_px = kWindowCornerNoisePx;
  window.corner_seed = 1700 + trial;
  window.scene_matches = scene_count;
  window.scene_noise_px = scene_noise_px;
  window.scene_wrong = kWrongShare;
  window.scene_seed = 50 + trial;
  window.device_seed = 1800 + trial;
  window.in_force = driftedRig(head.truth, 1.05, Eigen::Vector3d(0.02, 0.07, -0.03));
  const BundleAdjustmentSummary r = solveSyntheticWindow(head, head.truth, window, wrong);
  EXPECT_TRUE(r.success && r.covariance_ok) << r.message;
  WindowResult w;
  if (!r.success || !r.covariance_ok) return w;
  const StereoAccuracy t = evaluateStereoAccuracy(r.rig, head.truth);
  const StereoAccuracy p = predictStereoAccuracy(r.rig, r.rig_covariance);
  w.misalignment = t.misalignment_px.rms;
  w.bias = t.disparity_bias_px.rms;
  w.predicted_misalignment = p.misalignment_px.rms;
  w.predicted_bias = p.disparity_bias_px.rms;
  w.used = r.scene_matches_used;
  w.dropped = r.scene_matches_dropped;
  w.sigma = r.scene_sigma_px;
  return w;
}

struct Rms {
  double misalignment = 0, bias = 0, predicted_misalignment = 0, predicted_bias = 0;
};

// RMS over `trials` windows; scene_count 0: boards only.
Rms runWindows(const ScenarioHead& head, int trials, int scene_count, double scene_noise_px) {
  Rms rms;
  for (int trial = 0; trial < trials; ++trial) {
    int wrong = 0;
    const WindowResult w = solveWindow(head, trial, scene_count, scene_noise_px, &wrong);
    if (scene_count) {
      // The wrong matches are dropped (at the matcher's noise nearly all: near the image's
      // corners the distortion bends the epipolar lines, and a shift along the rows can undo
      // some of a 1 px offset across them; at 0.25 px, 5 spreads are more than 1 px: those
      // wrong ones stay, under the robust loss), few good ones with them; the spread is the
      // good matches' own (Sampson: the distance in the joint 4-D space).
      const double dropped_good_share = (w.dropped - wrong) / static_cast<double>(scene_count);
      if (scene_noise_px <= kSceneNoisePx) EXPECT_GE(w.dropped, 0.9 * wrong) << "window " << trial;
      EXPECT_LE(dropped_good_share, 0.01) << "window " << trial;
      EXPECT_NEAR(w.sigma, scene_noise_px, 0.25 * scene_noise_px) << "window " << trial;
    }
    rms.misalignment += w.misalignment * w.misalignment / trials;
    rms.bias += w.bias * w.bias / trials;
    rms.predicted_misalignment += w.predicted_misalignment * w.predicted_misalignment / trials;
    rms.predicted_bias += w.predicted_bias * w.predicted_bias / trials;
  }
  for (double* v : {&rms.misalignment, &rms.bias, &rms.predicted_misalignment, &rms.predicted_bias}) *v = std::sqrt(*v);
  std::printf("[ figures  ] %3d scene matches at %.2f px: misalignment %.4f px (predicted %.4f), bias %.4f px "
              "(predicted %.4f), RMS over %d windows\n",
              scene_count, scene_noise_px, rms.misalignment, rms.predicted_misalignment, rms.bias,
              rms.predicted_bias, trials);
  return rms;
}

void expectAsPredicted(const Rms& r) {
  EXPECT_LE(std::max(r.misalignment / r.predicted_misalignment, r.predicted_misalignment / r.misalignment), 1.5);
  EXPECT_LE(std::max(r.bias / r.predicted_bias, r.predicted_bias / r.bias), 1.5);
}

// 20 windows: the RMS over them scatters by about a sixth; 1.5 leaves room for that.
TEST(SceneConstraints, SeparateRotationFromTranslationAndKeepTheCovarianceHonest) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  const Rms boards = runWindows(head, 20, 0, 0.0);
  const Rms scene = runWindows(head, 20, 600, kSceneNoisePx);
  expectAsPredicted(boards);
  expectAsPredicted(scene);
  EXPECT_LT(scene.misalignment, 0.35 * boards.misalignment);
  EXPECT_LT(scene.bias, boards.bias);
  // Noisier matches count for less, and the prediction follows them.
  const Rms noisy = runWindows(head, 20, 600, 0.25);
  expectAsPredicted(noisy);
  EXPECT_GT(noisy.predicted_misalignment, 1.5 * scene.predicted_misalignment);
}

TEST(SceneConstraints, TooFewMatchesAreNotUsed) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  const WindowResult with = solveWindow(head, 0, BundleAdjustmentOptions().min_scene_matches - 1, kSceneNoisePx);
  const WindowResult without = solveWindow(head, 0, 0, 0.0);
  EXPECT_EQ(with.used, 0);
  EXPECT_EQ(with.misalignment, without.misalignment);
  EXPECT_EQ(with.bias, without.bias);
}

// The matcher on rendered light-off frames of the moving world: the matches' vertical offset
// after rectifying them with the true calibration (OpenCV: stereoRectify, undistortPoints).
TEST(SceneMatches, LieOnTheTrueEpipolarLinesOfRenderedFrames) {
  const SimRigConfig config = loadSimRigConfig(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  SimRig sim(config);
  const StereoRig& rig = config.rig;
  const cv::Size size(rig.left.width, rig.left.height);
  const auto K = [](const PinholeCamera& c) { return cv::Matx33d(c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1); };
  const auto D = [](const PinholeCamera& c) { return cv::Mat(std::vector<double>(c.dist.begin(), c.dist.end()), true); };
  cv::Mat R, t, R1, R2, P1, P2, Q;
  cv::eigen2cv(Eigen::Matrix3d(rig.right_from_left.linear()), R);
  cv::eigen2cv(Eigen::Vector3d(rig.right_from_left.translation()), t);
  cv::stereoRectify(K(rig.left), D(rig.left), K(rig.right), D(rig.right), size, R, t, R1, R2, P1, P2, Q,
                    cv::CALIB_ZERO_DISPARITY, 0);
  SceneMatchBuffers buffers;
  std::vector<double> offsets;
  int frames = 0;
  for (double time_s : {1.0, 2.3, 4.1, 6.7, 9.2}) {
    const SimFrame f = sim.render(time_s, 0.0, 400 + frames);
    cv::Mat left = f.left, right = f.right;
    if (left.channels() == 3) cv::cvtColor(f.left, left, cv::COLOR_BGR2GRAY);
    if (right.channels() == 3) cv::cvtColor(f.right, right, cv::COLOR_BGR2GRAY);
    const std::vector<SceneMatch> matches = matchStereoScene(left, right, rig, SceneMatchOptions(), &buffers);
    EXPECT_GE(matches.size(), 60u) << "at " << time_s << " s";
    std::vector<cv::Point2f> l, r, lr, rr;
    for (const SceneMatch& m : matches) {
      l.emplace_back(m.left_u, m.left_v);
      r.emplace_back(m.right_u, m.right_v);
    }
    if (l.empty()) continue;
    cv::undistortPoints(l, lr, K(rig.left), D(rig.left), R1, P1);
    cv::undistortPoints(r, rr, K(rig.right), D(rig.right), R2, P2);
    for (size_t i = 0; i < lr.size(); ++i) offsets.push_back(std::abs(lr[i].y - rr[i].y));
    ++frames;
  }
  ASSERT_GE(offsets.size(), 400u);
  std::sort(offsets.begin(), offsets.end());
  const double median = offsets[offsets.size() / 2], p90 = offsets[offsets.size() * 9 / 10];
  std::printf("[ figures  ] %zu matches in %d frames: vertical offset after rectification with the truth, median "
              "%.3f px, 90 %% %.3f px, max %.2f px\n",
              offsets.size(), frames, median, p90, offsets.back());
  EXPECT_LE(median, 0.08);
  EXPECT_LE(p90, 0.5);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
