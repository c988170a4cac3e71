// rostest: the PatternTracker's window tracking on the sim driver (tracker_window.test). Every
// window observation must be stamped with the last settled light-on frame of a calibration burst
// (at least 3 settled light-on frames, then light-off), never with a verification flash's frame,
// and its corners must agree with the simulator's ground truth of that frame (noise-free); the
// per-frame observations must still come for every settled light-on frame, flashes included.
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <set>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::BoardObservation;
using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;

namespace {

bool calibrating(const CalibrationMode& m) { return m.light_on && m.settled; }

// The settled light-on frames of each burst, split at settled light-off frames, in order.
std::vector<std::vector<ros::Time>> bursts(const std::vector<CalibrationMode::ConstPtr>& modes) {
  std::vector<std::vector<ros::Time>> out;
  std::vector<ros::Time> lit;
  for (const auto& m : modes) {
    if (calibrating(*m)) {
      lit.push_back(m->header.stamp);
    } else if (m->settled && !m->light_on) {
      if (!lit.empty()) out.push_back(lit);
      lit.clear();
    }
  }
  return out;  // a burst still lit is left out
}

double cornerRms(const std::vector<BoardObservation>& found, const std::vector<BoardObservation>& truth,
                 size_t* matched, size_t* expected) {
  std::map<std::pair<int, int>, std::pair<float, float>> at;
  for (const auto& b : truth)
    for (size_t i = 0; i < b.corner_ids.size(); ++i) at[{b.board_id, b.corner_ids[i]}] = {b.u[i], b.v[i]};
  *expected += at.size();
  double squared = 0.0;
  for (const auto& b : found)
    for (size_t i = 0; i < b.corner_ids.size(); ++i) {
      const auto it = at.find({b.board_id, b.corner_ids[i]});
      if (it == at.end()) continue;
      ++*matched;
      squared += std::pow(b.u[i] - it->second.first, 2) + std::pow(b.v[i] - it->second.second, 2);
    }
  return squared;
}

}  // namespace

TEST(TrackerWindow, OneObservationPerBurstStampedWithItsLastLitFrameAndNoneForAFlash) {
  ros::NodeHandle nh;
  Collector<CalibrationMode> modes(nh, "calibration_mode", 2000);
  Collector<StereoPatternObservation> windows(nh, "calibration/window_observations", 100);
  Collector<StereoPatternObservation> observations(nh, "calibration/observations", 2000);
  Collector<StereoPatternObservation> truth(nh, "ground_truth/observations", 2000);
  // Teaching takes the first burst; each later one is tracked in seconds.
  ASSERT_TRUE(windows.waitForCount(3, 40.0)) << "fewer than 3 window observations in 40 s";

  const auto seen = modes.snapshot();
  const auto all = bursts(seen);
  std::map<ros::Time, size_t> burst_of_last;  // the last lit frame of each burst -> its frame count
  size_t flashes = 0;
  for (const auto& b : all) {
    burst_of_last[b.back()] = b.size();
    flashes += b.size() == 1;
  }
  EXPECT_GE(flashes, 2u) << "the driver made no verification flashes: the test proves nothing about them";

  std::map<ros::Time, StereoPatternObservation::ConstPtr> truth_of;
  for (const auto& t : truth.snapshot()) truth_of[t->header.stamp] = t;
  size_t matched = 0, expected = 0;
  double squared = 0.0;
  for (const auto& w : windows.snapshot()) {
    const auto burst = burst_of_last.find(w->header.stamp);
    ASSERT_NE(burst, burst_of_last.end()) << "window observation " << w->header.stamp
                                          << " is not stamped with a burst's last settled light-on frame";
    EXPECT_GE(burst->second, 3u) << "a window observation for a burst of " << burst->second << " frames";
    const auto t = truth_of.find(w->header.stamp);
    ASSERT_NE(t, truth_of.end()) << "no ground truth of frame " << w->header.stamp;
    squared += cornerRms(w->left, t->second->left, &matched, &expected);
    squared += cornerRms(w->right, t->second->right, &matched, &expected);
  }
  const double rms = matched ? std::sqrt(squared / matched) : 0.0;
  std::printf("tracker_window: %zu window observations for %zu bursts (%zu flashes): %zu of %zu visible corners, "
              "RMS %.4f px against the ground truth\n",
              windows.snapshot().size(), all.size(), flashes, matched, expected, rms);
  EXPECT_GE(matched, expected * 95 / 100);
  EXPECT_LE(rms, 0.05);

  // Per-frame observations as without window tracking: one for every settled light-on frame
  // once the tracker was taught (on the first burst: from its first per-frame observation on),
  // flashes included.
  std::set<ros::Time> per_frame;
  for (const auto& o : observations.snapshot()) per_frame.insert(o->header.stamp);
  ASSERT_FALSE(per_frame.empty()) << "no per-frame observation";
  const ros::Time from = *per_frame.begin();
  size_t missing = 0, lit = 0;
  for (const auto& b : all)
    for (const ros::Time& t : b)
      if (t > from && t < windows.snapshot().back()->header.stamp) {
        ++lit;
        missing += !per_frame.count(t);
      }
  EXPECT_GE(lit, 6u);
  EXPECT_EQ(missing, 0u) << "settled light-on frames without a per-frame observation";
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "tracker_window_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
