// rostest: calibration/health on the simulated head, the rollback of a wrong calibration and
// the on-demand calibration burst after a knock.
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <cmath>

#include "driver_test_utils.h"
#include "health_test_utils.h"
#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationHealth;
using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::carriesCalibration;
using test_support::Collector;
using test_support::lastHealth;
using test_support::latestPair;
using sensor_msgs::CameraInfo;
using Healths = std::vector<CalibrationHealth::ConstPtr>;

namespace {

bool setCameraInfo(const std::string& service, const CameraInfo& info, std::string* message) {
  sensor_msgs::SetCameraInfo srv;
  srv.request.camera_info = info;
  if (!ros::service::call(service, srv)) {
    *message = service + " call failed";
    return false;
  }
  *message = srv.response.status_message;
  return srv.response.success;
}

// GOOD, with both signals measured.
bool goodWithBoth(const Healths& m) {
  return !m.empty() && m.back()->state == CalibrationHealth::GOOD && m.back()->verification_age_s >= 0.0 &&
         m.back()->misalignment_age_s >= 0.0;
}

// What the test watches.
struct Topics {
  Collector<CalibrationHealth>& health;
  Collector<CalibrationStatus>& status;
  Collector<CalibrationMode>& modes;
  Collector<CameraInfo>& left;
  Collector<CameraInfo>& right;
};

void expectGoodUndisturbed(Topics& t, CalibrationHealth* good_out) {
  auto& health = t.health;
  // 1. Undisturbed: GOOD once both signals were measured.
  ASSERT_TRUE(health.waitFor(goodWithBoth, 20.0)) << lastHealth(health);
  const CalibrationHealth& good = *good_out = *health.snapshot().back();
  std::printf("undisturbed: epoch %u GOOD, misalignment %.3f +- %.3f px, board rms %.3f / %.3f px, consistency "
              "%.3f px\n",
              good.epoch, good.misalignment_px, good.misalignment_sd_px, good.board_rms_left_px,
              good.board_rms_right_px, good.stereo_consistency_px);
  EXPECT_TRUE(std::isfinite(good.misalignment_px));
  EXPECT_TRUE(std::isfinite(good.board_rms_left_px));
}

void expectWrongCalibrationRolledBack(Topics& t, const CalibrationHealth& good, uint32_t* restored_out) {
  auto& health = t.health;
  auto& status = t.status;
  auto& modes = t.modes;
  auto& left = t.left;
  auto& right = t.right;
  // 2. A wrong calibration through set_camera_info: the right camera tilted by 0.5 degrees.
  CameraInfo original_left, original_right;
  ASSERT_TRUE(latestPair(left, right, &original_left, &original_right));
  const auto wrong = test_support::tilted(original_left, original_right, 0.5);
  std::string message;
  ASSERT_TRUE(setCameraInfo("left/set_camera_info", wrong.first, &message)) << message;
  ASSERT_TRUE(setCameraInfo("right/set_camera_info", wrong.second, &message)) << message;
  uint32_t wrong_epoch = 0;
  ASSERT_TRUE(modes.waitFor(
      [&](const std::vector<CalibrationMode::ConstPtr>& m) {
        if (m.empty() || m.back()->calibration_epoch == good.epoch) return false;
        wrong_epoch = m.back()->calibration_epoch;
        return true;
      },
      5.0));
  // The verification after it finds it worse and says so.
  ASSERT_TRUE(health.waitFor(
      [&](const Healths& m) {
        return !m.empty() && m.back()->epoch == wrong_epoch && m.back()->state >= CalibrationHealth::DEGRADED &&
               m.back()->verification_age_s >= 0.0;
      },
      6.0))
      << lastHealth(health);
  ASSERT_TRUE(status.waitFor(
      [&](const std::vector<CalibrationStatus::ConstPtr>& m) {
        return !m.empty() && m.back()->epoch == wrong_epoch && !m.back()->accepted &&
               m.back()->outcome == embedded_calibration_stereo::CalibrationStatus::OUTCOME_ROLLED_BACK;
      },
      5.0))
      << lastHealth(health);
  std::printf("rollback status: %s\n", status.snapshot().back()->reason.c_str());
  // The driver publishes the previous calibration again, under a new epoch, which verifies GOOD.
  uint32_t& restored_epoch = *restored_out;
  ASSERT_TRUE(modes.waitFor(
      [&](const std::vector<CalibrationMode::ConstPtr>& m) {
        if (m.empty() || m.back()->calibration_epoch == wrong_epoch || m.back()->calibration_epoch == good.epoch)
          return false;
        restored_epoch = m.back()->calibration_epoch;
        return true;
      },
      8.0));
  CameraInfo now_left, now_right;
  ASSERT_TRUE(left.waitForCount(left.snapshot().size() + 2, 3.0));
  ASSERT_TRUE(latestPair(left, right, &now_left, &now_right));
  EXPECT_TRUE(carriesCalibration(now_left, original_left) && carriesCalibration(now_right, original_right))
      << "the calibration in force is not the one before the wrong one";
  ASSERT_TRUE(health.waitFor(
      [&](const Healths& m) {
        return !m.empty() && m.back()->epoch == restored_epoch && goodWithBoth(m);
      },
      8.0))
      << lastHealth(health);
  // Before its verdict, the health of the restored calibration said why it came back.
  bool said_why = false;
  for (const auto& h : health.snapshot())
    said_why = said_why || (h->epoch == restored_epoch && h->reason.find("restoring the previous one; restored") !=
                                                              std::string::npos);
  EXPECT_TRUE(said_why) << "no health message of the restored epoch says why it was restored";
}

void expectKnockCalibratesOnDemand(Topics& t, uint32_t restored_epoch) {
  auto& health = t.health;
  auto& modes = t.modes;
  // 3. A knock of the right camera (tilt, 0.2 degrees): health leaves GOOD, the calibration in
  //    force stays (nothing was committed), and the driver starts a calibration burst on demand.
  //    First the light off and settled (a burst of the wrong calibration may still be running).
  ASSERT_TRUE(modes.waitFor(
      [](const std::vector<CalibrationMode::ConstPtr>& m) {
        return !m.empty() && !m.back()->light_on && m.back()->settled;
      },
      3.0));
  const size_t modes_before = modes.snapshot().size();
  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.0;
  drift.request.knock_rotation_deg[0] = 0.2;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  const ros::WallTime knocked = ros::WallTime::now();
  ASSERT_TRUE(health.waitFor(
      [&](const Healths& m) { return !m.empty() && m.back()->state >= CalibrationHealth::DEGRADED; }, 4.0))
      << lastHealth(health);
  const CalibrationHealth knock = *health.snapshot().back();
  std::printf("knock 0.2 deg about x: %s after %.2f s, misalignment %.3f px (%s)\n", test_support::healthStateName(knock.state),
              (ros::WallTime::now() - knocked).toSec(), knock.misalignment_px, knock.reason.c_str());
  EXPECT_EQ(knock.epoch, restored_epoch) << "a knock is no new calibration: nothing to roll back";
  // A calibration burst: more settled light-on frames in a row than a verification flash has
  // (one). The driver's default burst is 0.33 s, 5 frames at this test's 15 fps.
  EXPECT_TRUE(modes.waitFor(
      [&](const std::vector<CalibrationMode::ConstPtr>& m) {
        int run = 0;
        for (size_t i = modes_before; i < m.size(); ++i) {
          run = m[i]->light_on && m[i]->settled ? run + 1 : 0;
          if (run >= 4) return true;
        }
        return false;
      },
      5.0))
      << "no calibration burst after the health left GOOD";
}

}  // namespace

TEST(CalibrationHealth, GoodWrongCalibrationRolledBackKnockCalibratesOnDemand) {
  ros::NodeHandle nh;
  Collector<CalibrationHealth> health(nh, "calibration/health", 1000);
  Collector<CalibrationStatus> status(nh, "calibration/status");
  Collector<CalibrationMode> modes(nh, "calibration_mode", 2000);
  Collector<CameraInfo> left(nh, "left/camera_info", 50), right(nh, "right/camera_info", 50);
  ASSERT_TRUE(ros::service::waitForService("left/set_camera_info", 20000));

  Topics topics{health, status, modes, left, right};
  CalibrationHealth good;
  expectGoodUndisturbed(topics, &good);
  if (HasFatalFailure()) return;
  uint32_t restored_epoch = 0;
  expectWrongCalibrationRolledBack(topics, good, &restored_epoch);
  if (HasFatalFailure()) return;
  expectKnockCalibratesOnDemand(topics, restored_epoch);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibration_health_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
