// rostest (cold_start.test): the head started from a nominal description only (its cameras,
// stereo extrinsics and board placement off the simulated truth by manufacturing tolerances),
// with no calibration file and no tracker prior, teaches its tracker, calibrates itself and
// publishes a calibration within the accuracy targets against the simulator's truth:
// misalignment and disparity bias <= 0.05 px RMS, depth error at 10 m <= 0.7 %, fx <= 0.05 %,
// baseline <= 0.1 %. The truth only scores: the graph is the product's demo.launch.
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "child_launch.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationStatus;
using test_support::ChildLaunch;
using test_support::Collector;
using sensor_msgs::CameraInfo;

namespace {

constexpr int kSeed = 1;
constexpr double kWithinTimeoutS = 60.0;  // of the graph's running time, from its first frame

struct Scores {
  double misalignment_px = 0, bias_px = 0, depth_10m_pct = 0, fx_pct = 0, baseline_pct = 0;
  bool within() const {
    return misalignment_px <= 0.05 && bias_px <= 0.05 && depth_10m_pct <= 0.7 && fx_pct <= 0.05 &&
           baseline_pct <= 0.1;
  }
  std::string text() const {
    char s[200];
    std::snprintf(s, sizeof(s), "misalignment %.4f px, bias %.4f px, depth error at 10 m %.3f %%, fx %.4f %%, "
                  "baseline %.4f %%", misalignment_px, bias_px, depth_10m_pct, fx_pct, baseline_pct);
    return s;
  }
};

// The published calibration (the newest left/right camera_info pair) against the truth's.
bool score(Collector<CameraInfo>& left, Collector<CameraInfo>& right, Collector<CameraInfo>& truth_left,
           Collector<CameraInfo>& truth_right, Scores* out) {
  CameraInfo l, r, tl, tr;
  if (!test_support::latestPair(left, right, &l, &r) || !test_support::latestPair(truth_left, truth_right, &tl, &tr))
    return false;
  core::StereoRig published, truth;
  std::string error;
  if (!embedded_calibration_stereo::fromStereoCameraInfo(l, r, &published, &error) ||
      !embedded_calibration_stereo::fromStereoCameraInfo(tl, tr, &truth, &error))
    return false;
  const core::StereoAccuracyOptions options;
  const core::StereoAccuracy a = core::evaluateStereoAccuracy(published, truth, options);
  const auto at_10m = std::find(options.depths_m.begin(), options.depths_m.end(), 10.0);
  if (at_10m == options.depths_m.end()) return false;
  out->misalignment_px = a.misalignment_px.rms;
  out->bias_px = a.disparity_bias_px.rms;
  out->depth_10m_pct = a.at_depth[at_10m - options.depths_m.begin()].depth_error_pct.rms;
  out->fx_pct = 100.0 * std::max(std::abs(published.left.fx / truth.left.fx - 1.0),
                                 std::abs(published.right.fx / truth.right.fx - 1.0));
  out->baseline_pct = 100.0 * std::abs(published.baseline() / truth.baseline() - 1.0);
  return true;
}

}  // namespace

TEST(ColdStart, FromANominalDescriptionTheHeadCalibratesItselfWithinTheTargets) {
  ros::NodeHandle nh;
  test_support::TempDir dir("ecs_cold_start_test");
  ASSERT_FALSE(dir.path.empty());
  const std::string source = ECS_SOURCE_DIR;
  const std::string nominal = dir.path + "/nominal_device.yaml";
  const std::string perturb = "/usr/bin/python3 " + source + "/scripts/perturb_device.py " + source +
                              "/config/drive_photo.yaml " + nominal + " --seed " + std::to_string(kSeed) +
                              " > " + dir.path + "/perturb.log 2>&1";
  ASSERT_EQ(std::system(perturb.c_str()), 0) << perturb;

  Collector<CameraInfo> left(nh, "left/camera_info", 20), right(nh, "right/camera_info", 20);
  Collector<CameraInfo> truth_left(nh, "ground_truth/left/camera_info", 20);
  Collector<CameraInfo> truth_right(nh, "ground_truth/right/camera_info", 20);
  Collector<CalibrationStatus> statuses(nh, "calibration/status", 50);
  ChildLaunch head({source + "/launch/demo.launch", "calibration_dir:=" + dir.path, "device_config:=" + nominal},
                   dir.path + "/head.log");
  ASSERT_TRUE(head.started());
  ASSERT_TRUE(left.waitForCount(1, 30.0) && truth_right.waitForCount(1, 10.0)) << "no camera_info\n"
                                                                              << head.logTail();
  const ros::WallTime start = ros::WallTime::now();
  Scores first;
  // The four camera_info topics connect one by one: until a left/right pair of one stamp (of
  // both the head and the truth) has arrived there is nothing to score.
  const auto scored_now = [&](Scores* out) { return score(left, right, truth_left, truth_right, out); };
  ASSERT_TRUE(test_support::waitUntil([&] { return scored_now(&first); }, 5.0))
      << "no left/right camera_info pair of one stamp, of the head and of the truth";
  std::printf("start (the nominal description): %s\n", first.text().c_str());
  ASSERT_FALSE(first.within()) << "the nominal description is already within the targets: no cold start";

  // Each accepted calibration is scored once the cameras publish it; the test ends at the first
  // within the targets.
  size_t scored = 0;
  Scores now;
  bool within = false;
  while (!within && (ros::WallTime::now() - start).toSec() < kWithinTimeoutS) {
    const double left_s = kWithinTimeoutS - (ros::WallTime::now() - start).toSec();
    if (!statuses.waitFor([scored](const auto& m) {
          size_t accepted = 0;
          for (const auto& s : m) accepted += s->accepted ? 1 : 0;
          return accepted > scored;
        }, std::max(0.1, left_s)))
      break;
    ++scored;
    // The commit reaches the cameras' camera_info within a frame or two.
    const ros::Time committed = statuses.snapshot().back()->header.stamp;
    left.waitFor([&](const auto& m) { return m.back()->header.stamp > committed + ros::Duration(0.2); }, 3.0);
    ASSERT_TRUE(test_support::waitUntil([&] { return scored_now(&now); }, 5.0));
    within = now.within();
    std::printf("%.1f s: calibration %zu accepted: %s%s\n", (ros::WallTime::now() - start).toSec(), scored,
                now.text().c_str(), within ? " (within the targets)" : "");
  }
  EXPECT_GE(scored, 1u) << "no calibration accepted in " << kWithinTimeoutS << " s\n" << head.logTail();
  EXPECT_TRUE(within) << "last: " << now.text() << "\n" << head.logTail();
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "cold_start");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
