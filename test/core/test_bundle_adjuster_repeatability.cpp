// The bundle adjuster gives the same bits for the same input whatever ran before it in the
// process. Ceres orders the eliminated blocks of the Schur solver, and the covariance's columns,
// by the blocks' addresses; board poses kept in std::map nodes would follow the heap's history
// (which chunks earlier code freed), and the rounding of every result with them. Here the same
// observations are solved after different allocation patterns and compared bit for bit.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <memory>
#include <random>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace embedded_calibration_stereo::core {
namespace {

// Every double of a summary that the solve computes (timings excluded).
std::vector<double> figures(const BundleAdjustmentSummary& s) {
  std::vector<double> v = {s.initial_cost,    s.final_cost,          s.rms_left_px,
                           s.rms_right_px,    s.epipolar_rms_px,     s.residual_sigma_px,
                           s.baseline_stddev_m, s.rotation_stddev_deg};
  for (const PinholeCamera* c : {&s.rig.left, &s.rig.right}) {
    v.insert(v.end(), {c->fx, c->fy, c->cx, c->cy});
    v.insert(v.end(), c->dist.begin(), c->dist.end());
  }
  for (const CameraStddev* c : {&s.left_stddev, &s.right_stddev}) {
    v.insert(v.end(), {c->fx, c->fy, c->cx, c->cy});
    v.insert(v.end(), c->dist.begin(), c->dist.end());
  }
  const Eigen::Matrix4d t = s.rig.right_from_left.matrix();
  v.insert(v.end(), t.data(), t.data() + 16);
  for (const auto& [id, pose] : s.rig_from_board) {
    const Eigen::Matrix4d m = pose.matrix();
    v.insert(v.end(), m.data(), m.data() + 16);
  }
  return v;
}

// Leaves the heap in a different state: chunks of the sizes a solve uses, freed in a shuffled
// order, some kept until the end of the test.
std::vector<std::unique_ptr<char[]>> churnHeap(uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<std::unique_ptr<char[]>> chunks;
  for (int i = 0; i < 2000; ++i) chunks.emplace_back(new char[16 + rng() % 240]);
  std::shuffle(chunks.begin(), chunks.end(), rng);
  std::vector<std::unique_ptr<char[]>> kept;
  for (size_t i = 0; i < chunks.size(); i += 3) kept.push_back(std::move(chunks[i]));
  return kept;  // the others are freed here, in shuffled order
}

TEST(BundleAdjusterRepeatability, SameInputGivesTheSameBitsWhateverTheHeapHistory) {
  const StereoRig truth = makeSimLikeStereoRig();
  const std::vector<VirtualBoard> boards = makeSpreadVirtualBoards(truth.left, {});
  SyntheticObservationOptions o;
  o.frames = 4;
  o.noise_sigma_px = 0.3;
  o.seed = 5;
  const std::vector<StereoObservation> frames = generateSyntheticObservations(truth, boards, o);
  CalibrationInput input;
  input.frames = &frames;
  input.boards = &boards;
  input.image_width = truth.left.width;
  input.image_height = truth.left.height;

  for (const BoardPoseMode mode : {BoardPoseMode::kSharedAcrossFrames, BoardPoseMode::kPerFrame}) {
    BundleAdjustmentOptions options;
    options.board_pose_mode = mode;
    BundleAdjustmentConfig config;
    config.estimate_tangential = true;
    const BundleAdjuster adjuster(options, config);
    const BundleAdjustmentSummary first = adjuster.Solve(input);
    ASSERT_TRUE(first.success) << first.message;
    ASSERT_TRUE(first.covariance_ok);
    const std::vector<double> reference = figures(first);
    for (uint64_t seed : {1, 2, 3, 4}) {
      const auto kept = churnHeap(seed);
      const BundleAdjustmentSummary again = adjuster.Solve(input);
      ASSERT_TRUE(again.success) << again.message;
      const std::vector<double> v = figures(again);
      ASSERT_EQ(v.size(), reference.size());
      int differing = 0;
      for (size_t i = 0; i < v.size(); ++i)
        differing += std::memcmp(&v[i], &reference[i], sizeof(double)) != 0;
      EXPECT_EQ(differing, 0) << "of " << v.size() << " figures differ in their bits after heap "
                              << "pattern " << seed << ", " << first.board_poses
                              << " (fx " << again.rig.left.fx - first.rig.left.fx << " px apart)";
    }
  }
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
