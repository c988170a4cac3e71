// rostest: an acceptable calibration that the driver refuses to store (right set_camera_info
// fails) is not committed: status accepted = false naming the service, the left calibration
// (only staged by the driver) never comes into force, no /tf_static update (beyond the
// calibration in force sent at start).
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <tf2_msgs/TFMessage.h>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/SetRigDrift.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::Recalibrate;
using test_support::Collector;
using sensor_msgs::CameraInfo;

TEST(CalibratorCommitFailure, RefusedSetCameraInfoLeavesTheStatusNotCommitted) {
  ros::NodeHandle nh;
  Collector<CalibrationMode> modes(nh, "calibration_mode");
  Collector<CameraInfo> left(nh, "left/camera_info"), right(nh, "right/camera_info");
  Collector<CalibrationStatus> status(nh, "calibration/status");
  Collector<tf2_msgs::TFMessage> tf_static(nh, "/tf_static");
  ASSERT_TRUE(ros::service::waitForService("calibration/recalibrate", 20000));
  ASSERT_TRUE(left.waitForCount(1, 20.0));
  ASSERT_TRUE(right.waitForCount(1, 5.0));
  const CameraInfo left_before = *left.snapshot().back();
  const CameraInfo right_before = *right.snapshot().back();
  // The calibration in force goes on /tf_static once, at start (latched); nothing after it.
  ASSERT_TRUE(tf_static.waitForCount(1, 5.0)) << "no /tf_static of the calibration in force";
  const size_t tf_before = tf_static.snapshot().size();

  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.05;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  ASSERT_TRUE(modes.waitForCount(modes.snapshot().size() + 2, 5.0));

  Recalibrate srv;
  srv.request.frames = 10;
  srv.request.timeout_s = 3.0;
  ASSERT_TRUE(ros::service::call("calibration/recalibrate", srv));
  std::printf("answer: %s\n", srv.response.message.c_str());
  EXPECT_FALSE(srv.response.success);
  EXPECT_FALSE(srv.response.status.accepted);
  EXPECT_NE(srv.response.status.reason.find("not committed"), std::string::npos) << srv.response.status.reason;
  EXPECT_NE(srv.response.status.reason.find("right/set_camera_info"), std::string::npos) << srv.response.status.reason;
  // The driver only staged the left calibration (its P does not match the right one in force)
  // and dropped it when the right one could not be stored: nothing to restore.
  EXPECT_NE(srv.response.status.reason.find("the driver kept the calibration in force"), std::string::npos)
      << srv.response.status.reason;
  // The solve itself was good: the drifted focal length was found.
  ASSERT_EQ(srv.response.status.left_intrinsics.size(), 9u);
  EXPECT_NEAR(srv.response.status.left_intrinsics[0] / left_before.K[0], 1.05, 1e-3);
  ASSERT_TRUE(status.waitForCount(1, 2.0));
  EXPECT_FALSE(status.snapshot().back()->accepted);

  // A few frames later the driver still publishes the calibration it had.
  ASSERT_TRUE(modes.waitForCount(modes.snapshot().size() + 3, 5.0));
  EXPECT_EQ(left.snapshot().back()->K, left_before.K);
  EXPECT_EQ(left.snapshot().back()->P, left_before.P);
  EXPECT_EQ(right.snapshot().back()->K, right_before.K);
  EXPECT_EQ(tf_static.snapshot().size(), tf_before) << "a transform was broadcast for an uncommitted calibration";
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibrator_commit_failure_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
