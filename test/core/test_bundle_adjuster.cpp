// Bundle adjuster with FREE board poses (kSharedAcrossFrames, which kAuto picks when no device
// is given, and kPerFrame) against simulated corner observations with known truth: a rig like
// the sim's (752x480, fx ~650, k1 ~-0.28, k2 ~0.07, p1 = p2 = k3 = 0, baseline 0.12 m, ~0.5 deg
// rotation) and six virtual 8x6 boards of 25 mm squares, tilted +-25 deg, 1.2 m away. The
// rigid device model - the default when the device is given, and the more accurate - is
// tested against the calibrator's bounds on the sim's device in test_device_model_adjustment.cpp.
//
// Accuracy with 0.2 px corner noise is limited by the geometry: the boards appear ~95 px
// wide, so focal length trades against board distance. The Cramer-Rao bound (the covariance
// the adjuster reports, checked for calibration below) is far above the calibrator's bounds
// (0.05 % on fx, 0.01 deg) with free poses at this noise level, for one frame and for ten. So
// the tests check (a) exact recovery without noise, (b) errors within the reported standard
// deviations and those equal to the Cramer-Rao bound computed independently with OpenCV's
// Jacobians, (c) the 20-trial coverage of the reported standard deviations.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <iostream>
#include <opencv2/calib3d.hpp>
#include <random>

#include "embedded_calibration_stereo/test_support/cramer_rao.h"
#include "embedded_calibration_stereo/test_support/solution_errors.h"
#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/calibration/corner_tracks.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace embedded_calibration_stereo::core {
namespace {

struct Scenario {
  StereoRig truth = makeSimLikeStereoRig();
  std::vector<VirtualBoard> boards = makeSpreadVirtualBoards(truth.left, {});

  std::vector<StereoObservation> observe(int frames, double noise, uint64_t seed) const {
    SyntheticObservationOptions o;
    o.frames = frames;
    o.noise_sigma_px = noise;
    o.seed = seed;
    return generateSyntheticObservations(truth, boards, o);
  }
  // The calibration in force after a 5 % zoom and a 0.3 deg knock of the right camera.
  StereoRig perturbed() const {
    return driftedRig(truth, 1.05, Eigen::Vector3d(0.1, 0.3, -0.05).normalized() * 0.3);
  }
};

BundleAdjustmentSummary solve(const std::vector<StereoObservation>& frames,
                              const std::vector<VirtualBoard>& boards,
                              std::optional<StereoRig> in_force,
                              BundleAdjustmentOptions options = {},
                              BundleAdjustmentConfig config = {}) {
  CalibrationInput input;
  input.frames = &frames;
  input.boards = &boards;
  input.image_width = 752;
  input.image_height = 480;
  input.in_force = std::move(in_force);
  return BundleAdjuster(options, config).Solve(input);
}

void expectNearTruth(const StereoRig& estimate, const StereoRig& truth, double fx_rel, double c_px,
                     double k, double baseline_rel, double rotation_deg) {
  const RigErrors e = compareRigs(estimate, truth);
  for (int c = 0; c < 2; ++c) {
    EXPECT_LE(e.fx_rel[c], fx_rel) << "camera " << c;
    EXPECT_LE(e.fy_rel[c], fx_rel) << "camera " << c;
    EXPECT_LE(e.cx_px[c], c_px) << "camera " << c;
    EXPECT_LE(e.cy_px[c], c_px) << "camera " << c;
    EXPECT_LE(e.k1[c], k) << "camera " << c;
    EXPECT_LE(e.k2[c], k) << "camera " << c;
  }
  EXPECT_LE(e.baseline_rel, baseline_rel);
  EXPECT_LE(e.rotation_deg, rotation_deg);
}

TEST(SyntheticObservations, AllCornersOfTheLayoutAreSeenAndNoiseIsSeeded) {
  const Scenario s;
  const auto a = s.observe(2, 0.2, 5), b = s.observe(2, 0.2, 5), c = s.observe(1, 0.0, 5);
  ASSERT_EQ(a.size(), 2u);
  EXPECT_EQ(a[0].left.size(), 6u);
  EXPECT_GE(a[0].right.size(), 5u);
  EXPECT_EQ(a[0].left[0].u, b[0].left[0].u);        // same seed, same noise
  EXPECT_NE(a[0].left[0].u[0], a[1].left[0].u[0]);  // frames differ by noise only
  // Noise-free corners where OpenCV projects them (not the PinholeCamera they are made with).
  const PinholeCamera& cam = s.truth.left;
  const Eigen::Vector3d corner = s.boards[0].cornerInRig(c[0].left[0].corner_ids[0]);
  std::vector<cv::Point2d> p;
  cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(corner.x(), corner.y(), corner.z())}, cv::Vec3d(0, 0, 0),
                    cv::Vec3d(0, 0, 0), cv::Matx33d(cam.fx, cam.skew, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1),
                    cv::Mat(cv::Matx<double, 1, 5>(cam.dist.data()), true), p);
  EXPECT_NEAR(c[0].left[0].u[0], p[0].x, 1e-4);
  EXPECT_NEAR(c[0].left[0].v[0], p[0].y, 1e-4);
}

