// rostest: a chain of commits faster than verifications (calibration_health_chain.test). Two
// wrong calibrations (the right camera tilted 0.5, then 0.8 degrees) are sent to set_camera_info,
// the second as soon as the driver publishes the first: it replaces the first before, or just
// after, the first one's verification. Once, the second was judged against the first (no
// verdict: nothing to judge it against; BAD: "no worse"), stayed in force and the health stayed
// BAD. Now the second is judged against the last calibration verified GOOD (the first one is no
// reference: unverified, or rejected), found worse, and that one is restored and verified GOOD.
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <cmath>
#include <cstdio>

#include "driver_test_utils.h"
#include "health_test_utils.h"
#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationHealth;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::carriesCalibration;
using test_support::Collector;
using test_support::lastHealth;
using test_support::setPair;
using test_support::tilted;
using test_support::latestPair;
using sensor_msgs::CameraInfo;
using Healths = std::vector<CalibrationHealth::ConstPtr>;

namespace {

}  // namespace

TEST(CalibrationHealthChain, TheLastCalibrationVerifiedGoodIsRestoredNotTheUnverifiedOneInBetween) {
  ros::NodeHandle nh;
  Collector<CalibrationHealth> health(nh, "calibration/health", 1000);
  Collector<CalibrationStatus> status(nh, "calibration/status");
  Collector<CameraInfo> left(nh, "left/camera_info", 50), right(nh, "right/camera_info", 50);
  ASSERT_TRUE(ros::service::waitForService("left/set_camera_info", 20000));
  const auto verified_good = [](const Healths& m) {
    return !m.empty() && m.back()->state == CalibrationHealth::GOOD && m.back()->verification_age_s >= 0.0;
  };
  ASSERT_TRUE(health.waitFor(verified_good, 20.0)) << lastHealth(health);
  CameraInfo good_left, good_right;
  ASSERT_TRUE(latestPair(left, right, &good_left, &good_right));

  // The first wrong calibration; the second as soon as frames carry the first (its verification
  // flash starts with them).
  const auto first = tilted(good_left, good_right, 0.5), second = tilted(good_left, good_right, 0.8);
  setPair(first);
  ASSERT_TRUE(left.waitFor(
      [&](const std::vector<CameraInfo::ConstPtr>& m) { return !m.empty() && carriesCalibration(*m.back(), first.first); },
      5.0));
  setPair(second);
  ASSERT_TRUE(left.waitFor(
      [&](const std::vector<CameraInfo::ConstPtr>& m) { return !m.empty() && carriesCalibration(*m.back(), second.first); },
      5.0));
  // The second one is found worse than the last one verified GOOD and rolled back to it.
  ASSERT_TRUE(status.waitFor(
      [&](const std::vector<CalibrationStatus::ConstPtr>& m) {
        return !m.empty() && m.back()->outcome == embedded_calibration_stereo::CalibrationStatus::OUTCOME_ROLLED_BACK;
      },
      10.0))
      << "no rollback; " << lastHealth(health);
  std::printf("rollback status: %s\n", status.snapshot().back()->reason.c_str());
  EXPECT_NE(status.snapshot().back()->reason.find("(epoch 0) was GOOD"), std::string::npos)
      << "not judged against the calibration verified GOOD before the chain";
  ASSERT_TRUE(left.waitFor(
      [&](const std::vector<CameraInfo::ConstPtr>& m) { return !m.empty() && carriesCalibration(*m.back(), good_left); },
      8.0))
      << "the calibration in force is not the one verified GOOD before the chain";
  CameraInfo now_left, now_right;
  ASSERT_TRUE(left.waitForCount(left.snapshot().size() + 2, 3.0));
  ASSERT_TRUE(latestPair(left, right, &now_left, &now_right));
  EXPECT_TRUE(carriesCalibration(now_right, good_right));
  const uint32_t restored_epoch = health.snapshot().back()->epoch;
  ASSERT_TRUE(health.waitFor(
      [&](const Healths& m) { return verified_good(m) && m.back()->epoch >= restored_epoch; }, 8.0))
      << lastHealth(health);
  std::printf("restored and verified GOOD: %s\n", lastHealth(health).c_str());
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibration_health_chain_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
