// DepthCoverageWatch (the health's watch on valid disparity): collapses found against the
// medians computed here by sorting the fractions fed (an independent brute force), and the
// cases that must not count (a slow change of scene, a view with little depth, a rebase).
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/depth_coverage_watch.h"

namespace core = embedded_calibration_stereo::core;

namespace {

constexpr double kFps = 15.0;

double sortedMedian(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  return values[values.size() / 2];
}

// Feeds fraction(t) from t0 to t1 at kFps with +-0.03 uniform noise; returns what was fed.
template <class F>
std::vector<double> feed(core::DepthCoverageWatch* watch, double t0, double t1, F fraction, std::mt19937* rng) {
  std::uniform_real_distribution<double> noise(-0.03, 0.03);
  std::vector<double> fed;
  for (double t = t0; t < t1 - 1e-9; t += 1.0 / kFps) {
    const double f = std::clamp(fraction(t) + noise(*rng), 0.0, 1.0);
    watch->add(t, f);
    fed.push_back(f);
  }
  return fed;
}

}  // namespace

TEST(DepthCoverageWatch, ACollapseIsSeenWithinTheRecentSpanAgainstTheMedianBefore) {
  std::mt19937 rng(1);
  core::DepthCoverageWatch watch{core::DepthCoverageWatchOptions{}};
  const std::vector<double> before = feed(&watch, 0.0, 40.0, [](double) { return 0.6; }, &rng);
  EXPECT_FALSE(watch.collapse());
  // Depth empties (a calibration whose rectified images left the view).
  feed(&watch, 40.0, 40.6, [](double) { return 0.02; }, &rng);
  EXPECT_FALSE(watch.collapse()) << "less than half the recent span is low yet";
  const std::vector<double> after = feed(&watch, 40.6, 42.5, [](double) { return 0.02; }, &rng);
  const auto collapse = watch.collapse();
  ASSERT_TRUE(collapse);
  // The reference: the level before (plus the few low fractions of the second before the
  // collapse was seen, which move the median of 600 by a few thousandths).
  EXPECT_NEAR(collapse->reference, sortedMedian(before), 0.005);
  EXPECT_NEAR(collapse->recent, 0.02, 0.03);
  EXPECT_NE(collapse->text().find("against 6"), std::string::npos) << collapse->text();
}

TEST(DepthCoverageWatch, ACollapseLastsUntilDepthRecoversHoweverLong) {
  std::mt19937 rng(2);
  core::DepthCoverageWatch watch{core::DepthCoverageWatchOptions{}};
  feed(&watch, 0.0, 30.0, [](double) { return 0.5; }, &rng);
  feed(&watch, 30.0, 300.0, [](double) { return 0.1; }, &rng);  // far longer than history_s
  ASSERT_TRUE(watch.collapse()) << "a collapse must not be learned as the new normal";
  EXPECT_NEAR(watch.collapse()->reference, 0.5, 0.03);
  feed(&watch, 300.0, 303.0, [](double) { return 0.5; }, &rng);
  EXPECT_FALSE(watch.collapse());
}

TEST(DepthCoverageWatch, ASlowChangeOfSceneIsNoCollapse) {
  // From 60 % to 15 % over four minutes (driving into a bare corridor): the history follows.
  std::mt19937 rng(3);
  core::DepthCoverageWatch watch{core::DepthCoverageWatchOptions{}};
  bool seen = false;
  std::uniform_real_distribution<double> noise(-0.03, 0.03);
  for (double t = 0.0; t < 240.0; t += 1.0 / kFps) {
    watch.add(t, 0.6 - 0.45 * t / 240.0 + noise(rng));
    seen = seen || watch.collapse().has_value();
  }
  EXPECT_FALSE(seen);
}

TEST(DepthCoverageWatch, NoVerdictOnAShortHistoryOrAViewWithLittleDepth) {
  std::mt19937 rng(4);
  core::DepthCoverageWatch young{core::DepthCoverageWatchOptions{}};
  feed(&young, 0.0, 5.0, [](double) { return 0.6; }, &rng);
  feed(&young, 5.0, 8.0, [](double) { return 0.0; }, &rng);  // history of 8 s: less than min_history_s
  EXPECT_FALSE(young.collapse());

  core::DepthCoverageWatch dim{core::DepthCoverageWatchOptions{}};
  feed(&dim, 0.0, 30.0, [](double) { return 0.04; }, &rng);  // below min_reference: the sky
  feed(&dim, 30.0, 33.0, [](double) { return 0.0; }, &rng);
  EXPECT_FALSE(dim.collapse());
}

TEST(DepthCoverageWatch, ARebaseAcceptsTheLevelOfNow) {
  std::mt19937 rng(5);
  core::DepthCoverageWatch watch{core::DepthCoverageWatchOptions{}};
  feed(&watch, 0.0, 30.0, [](double) { return 0.6; }, &rng);
  feed(&watch, 30.0, 33.0, [](double) { return 0.2; }, &rng);
  ASSERT_TRUE(watch.collapse());
  watch.rebase();  // the calibrator confirmed the calibration: the scene changed
  feed(&watch, 33.0, 60.0, [](double) { return 0.2; }, &rng);
  EXPECT_FALSE(watch.collapse());
  feed(&watch, 60.0, 63.0, [](double) { return 0.05; }, &rng);
  ASSERT_TRUE(watch.collapse()) << "the new level is the reference now";
  EXPECT_NEAR(watch.collapse()->reference, 0.2, 0.03);
}

TEST(DepthCoverageWatch, TimeGoingBackStartsAgain) {
  std::mt19937 rng(6);
  core::DepthCoverageWatch watch{core::DepthCoverageWatchOptions{}};
  feed(&watch, 100.0, 130.0, [](double) { return 0.6; }, &rng);
  feed(&watch, 0.0, 3.0, [](double) { return 0.1; }, &rng);  // a bag played again
  EXPECT_FALSE(watch.collapse());
}

TEST(DepthCoverageWatch, OptionsAreChecked) {
  core::DepthCoverageWatchOptions o;
  EXPECT_EQ(o.validate(), "");
  o.collapse_ratio = 1.0;
  EXPECT_NE(o.validate().find("collapse_ratio"), std::string::npos);
  o = {};
  o.history_s = o.recent_s;
  EXPECT_NE(o.validate().find("history_s"), std::string::npos);
  EXPECT_THROW(core::DepthCoverageWatch{o}, std::invalid_argument);
}