TEST(BundleAdjuster, NoiseFreeObservationsRecoverTheTruthFromZhang) {
  const Scenario s;
  const auto frames = s.observe(2, 0.0, 1);
  for (const auto& [mode, loss] :
       {std::make_pair(BoardPoseMode::kSharedAcrossFrames, RobustLoss::kCauchy),
        std::make_pair(BoardPoseMode::kSharedAcrossFrames, RobustLoss::kNone),
        std::make_pair(BoardPoseMode::kPerFrame, RobustLoss::kHuber)}) {
    BundleAdjustmentOptions o;
    o.board_pose_mode = mode;
    o.loss = loss;
    const BundleAdjustmentSummary r = solve(frames, s.boards, std::nullopt, o);
    ASSERT_TRUE(r.success) << r.message;
    EXPECT_TRUE(r.converged) << r.message;
    EXPECT_EQ(r.initialization, "zhang");
    EXPECT_LT(r.rms_left_px, 1e-3);
    EXPECT_LT(r.epipolar_rms_px, 1e-3);
    expectNearTruth(r.rig, s.truth, 1e-6, 1e-3, 1e-5, 1e-6, 1e-5);
  }
}

TEST(BundleAdjuster, TangentialTermsAreEstimatedOnlyWhenConfigured) {
  Scenario s;
  s.truth.left.dist[2] = 4e-4;
  s.truth.left.dist[3] = -3e-4;
  s.truth.right.dist[2] = -2.8e-4;
  s.truth.right.dist[3] = 3.6e-4;
  const auto frames = s.observe(1, 0.0, 11);
  BundleAdjustmentConfig tangential;
  tangential.estimate_tangential = true;
  const BundleAdjustmentSummary with = solve(frames, s.boards, std::nullopt, {}, tangential);
  ASSERT_TRUE(with.success) << with.message;
  expectNearTruth(with.rig, s.truth, 1e-6, 1e-3, 1e-5, 1e-6, 1e-5);
  EXPECT_NEAR(with.rig.left.dist[2], 4e-4, 2e-7);  // u, v are float32
  EXPECT_NEAR(with.rig.right.dist[3], 3.6e-4, 2e-7);
  // Default model (k1, k2): p1, p2 stay at Zhang's zero and the fit is no longer exact.
  const BundleAdjustmentSummary without = solve(frames, s.boards, std::nullopt);
  ASSERT_TRUE(without.success);
  EXPECT_EQ(without.rig.left.dist[2], 0.0);
  EXPECT_GT(without.rms_left_px, 0.01);
}

TEST(BundleAdjuster, PerturbedInForceCalibrationConvergesToTheTruth) {
  const Scenario s;
  const StereoRig start = s.perturbed();
  ASSERT_GT(compareRigs(start, s.truth).rotation_deg, 0.29);
  // Without noise the solution is the truth itself ...
  const BundleAdjustmentSummary exact = solve(s.observe(1, 0.0, 2), s.boards, start);
  ASSERT_TRUE(exact.success) << exact.message;
  EXPECT_EQ(exact.initialization, "in force");
  expectNearTruth(exact.rig, s.truth, 1e-6, 1e-3, 1e-5, 1e-6, 1e-5);
  // ... and with noise it is the same minimum Zhang's start reaches.
  const auto frames = s.observe(10, 0.2, 3);
  const BundleAdjustmentSummary from_in_force = solve(frames, s.boards, start);
  const BundleAdjustmentSummary from_zhang = solve(frames, s.boards, std::nullopt);
  ASSERT_TRUE(from_in_force.success && from_zhang.success);
  EXPECT_TRUE(from_in_force.converged);
  expectNearTruth(from_in_force.rig, from_zhang.rig, 1e-6, 1e-3, 1e-5, 1e-6, 1e-5);
}

