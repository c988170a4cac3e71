// rostest: an accepted calibration the driver could not store is committed again once it can
// be (calibrator_commit_retry.test). The right calibration file's directory is a regular file
// (as a full disk, every write fails; unlike one, this works for root and any file system):
//  - a recalibration of a drifted rig is accepted by the gate but not committed, and the
//    driver keeps publishing the calibration in force;
//  - once the blocking file is gone, the calibrator commits it again within commit_retry_s
//    (2 s here) and the service timeouts: an accepted status is published, the driver publishes
//    the new calibration on both sides with the epoch of that status, and both files exist
//    and carry it (read with camera_calibration_parsers).
#include <camera_calibration_parsers/parse.h>
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>

#include <filesystem>
#include <fstream>

#include "calibrator_test_utils.h"
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

TEST(CalibratorCommitRetry, AnAcceptedCalibrationNotStoredIsCommittedOnceTheDriverCanStoreIt) {
  ros::NodeHandle nh;
  std::string dir;
  ASSERT_TRUE(ros::param::get("~calibration_dir", dir));
  std::filesystem::create_directories(dir);
  const std::string blocker = dir + "/blocked";
  std::ofstream(blocker) << "a file where the right calibration's directory should be\n";

  Collector<CalibrationMode> modes(nh, "calibration_mode", 5000);
  Collector<CameraInfo> left(nh, "left/camera_info", 5000), right(nh, "right/camera_info", 5000);
  Collector<CalibrationStatus> status(nh, "calibration/status");
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 1000);
  ASSERT_TRUE(ros::service::waitForService("calibration/recalibrate", 20000));
  ASSERT_TRUE(modes.waitForCount(2, 20.0));
  ASSERT_TRUE(right.waitForCount(1, 5.0));
  const CameraInfo right_before = *right.snapshot().back();
  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.03;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  ASSERT_TRUE(modes.waitForCount(modes.snapshot().size() + 2, 5.0));

  Recalibrate srv;
  srv.request.frames = 10;
  srv.request.timeout_s = 4.0;
  ASSERT_TRUE(ros::service::call("calibration/recalibrate", srv));
  std::printf("recalibrate: %s: %s\n", srv.response.success ? "success" : "false", srv.response.message.c_str());
  ASSERT_FALSE(srv.response.success);
  ASSERT_NE(srv.response.message.find("not committed"), std::string::npos) << srv.response.message;
  ASSERT_NE(srv.response.message.find("right/set_camera_info"), std::string::npos) << srv.response.message;
  // Tried again and refused again while blocked: the driver publishes the calibration in force.
  std::string found;
  ASSERT_TRUE(test_support::waitForLog(log, {"still not committed", "right/set_camera_info"}, 10.0, &found));
  std::printf("logged: %s\n", found.c_str());
  ASSERT_TRUE(modes.waitForCount(modes.snapshot().size() + 2, 5.0));
  EXPECT_EQ(right.snapshot().back()->K, right_before.K);
  for (const auto& s : status.snapshot()) EXPECT_FALSE(s->accepted) << "committed while the disk was full";

  std::filesystem::remove(blocker);
  const ros::WallTime freed = ros::WallTime::now();
  ASSERT_TRUE(status.waitFor([](const auto& m) { return !m.empty() && m.back()->accepted; }, 2.0 + 4 * 2.0 + 3.0))
      << "the calibration was not committed again after the space was freed";
  const CalibrationStatus committed = *status.snapshot().back();
  std::printf("committed %.1f s after the space was freed, epoch %u\n", (ros::WallTime::now() - freed).toSec(),
              committed.epoch);
  EXPECT_TRUE(test_support::waitForLog(log, {"committed now"}, 5.0, &found));
  std::printf("logged: %s\n", found.c_str());
  // The driver publishes it, under the epoch the status reports.
  const std::optional<uint32_t> published = test_support::epochPublishedWith(committed, modes, left, right);
  ASSERT_TRUE(published) << "the driver never published the calibration committed again";
  EXPECT_EQ(committed.epoch, *published);
  // Both files carry it.
  for (const auto& [path, intrinsics] : {std::make_pair(dir + "/left.yaml", committed.left_intrinsics),
                                         std::make_pair(dir + "/blocked/right.yaml", committed.right_intrinsics)}) {
    std::string name;
    CameraInfo info;
    ASSERT_TRUE(camera_calibration_parsers::readCalibration(path, name, info)) << path;
    EXPECT_NEAR(info.K[0], intrinsics[0], 1e-6 * intrinsics[0]) << path;
    EXPECT_NEAR(info.K[2], intrinsics[2], 1e-6 * intrinsics[0]) << path;
  }
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibrator_commit_retry_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
