// The default matcher (DisparityOptions{}, whatever algorithm it names) on the moving,
// photographed drive_photo world with a fixed seed, against the simulator's depth truth: light-on
// frames separated by the Separator, whose device image is learned from the light bursts as the
// Separator nodelet learns it (no covered scene, no truth; test_support sim_disparity_eval.h),
// give disparity within a bound (bad > 2 px, invalid counted bad) of the light-off frames around
// them. The light-off frames' own bad rate has a sanity bound, so that a matcher that fails
// everywhere cannot pass the comparison. Rectified with the true calibration: this
// measures the matcher and the separation, not the calibration. bench_disparity_sim prints the
// same comparison for every algorithm.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/test_support/sim_disparity_eval.h"

namespace embedded_calibration_stereo::core {
namespace {

// The gap the Separator may leave: separated lit frames against the light-off frames around
// them, bad > 2 px, percentage points. The goal is 2; the head does not reach it yet
// (docs/depth_quality.md: under the cameras' auto-exposure the first lit frames of a burst
// saturate, and what separation leaves of the boards matches between the cameras), so this
// bound is the measured gap with a margin: it catches a separation or matcher that gets worse.
constexpr double kMaxGapPoints = 10.0;
// Sanity bound of the default matcher's bad > 2 px on the light-off frames, percent: about
// twice the rate measured when it was set (docs/depth_quality.md has the figure), so that a new
// default matcher as good as the old one passes and a broken chain (rectification, truth,
// matcher) does not.
constexpr double kMaxLightOffBadPercent = 5.0;

std::vector<RectifiedSample> ofBurst(const std::vector<RectifiedSample>& samples, int burst) {
  std::vector<RectifiedSample> out;
  for (const RectifiedSample& s : samples)
    if (s.burst == burst) out.push_back(s);
  return out;
}

TEST(DisparityOnSim, SeparatedLitFramesMatchTheLightOffFramesAroundThem) {
  const auto t0 = std::chrono::steady_clock::now();
  SimDisparitySetOptions o;
  o.config_path = std::string(ECS_SOURCE_DIR) + "/config/drive_photo.yaml";
  o.seed = 1;
  o.scored_bursts = 3;
  o.lit_per_burst = 2;
  o.off_per_burst = 2;
  const SimDisparitySet set = renderSimDisparitySet(o);
  for (const std::string& line : set.log) std::printf("  separator %s\n", line.c_str());
  ASSERT_EQ(set.lit.size(), 6u);
  ASSERT_EQ(set.light_off.size(), 6u);

  const DisparityOptions defaults;
  for (int b = 0; b < o.scored_bursts; ++b) {
    const DisparityScore off = scoreMatcher(defaults, ofBurst(set.light_off, b));
    const DisparityScore lit = scoreMatcher(defaults, ofBurst(set.lit, b));
    std::printf("  burst %d: bad>2px light-off %.2f %%, separated lit %.2f %% (%+.2f points)\n", b, off.badPercent(),
                lit.badPercent(), lit.badPercent() - off.badPercent());
  }
  const DisparityScore off = scoreMatcher(defaults, set.light_off);
  const DisparityScore lit = scoreMatcher(defaults, set.lit);
  const double gap = lit.badPercent() - off.badPercent();
  std::printf("  default (%s), %zu frames each: bad>2px light-off %.2f %% (invalid %.2f %%, rms %.3f px), "
              "separated lit %.2f %% (invalid %.2f %%, rms %.3f px): %+.2f points; test time %.1f s\n",
              defaults.algorithm.c_str(), set.lit.size(), off.badPercent(), off.invalidPercent(), off.inlierRmsPx(),
              lit.badPercent(), lit.invalidPercent(), lit.inlierRmsPx(), gap,
              std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  EXPECT_LE(std::abs(gap), kMaxGapPoints);
  EXPECT_LT(off.badPercent(), kMaxLightOffBadPercent);
  EXPECT_GT(off.evaluated, 6 * 300000) << "most pixels have truth (an indoor world)";
}

// The bench's diagnosis of the gap (bench_disparity_sim --ideal, --ideal-clipped): an ideal
// separation leaves only the lit frame's sensor noise, within the 2-point goal; keeping what the
// Separator gives at the clipped pixels puts most of the gap back. It fails if the ideal frames
// are not aligned with the truth, carry too much noise, or are the Separator's output.
TEST(DisparityOnSim, AnIdealSeparationLeavesOnlyTheSensorNoise) {
  SimDisparitySetOptions o;
  o.config_path = std::string(ECS_SOURCE_DIR) + "/config/drive_photo.yaml";
  o.scored_bursts = 2;
  const DisparityOptions defaults;
  const auto gap = [&](SimDisparitySetOptions::Ideal ideal) {
    o.ideal = ideal;
    const SimDisparitySet set = renderSimDisparitySet(o);
    return scoreMatcher(defaults, set.lit).badPercent() - scoreMatcher(defaults, set.light_off).badPercent();
  };
  const double ideal = gap(SimDisparitySetOptions::Ideal::kIdeal);
  const double clipped = gap(SimDisparitySetOptions::Ideal::kIdealClipped);
  const double product = gap(SimDisparitySetOptions::Ideal::kNone);
  std::printf("  lit - light-off, bad>2px: ideal %+.2f, ideal but the clipped pixels %+.2f, the Separator %+.2f points\n",
              ideal, clipped, product);
  EXPECT_LT(std::abs(ideal), 2.0) << "the goal is reachable without the clipped pixels";
  EXPECT_GT(clipped, ideal + 2.0) << "the clipped pixels are most of the gap";
  EXPECT_GT(product, ideal + 2.0);
}

TEST(DisparityOnSim, ScoresCountInvalidAsBadAndSkipPixelsWithoutTruth) {
  cv::Mat truth(1, 4, CV_32F), d(1, 4, CV_32F);
  truth.at<float>(0) = 10.0f;  d.at<float>(0) = 10.5f;              // inlier, error 0.5
  truth.at<float>(1) = 10.0f;  d.at<float>(1) = 13.0f;              // bad
  truth.at<float>(2) = 10.0f;  d.at<float>(2) = kInvalidDisparity;  // invalid, bad
  truth.at<float>(3) = 0.0f;   d.at<float>(3) = 99.0f;              // no truth
  const DisparityScore s = scoreDisparity(d, truth);
  EXPECT_EQ(s.evaluated, 3);
  EXPECT_EQ(s.bad, 2);
  EXPECT_EQ(s.invalid, 1);
  EXPECT_EQ(s.inliers, 1);
  EXPECT_NEAR(s.inlierRmsPx(), 0.5, 1e-6);
  EXPECT_THROW(scoreDisparity(d, cv::Mat(1, 3, CV_32F)), std::invalid_argument);
  const std::vector<std::string> names = acceptedDisparityAlgorithms();
  ASSERT_FALSE(names.empty());
  EXPECT_EQ(names[0], "sad");
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