// The reported standard deviations against the same covariance computed independently
// (cramer_rao.h: OpenCV's projection Jacobians, no Ceres) and the true errors within 4 of them.
// (1) Linearised at the solution (its rig and board poses) with its residual sigma, as the
// adjuster does: within 5 %, for its Cauchy loss weights residuals of ~0.28 px by ~0.93
// against its 1 px scale (sd ~4 % higher with one frame; ten frames' track means are sqrt(10)
// less noisy, so ~0.4 %). (2) At the truth with the true noise - the Cramer-Rao bound, the best any
// unbiased estimator can do: within 10 % at 10 frames; one frame's estimate is too far from the
// truth for the bound at the truth to describe its covariance that closely.
// A missing noise scale, frames not counted or a parameter block left out are far outside.
TEST(BundleAdjuster, NoisyFramesReportTheCramerRaoBound) {
  const Scenario s;
  const StereoObservation visible = s.observe(1, 0.0, 1).front();
  for (int frames : {1, 10}) {
    SCOPED_TRACE(std::to_string(frames) + " frame(s)");
    const BundleAdjustmentSummary r = solve(s.observe(frames, 0.2, 4), s.boards, s.perturbed());
    ASSERT_TRUE(r.success) << r.message;
    ASSERT_TRUE(r.converged);
    ASSERT_TRUE(r.covariance_ok);
    EXPECT_EQ(r.frames_used, frames);
    EXPECT_EQ(r.boards_left, 6);
    EXPECT_GE(r.boards_right, 5);
    // Corner noise 0.2 px per coordinate: the RMS of the error norm is 0.2 * sqrt(2).
    EXPECT_NEAR(r.rms_left_px, 0.2 * std::sqrt(2.0), 0.03);
    EXPECT_NEAR(r.rms_right_px, 0.2 * std::sqrt(2.0), 0.03);
    EXPECT_NEAR(r.residual_sigma_px, 0.2, 0.02);
    EXPECT_NEAR(r.epipolar_rms_px, 0.2 * std::sqrt(2.0), 0.05);  // both corners' noise
    for (double z : errorsInReportedStddevs(r, s.truth)) EXPECT_LE(z, 4.0);
    std::vector<VirtualBoard> estimated_boards = s.boards;
    for (VirtualBoard& b : estimated_boards) {
      ASSERT_TRUE(r.rig_from_board.count(b.virtual_id));
      b.rig_from_board = r.rig_from_board.at(b.virtual_id);
    }
    const CramerRaoBound at_solution =
        freePoseCramerRaoBound(r.rig, estimated_boards, visible, frames, r.residual_sigma_px);
    const CramerRaoBound at_truth = freePoseCramerRaoBound(s.truth, s.boards, visible, frames, 0.2);
    const auto expectBound = [&](double reported, double solution, double truth, const std::string& what) {
      std::printf("[ figures  ] %s sd: reported %.4g, linearised at the solution %.4g (ratio %.3f), "
                  "Cramer-Rao bound %.4g (ratio %.3f)\n",
                  what.c_str(), reported, solution, reported / solution, truth, reported / truth);
      EXPECT_NEAR(reported / solution, 1.0, 0.05) << what;
      if (frames == 10) EXPECT_NEAR(reported / truth, 1.0, 0.10) << what;
    };
    for (int c = 0; c < 2; ++c) {
      const CameraStddev& rep = c == 0 ? r.left_stddev : r.right_stddev;
      const CameraStddev& sol = c == 0 ? at_solution.left_stddev : at_solution.right_stddev;
      const CameraStddev& tru = c == 0 ? at_truth.left_stddev : at_truth.right_stddev;
      const std::string side = c == 0 ? "left " : "right ";
      expectBound(rep.fx, sol.fx, tru.fx, side + "fx");
      expectBound(rep.fy, sol.fy, tru.fy, side + "fy");
      expectBound(rep.cx, sol.cx, tru.cx, side + "cx");
      expectBound(rep.cy, sol.cy, tru.cy, side + "cy");
      expectBound(rep.dist[0], sol.dist[0], tru.dist[0], side + "k1");
      expectBound(rep.dist[1], sol.dist[1], tru.dist[1], side + "k2");
    }
    expectBound(r.baseline_stddev_m, at_solution.baseline_stddev_m, at_truth.baseline_stddev_m, "baseline");
    expectBound(r.rotation_stddev_deg, at_solution.rotation_stddev_deg, at_truth.rotation_stddev_deg, "rotation");
    // Unestimated terms are held and report no uncertainty.
    EXPECT_EQ(r.rig.left.dist[2], 0.0);
    EXPECT_EQ(r.left_stddev.dist[4], 0.0);
  }
}

