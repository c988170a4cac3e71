// rostest: which boards the calibration health verifies a calibration against
// (health_solve_boards.test). The calibration in force is the simulator's true one throughout;
// only the board poses it is checked with change:
//  1. a calibration/status of an accepted solve with the calibration in force's intrinsics and
//     the device's boards moved 3 mm sideways, then that calibration committed again: the health
//     verifies it against the status's boards (its diagnostics say "its solve"), which the true
//     corners do not fit: it leaves GOOD;
//  2. the calibration committed again with a focal length 1e-3 px longer (no solve made it): the
//     health waits for a solve's boards, then verifies against device_config's, where the true
//     corners are: GOOD.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationHealth;
using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using test_support::Collector;
using sensor_msgs::CameraInfo;
using Healths = std::vector<CalibrationHealth::ConstPtr>;

namespace {

// Commits the pair through the driver's services and returns the epoch it is in force under (each
// call moves the driver's epoch: the one of a frame after both); 0 on failure.
uint32_t commitPair(const CameraInfo& left, const CameraInfo& right, Collector<CalibrationMode>& modes) {
  for (const auto& [name, info] : {std::make_pair("left/set_camera_info", left), std::make_pair("right/set_camera_info", right)}) {
    sensor_msgs::SetCameraInfo srv;
    srv.request.camera_info = info;
    if (!ros::service::call(name, srv) || !srv.response.success) return 0;
  }
  const size_t seen = modes.snapshot().size();
  if (!modes.waitForCount(seen + 2, 5.0)) return 0;
  return modes.snapshot().back()->calibration_epoch;
}

std::vector<double> intrinsics(const CameraInfo& info) {
  std::vector<double> v = {info.K[0], info.K[4], info.K[2], info.K[5]};
  v.insert(v.end(), info.D.begin(), info.D.end());
  return v;
}

// The health's newest word on the boards it verifies against (its diagnostics).
std::string boardsSource(const std::vector<diagnostic_msgs::DiagnosticArray::ConstPtr>& all) {
  for (auto it = all.rbegin(); it != all.rend(); ++it)
    for (const auto& status : (*it)->status)
      for (const auto& kv : status.values)
        if (kv.key == "boards verified against") return kv.value;
  return "";
}

}  // namespace

TEST(HealthSolveBoards, ACalibrationIsVerifiedAgainstItsSolvesBoards) {
  ros::NodeHandle nh;
  Collector<CalibrationHealth> health(nh, "calibration/health", 1000);
  Collector<CalibrationMode> modes(nh, "calibration_mode", 2000);
  Collector<CameraInfo> left(nh, "left/camera_info", 20), right(nh, "right/camera_info", 20);
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics(nh, "/diagnostics", 200);
  ros::Publisher status_pub = nh.advertise<CalibrationStatus>("calibration/status", 1, true);
  ASSERT_TRUE(ros::service::waitForService("left/set_camera_info", 20000));
  ASSERT_TRUE(health.waitFor(
      [](const Healths& m) {
        return !m.empty() && m.back()->state == CalibrationHealth::GOOD && m.back()->verification_age_s >= 0.0;
      },
      20.0));
  ASSERT_TRUE(left.waitForCount(1, 5.0) && right.waitForCount(1, 5.0));
  const CameraInfo in_force_left = *left.snapshot().back(), in_force_right = *right.snapshot().back();

  // 1. An accepted solve of this calibration whose boards sit 3 mm to the side.
  cv::FileStorage fs = core::openYaml(ECS_SOURCE_DIR "/config/sim_rig.yaml");
  CalibrationStatus solve;
  solve.header.stamp = ros::Time::now();
  solve.accepted = true;
  solve.left_intrinsics = intrinsics(in_force_left);
  solve.right_intrinsics = intrinsics(in_force_right);
  for (const core::VirtualBoard& board : core::loadDevice(fs["device"], "device").virtualBoards()) {
    Eigen::Isometry3d moved = board.rig_from_board;
    moved.translation().x() += 0.003;
    solve.board_ids.push_back(static_cast<uint16_t>(board.virtual_id));
    solve.board_poses.push_back(embedded_calibration_stereo::toPoseMsg(moved));
  }
  ASSERT_TRUE(test_support::waitUntil([&] { return status_pub.getNumSubscribers() > 0; }, 5.0));
  status_pub.publish(solve);
  uint32_t epoch = commitPair(in_force_left, in_force_right, modes);
  ASSERT_NE(epoch, 0u);
  ASSERT_TRUE(health.waitFor(
      [&](const Healths& m) {
        return m.back()->epoch == epoch && m.back()->state >= CalibrationHealth::DEGRADED &&
               m.back()->verification_age_s >= 0.0;
      },
      10.0))
      << "last health: " << health.snapshot().back()->reason;
  std::printf("against the solve's boards, 3 mm off: %s\n", health.snapshot().back()->reason.c_str());
  EXPECT_TRUE(diagnostics.waitFor([](const auto& m) { return boardsSource(m) == "its solve"; }, 5.0))
      << boardsSource(diagnostics.snapshot());

  // 2. A calibration no solve made: after the wait, device_config's boards, where the true
  // corners are.
  CameraInfo other_left = in_force_left, other_right = in_force_right;
  other_left.K[0] += 1e-3;
  other_left.P[0] += 1e-3;
  other_right.P[0] += 1e-3;
  epoch = commitPair(other_left, other_right, modes);
  ASSERT_NE(epoch, 0u);
  ASSERT_TRUE(health.waitFor(
      [&](const Healths& m) {
        return m.back()->epoch == epoch && m.back()->state == CalibrationHealth::GOOD && m.back()->verification_age_s >= 0.0;
      },
      10.0))
      << "last health: " << health.snapshot().back()->reason;
  EXPECT_TRUE(diagnostics.waitFor([](const auto& m) { return boardsSource(m) == "device_config"; }, 5.0))
      << boardsSource(diagnostics.snapshot());
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "health_solve_boards_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
