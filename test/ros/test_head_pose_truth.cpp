// HeadPoseTruth: the ground-truth head pose messages against a closed-form motion (a head
// driving an arc: constant forward speed and yaw rate), not against the code's own difference.
#include <gtest/gtest.h>

#include <cmath>

#include "embedded_calibration_stereo/ros/head_pose_truth.h"

using embedded_calibration_stereo::HeadPoseTruth;

namespace {

constexpr double kSpeed = 1.5;     // m/s along the optical axis (z forward)
constexpr double kYawRate = 0.6;   // rad/s about the optical y axis (down)
constexpr double kFps = 30.0;

// The arc: heading theta = w t, forward axis (sin theta, 0, cos theta) in the world, so the
// position integrates to (v/w) (1 - cos theta, 0, sin theta); a fixed offset and a tilt make
// the world frame general.
Eigen::Isometry3d arcPose(double t) {
  const double theta = kYawRate * t;
  Eigen::Isometry3d moving = Eigen::Isometry3d::Identity();
  moving.linear() = Eigen::AngleAxisd(theta, Eigen::Vector3d::UnitY()).toRotationMatrix();
  moving.translation() = kSpeed / kYawRate * Eigen::Vector3d(1.0 - std::cos(theta), 0.0, std::sin(theta));
  Eigen::Isometry3d world_from_start = Eigen::Isometry3d::Identity();
  world_from_start.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  world_from_start.translation() = Eigen::Vector3d(4.0, -1.0, 2.5);
  return world_from_start * moving;
}

}  // namespace

TEST(HeadPoseTruth, FramesCarryTheGroundTruthPrefix) {
  EXPECT_EQ(embedded_calibration_stereo::groundTruthFrame("stereo_left_optical_frame"),
            "ground_truth/stereo_left_optical_frame");
  EXPECT_EQ(embedded_calibration_stereo::groundTruthFrame("/cam"), "ground_truth/cam");
  HeadPoseTruth truth("stereo_left_optical_frame");
  truth.update(arcPose(0.0), 0.0);
  const auto odom = truth.odometry(ros::Time(10.0));
  EXPECT_EQ(odom.header.frame_id, "ground_truth/world");
  EXPECT_EQ(odom.child_frame_id, "ground_truth/stereo_left_optical_frame");
  EXPECT_EQ(odom.header.stamp, ros::Time(10.0));
  const auto tf = truth.transform(ros::Time(10.0));
  EXPECT_EQ(tf.header.frame_id, "ground_truth/world");
  EXPECT_EQ(tf.child_frame_id, "ground_truth/stereo_left_optical_frame");
}

TEST(HeadPoseTruth, PoseAndTwistFollowAnArc) {
  HeadPoseTruth truth("left");
  for (int k = 0; k < 90; ++k) {
    const double t = k / kFps;
    const Eigen::Isometry3d pose = arcPose(t);
    truth.update(pose, t);
    const auto odom = truth.odometry(ros::Time(100.0 + t));
    const auto& p = odom.pose.pose;
    EXPECT_NEAR(p.position.x, pose.translation().x(), 1e-12) << k;
    EXPECT_NEAR(p.position.y, pose.translation().y(), 1e-12) << k;
    EXPECT_NEAR(p.position.z, pose.translation().z(), 1e-12) << k;
    const Eigen::Quaterniond q(p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z);
    EXPECT_LT(q.angularDistance(Eigen::Quaterniond(pose.rotation())), 1e-9) << k;
    const auto& tf = truth.transform(ros::Time(100.0 + t)).transform;
    EXPECT_EQ(tf.translation.x, p.position.x);
    EXPECT_EQ(tf.rotation.w, p.orientation.w);

    const auto& v = odom.twist.twist;
    if (k == 0) {
      EXPECT_EQ(v.linear.z, 0.0);
      EXPECT_EQ(v.angular.y, 0.0);
      continue;
    }
    // Over one period the head moves along the chord: v sinc(w dt / 2), straight ahead in the
    // body frame half-way through the turn; the yaw rate is exact.
    const double half = 0.5 * kYawRate / kFps;
    EXPECT_NEAR(v.linear.x, 0.0, 1e-9) << k;
    EXPECT_NEAR(v.linear.y, 0.0, 1e-9) << k;
    EXPECT_NEAR(v.linear.z, kSpeed * std::sin(half) / half, 1e-9) << k;
    EXPECT_NEAR(v.angular.x, 0.0, 1e-9) << k;
    EXPECT_NEAR(v.angular.y, kYawRate, 1e-9) << k;
    EXPECT_NEAR(v.angular.z, 0.0, 1e-9) << k;
  }
}

TEST(HeadPoseTruth, ATimeNotAfterThePreviousRestartsTheDifference) {
  HeadPoseTruth truth("left");
  truth.update(arcPose(0.0), 0.0);
  truth.update(arcPose(0.1), 0.1);
  EXPECT_GT(truth.linearVelocity().norm(), 1.0);
  truth.update(arcPose(0.5), 0.1);  // same time: no velocity from a zero period
  EXPECT_EQ(truth.linearVelocity().norm(), 0.0);
  EXPECT_EQ(truth.angularVelocity().norm(), 0.0);
}