TEST(BundleAdjuster, ReportedStddevsCoverTheTrueErrorIn95PercentOfTwentyTrials) {
  const Scenario s;
  int inside = 0, total = 0;
  for (int trial = 0; trial < 20; ++trial) {
    const BundleAdjustmentSummary r = solve(s.observe(10, 0.2, 100 + trial), s.boards, s.truth);
    ASSERT_TRUE(r.success && r.covariance_ok) << r.message;
    for (double z : errorsInReportedStddevs(r, s.truth)) {
      ++total;
      if (z <= 3.0) ++inside;
    }
  }
  std::cout << "within 3 reported stddevs: " << inside << " of " << total << "\n";
  EXPECT_GE(static_cast<double>(inside) / total, 0.95) << inside << " of " << total;
}

TEST(BundleAdjuster, SharedAndPerFramePosesAgreeOnTheSameObservations) {
  const Scenario s;
  const auto frames = s.observe(3, 0.2, 6);
  BundleAdjustmentOptions per_frame;
  per_frame.board_pose_mode = BoardPoseMode::kPerFrame;
  const BundleAdjustmentSummary a = solve(frames, s.boards, s.truth);
  const BundleAdjustmentSummary b = solve(frames, s.boards, s.truth, per_frame);
  ASSERT_TRUE(a.success && b.success);
  // Same information on the cameras (the Schur complements coincide when every frame sees
  // the same boards); the solutions differ by a small fraction of a standard deviation.
  EXPECT_LT(std::abs(a.rig.left.fx - b.rig.left.fx), 0.2 * a.left_stddev.fx);
  EXPECT_NEAR(a.left_stddev.fx, b.left_stddev.fx, 0.05 * a.left_stddev.fx);
  EXPECT_EQ(a.rig_from_board.size(), 6u);
}

TEST(CornerTracks, MedianTestDropsAFrameWithAMisdetectedCorner) {
  BoardView v;
  v.corner_ids = {0};
  std::vector<BoardView> views(4, v);
  for (int f = 0; f < 4; ++f) {
    views[f].frame = f;
    views[f].pixels = {Eigen::Vector2d(100.0 + 0.1 * f, 50.0)};
  }
  views[2].pixels[0].x() += 5.0;
  const CornerTracks shared = buildCornerTracks(views, true, 2.0);
  ASSERT_EQ(shared.tracks.size(), 1u);
  EXPECT_EQ(shared.rejected, 1);
  EXPECT_EQ(shared.tracks[0].observations.size(), 3u);
  EXPECT_NEAR(shared.tracks[0].mean.x(), 100.0 + 0.1 * (0 + 1 + 3) / 3.0, 1e-12);
  const CornerTracks per_frame = buildCornerTracks(views, false, 2.0);
  EXPECT_EQ(per_frame.tracks.size(), 4u);
  EXPECT_EQ(per_frame.rejected, 0);
}

// --- invalid input: dropped with a reason, never a crash ---

bool anyReasonContains(const BundleAdjustmentSummary& s, const std::string& text) {
  for (const std::string& r : s.dropped)
    if (r.find(text) != std::string::npos) return true;
  return false;
}

