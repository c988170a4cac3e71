// rostest: the calibration verified GOOD survives restarts (calibration_verified_restart.test).
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <fstream>

#include "calibration_test_utils.h"
#include "driver_test_utils.h"
#include "health_test_utils.h"
#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/VerifiedCalibration.h"
#include "embedded_calibration_stereo/ros/calibration_file.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationHealth;
using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::carriesCalibration;
using embedded_calibration_stereo::VerifiedCalibration;
using test_support::Collector;
using test_support::lastHealth;
using sensor_msgs::CameraInfo;
using Pair = std::pair<CameraInfo, CameraInfo>;

namespace {

constexpr const char* kHealthType = "embedded_calibration_stereo/CalibrationHealth";

bool carries(const Pair& published, const Pair& expected) {
  return carriesCalibration(published.first, expected.first) && carriesCalibration(published.second, expected.second);
}

class Head {
 public:
  explicit Head(const std::string& dir) : dir_(dir) {}
  ~Head() { stop(); }
  bool startDriver() {
    return manager_.load("/stereo/camera_driver", {{"backend", "sim"},
                                                   {"fps", 15.0},
                                                   {"settle_frames", 2},
                                                   {"calibration_period_s", 0.0},
                                                   {"calibration_trigger", "on_demand"},
                                                   {"min_calibration_interval_s", 1.0},
                                                   {"verification_period_s", 2.0},
                                                   {"left_camera_info_url", "file://" + dir_ + "/left.yaml"},
                                                   {"right_camera_info_url", "file://" + dir_ + "/right.yaml"}});
  }
  bool startHealth() {
    return manager_.load("/stereo/calibration_health", {}, kHealthType,
                         {{"/stereo/calibration/observations", "/stereo/ground_truth/observations"}});
  }
  void stopHealth() { manager_.unload("/stereo/calibration_health"); }
  void stop() {
    stopHealth();
    manager_.unload("/stereo/camera_driver");
  }

 private:
  std::string dir_;
  test_support::InProcessManager manager_;
};

// The pair the driver publishes now (the newest common stamp).
Pair published(Collector<CameraInfo>& left, Collector<CameraInfo>& right) {
  Pair pair;
  EXPECT_TRUE(left.waitForCount(left.snapshot().size() + 2, 5.0));
  EXPECT_TRUE(test_support::latestPair(left, right, &pair.first, &pair.second));
  return pair;
}

}  // namespace

TEST(CalibrationVerifiedRestart, TheCalibrationVerifiedGoodIsKeptAcrossRestarts) {
  ros::NodeHandle nh("/stereo");
  const test_support::TempDir temp("ecs_verified_restart");
  ASSERT_FALSE(temp.path.empty());
  Collector<CalibrationHealth> health(nh, "calibration/health", 3000);
  Collector<CalibrationStatus> status(nh, "calibration/status");
  Collector<CalibrationMode> modes(nh, "calibration_mode", 3000);
  Collector<CameraInfo> left(nh, "left/camera_info", 50), right(nh, "right/camera_info", 50);
  Collector<VerifiedCalibration> verified(nh, "calibration/verified");

  // 1. A stored calibration (the nominal one, written), verified GOOD: marked on disk.
  Head head(temp.path);
  ASSERT_TRUE(head.startDriver());
  ASSERT_TRUE(head.startHealth());
  ASSERT_TRUE(modes.waitForCount(2, 20.0));
  const Pair good = published(left, right);
  test_support::setPair(good, "/stereo/");
  ASSERT_TRUE(verified.waitFor(
      [&](const auto& m) { return !m.empty() && carries({m.back()->left, m.back()->right}, good); }, 30.0))
      << "the stored calibration was not marked verified: " << lastHealth(health);
  const unsigned good_generation = verified.snapshot().back()->generation;
  std::printf("verified GOOD: generation %u\n", good_generation);

  // 2. The health stops; a wrong calibration (right camera tilted 0.5 degrees) is committed.
  head.stopHealth();
  const Pair wrong = test_support::tilted(good.first, good.second, 0.5);
  std::string error;
  test_support::setPair(wrong, "/stereo/");
  ASSERT_TRUE(carries(published(left, right), wrong));
  head.stop();

  // 3. Restart: the driver starts on the wrong calibration (its files); the health, fresh, tests
  //    it against the one verified before the restart and restores that one.
  status.clear();
  ASSERT_TRUE(head.startDriver());
  ASSERT_TRUE(head.startHealth());
  ASSERT_TRUE(status.waitFor(
      [](const auto& m) {
        return !m.empty() && m.back()->outcome == embedded_calibration_stereo::CalibrationStatus::OUTCOME_ROLLED_BACK &&
               m.back()->reason.find("verified before the restart") != std::string::npos;
      },
      40.0))
      << lastHealth(health);
  std::printf("after the restart: %s\n", status.snapshot().back()->reason.c_str());
  ASSERT_TRUE(left.waitFor([&](const auto& m) { return carriesCalibration(*m.back(), good.first); }, 10.0))
      << "the calibration verified before the restart is not back in force";
  EXPECT_TRUE(carries(published(left, right), good));
  head.stop();

  // 4. The files rejected at start-up (the left one's cy' moved 100000 px, written through its
  //    link into the current generation): the newest verified generation runs, not the newer
  //    unverified wrong one.
  CameraInfo far = wrong.first;
  far.P[6] += 100000;
  ASSERT_TRUE(embedded_calibration_stereo::writeCalibrationFileAtomic(temp.path + "/far.yaml", "stereo_left", far,
                                                                      &error))
      << error;
  { std::ofstream(temp.path + "/left.yaml", std::ios::trunc) << test_support::fileBytes(temp.path + "/far.yaml"); }
  left.clear();
  right.clear();
  ASSERT_TRUE(head.startDriver());
  ASSERT_TRUE(left.waitForCount(3, 20.0));
  const Pair running = published(left, right);
  EXPECT_TRUE(carries(running, good)) << "not the calibration verified GOOD";
  EXPECT_FALSE(carries(running, wrong));
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibration_verified_restart_test");
  ros::AsyncSpinner spinner(3);
  spinner.start();
  return RUN_ALL_TESTS();
}
