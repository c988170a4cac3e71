// The CalibrationHealth's ROS glue (calibration_health_io.h): the frame records it looks frames
// up in, the boards a calibrator's status places, the message of a verdict and its diagnostics.
#include <gtest/gtest.h>

#include <cmath>

#include "embedded_calibration_stereo/ros/calibration_health_io.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;

namespace {

sensor_msgs::CameraInfoConstPtr info(double stamp_s, double fx) {
  auto msg = boost::make_shared<sensor_msgs::CameraInfo>();
  msg->header.stamp = ros::Time(stamp_s);
  msg->K = {fx, 0, 320, 0, fx, 240, 0, 0, 1};
  msg->D = {0.1, -0.2, 0, 0, 0};
  return msg;
}

TEST(HealthFrameRecords, FindsTheFramesAndCalibrationsOfAStampAndForgetsTheOldest) {
  HealthFrameRecords records(3);
  for (int i = 1; i <= 4; ++i) {
    records.addFrame({ros::Time(i), static_cast<uint32_t>(10 + i), i % 2 == 0, i % 2 == 1});
    records.addCameraInfo(true, info(i, 500 + i));
    records.addCameraInfo(false, info(i, 600 + i));
  }
  ASSERT_NE(records.frame(ros::Time(3)), nullptr);
  EXPECT_EQ(records.frame(ros::Time(3))->epoch, 13u);
  EXPECT_TRUE(records.frame(ros::Time(4))->lit);
  EXPECT_TRUE(records.frame(ros::Time(3))->dark);
  EXPECT_EQ(records.frame(ros::Time(1)), nullptr) << "only the latest 3 are kept";
  EXPECT_EQ(records.frame(ros::Time(5)), nullptr);
  ASSERT_NE(records.cameraInfo(true, ros::Time(2)), nullptr);
  EXPECT_DOUBLE_EQ(records.cameraInfo(true, ros::Time(2))->K[0], 502);
  EXPECT_DOUBLE_EQ(records.cameraInfo(false, ros::Time(2))->K[0], 602);
  EXPECT_EQ(records.cameraInfo(false, ros::Time(1)), nullptr);
}

TEST(CalibrationHealthIo, AnAcceptedStatusPlacesTheBoardsItNamesSolvedWithItsIntrinsics) {
  std::vector<core::VirtualBoard> boards(3);
  for (int i = 0; i < 3; ++i) boards[i].virtual_id = i;
  CalibrationStatus status;
  status.accepted = true;
  status.board_ids = {2, 0};
  status.board_poses.resize(2);
  status.board_poses[0].position.x = 0.5;
  status.board_poses[0].orientation.w = 1.0;
  status.board_poses[1].orientation.w = 1.0;
  status.left_intrinsics = {501, 501, 320, 240, 0.1, -0.2, 0, 0, 0};
  status.right_intrinsics = {601, 601, 320, 240, 0.1, -0.2, 0, 0, 0};
  const std::optional<SolvedBoards> solved = solvedBoards(status, boards);
  ASSERT_TRUE(solved);
  ASSERT_EQ(solved->boards.size(), 2u) << "board 1 was not placed by the solve";
  EXPECT_EQ(solved->boards[0].virtual_id, 0);
  EXPECT_EQ(solved->boards[1].virtual_id, 2);
  EXPECT_DOUBLE_EQ(solved->boards[1].rig_from_board.translation().x(), 0.5);
  EXPECT_TRUE(solvedWith(*solved, *info(0, 501), *info(0, 601)));
  EXPECT_FALSE(solvedWith(*solved, *info(0, 501.01), *info(0, 601))) << "another left focal length";
  EXPECT_FALSE(solvedWith(*solved, *info(0, 501), *info(0, 501)));

  CalibrationStatus rejected = status;
  rejected.accepted = false;
  EXPECT_FALSE(solvedBoards(rejected, boards));
  CalibrationStatus mismatched = status;
  mismatched.board_poses.pop_back();
  EXPECT_FALSE(solvedBoards(mismatched, boards));
}

TEST(CalibrationHealthIo, AVerdictsFiguresAreNaNForASignalNotMeasured) {
  core::HealthReport report;
  report.state = core::CalibrationHealth::kDegraded;
  report.misalignment_px = 0.2;
  report.board_rms_left_px = 0.3;
  report.epipolar_age_s = 0.5;
  report.board_age_s = -1.0;
  const CalibrationHealthPtr msg = toHealthMsg(report, 7, ros::Time(12.5));
  EXPECT_EQ(msg->state, CalibrationHealth::DEGRADED);
  EXPECT_EQ(msg->epoch, 7u);
  EXPECT_DOUBLE_EQ(msg->misalignment_px, 0.2);
  EXPECT_TRUE(std::isnan(msg->board_rms_left_px));
  EXPECT_DOUBLE_EQ(msg->predicted_depths_m[3], 10.0);
}

TEST(CalibrationHealthIo, TheStatusFieldsThePolicyDecidesOn) {
  CalibrationStatus status;
  status.epoch = 4;
  status.in_force_confirmed = true;
  status.newest_frame = ros::Time(100, 500000000);
  status.predicted_misalignment_rms_px = 0.05;
  status.predicted_disparity_bias_rms_px = 0.09;
  const core::CalibratorStatus seen = toCalibratorStatus(status);
  EXPECT_EQ(seen.epoch, 4u);
  EXPECT_FALSE(seen.accepted);
  EXPECT_TRUE(seen.in_force_confirmed);
  EXPECT_DOUBLE_EQ(seen.newest_frame_s, 100.5);
  EXPECT_DOUBLE_EQ(seen.predicted_misalignment_px, 0.05);
  EXPECT_DOUBLE_EQ(seen.predicted_disparity_bias_px, 0.09);
}

TEST(CalibrationHealthIo, DiagnosticsSayARestoreFailedOrTheStateWithItsReason) {
  using Policy = core::CalibrationHealthPolicy<std::string>;
  Policy policy({}, [](const std::string& a, const std::string& b) { return a == b; });
  policy.newCalibration(1, "A");
  core::HealthReport report;
  report.state = core::CalibrationHealth::kGood;
  policy.published(report, 1.0);
  diagnostic_updater::DiagnosticStatusWrapper ok;
  fillHealthDiagnostics(report, policy, "", {}, &ok);
  EXPECT_EQ(ok.level, diagnostic_msgs::DiagnosticStatus::OK);
  EXPECT_EQ(ok.message, "GOOD");

  policy.newCalibration(2, "B");
  report.state = core::CalibrationHealth::kBad;
  ASSERT_EQ(policy.afterVerification(report).outcome, Policy::Verified::Outcome::kRestore);
  policy.restoreFinished("left/set_camera_info did not answer");
  diagnostic_updater::DiagnosticStatusWrapper failed;
  report.state = core::CalibrationHealth::kDegraded;
  fillHealthDiagnostics(report, policy, "tilted", {}, &failed);
  EXPECT_EQ(failed.level, diagnostic_msgs::DiagnosticStatus::ERROR) << "a failed restore is an error";
  EXPECT_EQ(failed.message, policy.lastRestore());

  diagnostic_updater::DiagnosticStatusWrapper unknown;
  Policy fresh({}, [](const std::string& a, const std::string& b) { return a == b; });
  report.state = core::CalibrationHealth::kUnknown;
  fillHealthDiagnostics(report, fresh, "no calibration", {}, &unknown);
  EXPECT_EQ(unknown.level, diagnostic_msgs::DiagnosticStatus::WARN);
  EXPECT_EQ(unknown.message, "no verdict yet: no calibration");
}

}  // namespace