TEST(BundleAdjuster, BadObservationsAreDroppedWithAReason) {
  const Scenario s;
  auto frames = s.observe(2, 0.2, 7);
  BoardCorners& a = frames[0].left[0];
  a.u[0] = std::numeric_limits<float>::quiet_NaN();
  a.v[1] = std::numeric_limits<float>::infinity();
  BoardCorners& b = frames[0].left[1];
  b.corner_ids[3] = b.corner_ids[4];  // duplicate id
  // Right boards near the image border are partly cut off: edit complete ones.
  const auto largest = [](const std::vector<BoardCorners>& list, size_t skip) {
    size_t best = skip == 0 ? 1 : 0;
    for (size_t i = 0; i < list.size(); ++i)
      if (i != skip && list[i].size() > list[best].size()) best = i;
    return best;
  };
  BoardCorners& c = frames[0].right[largest(frames[0].right, 99)];
  c.corner_ids[0] = 48;  // 8 x 6 board: ids 0..47
  c.corner_ids[1] = -1;
  BoardCorners unknown = frames[1].left[2];
  unknown.board_id = 99;
  frames[1].left.push_back(unknown);
  const size_t ragged_index = largest(frames[1].right, 99);
  BoardCorners ragged = frames[1].right[ragged_index];
  ragged.u.pop_back();
  frames[1].right[ragged_index] = ragged;
  frames[1].left[3].u[0] = 5000.0f;  // far outside the image

  const BundleAdjustmentSummary r = solve(frames, s.boards, s.truth);
  ASSERT_TRUE(r.success) << r.message;
  EXPECT_TRUE(anyReasonContains(r, "non-finite")) << ::testing::PrintToString(r.dropped);
  EXPECT_TRUE(anyReasonContains(r, "duplicate ids"));
  EXPECT_TRUE(anyReasonContains(r, "ids outside the board"));
  EXPECT_TRUE(anyReasonContains(r, "board 99: unknown board_id"));
  EXPECT_TRUE(anyReasonContains(r, "differ in length"));
  EXPECT_TRUE(anyReasonContains(r, "outside the image"));
  // 2 non-finite + 2 duplicates + 2 bad ids + 1 outside + the ragged board are gone, the rest
  // is used and still fits.
  const size_t all = frames[0].cornerCount() + frames[1].cornerCount();
  const size_t dropped = 2 + 2 + 2 + 1 + unknown.size() + ragged.corner_ids.size();
  EXPECT_EQ(static_cast<size_t>(r.corners_used), all - dropped);
  EXPECT_LT(r.rms_left_px, 0.4);
}

TEST(BundleAdjuster, ImageSizeInconsistentWithTheCalibrationInForceIsRejected) {
  const Scenario s;
  const auto frames = s.observe(1, 0.2, 8);
  CalibrationInput input;
  input.frames = &frames;
  input.boards = &s.boards;
  input.image_width = 640;
  input.image_height = 480;
  input.in_force = s.truth;
  const BundleAdjustmentSummary r = BundleAdjuster({}, {}).Solve(input);
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.message.find("image size 640x480"), std::string::npos) << r.message;
}

TEST(BundleAdjuster, NothingUsableAndBadOptionsFailWithAMessage) {
  const Scenario s;
  const std::vector<StereoObservation> none(3);
  EXPECT_FALSE(solve(none, s.boards, s.truth).success);
  BundleAdjustmentOptions bad;
  bad.loss_scale_px = -1;
  const BundleAdjustmentSummary r = solve(s.observe(1, 0.2, 9), s.boards, s.truth, bad);
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.message.find("loss_scale_px"), std::string::npos);
  CalibrationInput missing;
  EXPECT_FALSE(BundleAdjuster({}, {}).Solve(missing).success);
}

TEST(BundleAdjuster, FixedCalibrationEvaluationSeparatesTruthFromADriftedRig) {
  const Scenario s;
  const auto frames = s.observe(5, 0.2, 10);
  const BundleAdjustmentSummary truth_fit = evaluateFixedCalibration(s.truth, frames, s.boards);
  const BundleAdjustmentSummary drifted_fit =
      evaluateFixedCalibration(s.perturbed(), frames, s.boards);
  ASSERT_TRUE(truth_fit.success && drifted_fit.success);
  EXPECT_NEAR(truth_fit.rms_left_px, 0.2 * std::sqrt(2.0), 0.02);
  EXPECT_GT(drifted_fit.rms_right_px, 3 * truth_fit.rms_right_px);
  EXPECT_GT(drifted_fit.epipolar_rms_px, 1.0);
  // The rig is untouched.
  EXPECT_DOUBLE_EQ(drifted_fit.rig.left.fx, s.perturbed().left.fx);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
