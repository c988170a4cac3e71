// rostest: the driver's ground-truth head pose on a moving scenario. The messages carry wall
// stamps, so the frame index k of each pose is found here: the k in the first half of the
// drive's loop (where no pose repeats) whose trajectory pose, evaluated here at k / fps,
// matches. The simulator's scene time is the frame index / fps, not the wall time, so that a
// run renders the same frames however loaded the machine is: consecutive messages must be
// consecutive frames even when one came late.
#include <gtest/gtest.h>
#include <nav_msgs/Odometry.h>
#include <tf2_msgs/TFMessage.h>

#include <cmath>
#include <limits>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/sim/trajectory.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;

namespace {

// Position and rotation error (m + rad) between the message and the trajectory at t.
double poseError(const nav_msgs::Odometry& m, const core::SimTrajectory& trajectory, double t) {
  const Eigen::Isometry3d truth = core::trajectoryPose(trajectory, t);
  const auto& p = m.pose.pose;
  const Eigen::Quaterniond q(p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z);
  return (Eigen::Vector3d(p.position.x, p.position.y, p.position.z) - truth.translation()).norm() +
         q.angularDistance(Eigen::Quaterniond(truth.rotation()));
}

}  // namespace

TEST(DriverMotion, HeadPoseFollowsTheTrajectoryAtFrameOverFps) {
  ros::NodeHandle nh;
  double fps = 0.0;
  std::string config_path;
  ASSERT_TRUE(ros::param::get("~fps", fps));
  ASSERT_TRUE(ros::param::get("~sim_config", config_path));
  const core::SimRigConfig config = core::loadSimRigConfig(config_path);
  ASSERT_EQ(config.trajectory.kind, core::SimTrajectory::Kind::kDrive);
  ASSERT_GT(config.trajectory.loop_s, 0.0);
  Collector<nav_msgs::Odometry> poses(nh, "ground_truth/head_pose");
  Collector<tf2_msgs::TFMessage> tf(nh, "/tf");
  ASSERT_TRUE(poses.waitForCount(15, 20.0)) << "no ground_truth/head_pose";
  ASSERT_TRUE(tf.waitForCount(5, 5.0)) << "no /tf";
  const auto messages = poses.snapshot();
  const int last_k = static_cast<int>(0.5 * config.trajectory.loop_s * fps);
  std::vector<int> frames;
  double worst = 0.0;
  for (const auto& m : messages) {
    int best = -1;
    double best_error = std::numeric_limits<double>::infinity();
    for (int k = 0; k < last_k; ++k) {
      const double e = poseError(*m, config.trajectory, k / fps);
      if (e < best_error) best_error = e, best = k;
    }
    ASSERT_LT(best_error, 1e-9) << "a head pose that is on no frame of the first " << last_k
                                << " (the test started late, or the pose is not the trajectory at k / fps)";
    worst = std::max(worst, best_error);
    frames.push_back(best);
  }
  for (size_t i = 1; i < messages.size(); ++i) {
    EXPECT_EQ(frames[i] - frames[i - 1], 1) << "message " << i;
    EXPECT_GT(messages[i]->header.stamp, messages[i - 1]->header.stamp) << "message " << i;
  }
  std::printf("head poses of frames %d..%d match the trajectory within %.1e\n", frames.front(), frames.back(), worst);
  // The head moves, with a forward velocity near the configured speed.
  const auto& v = messages.back()->twist.twist.linear;
  EXPECT_NEAR(std::sqrt(v.x * v.x + v.y * v.y + v.z * v.z), config.trajectory.speed_m_s, 0.1 * config.trajectory.speed_m_s);
  for (const auto& m : tf.snapshot())
    for (const auto& t : m->transforms) EXPECT_EQ(t.child_frame_id, "ground_truth/stereo_left_optical_frame");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "driver_motion_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
