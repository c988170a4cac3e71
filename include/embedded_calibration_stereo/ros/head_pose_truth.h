#pragma once
// The simulated head's ground-truth motion as ROS messages: the pose of the left optical frame
// in the world, as a tf transform and as a nav_msgs/Odometry with its velocity.
//
// Frames: both ends carry the "ground_truth/" prefix ("ground_truth/world" ->
// "ground_truth/<left_frame_id>"), so the truth never joins the head's own tf tree (the
// calibrator's left -> right on /tf_static): rviz can show both side by side and nothing that
// looks up the product's frames can pick up the truth by accident.
// Odometry: pose in ground_truth/world; twist in the child frame (nav_msgs convention), by a
// backward finite difference over the previous rendered frame (zero for the first frame): the
// mean velocity over the last frame period (the displacement seen from the body frame half-way
// through it; exact in direction for a constant twist).
//
// Threading: not thread-safe; one owner (the driver's capture thread, or the bag tool).
#include <Eigen/Geometry>
#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Odometry.h>
#include <ros/time.h>

#include <optional>
#include <string>

namespace embedded_calibration_stereo {

constexpr const char* kGroundTruthPrefix = "ground_truth/";
constexpr const char* kGroundTruthWorldFrame = "ground_truth/world";

// "ground_truth/" + frame_id (a leading '/' of frame_id is dropped).
std::string groundTruthFrame(const std::string& frame_id);

class HeadPoseTruth {
 public:
  explicit HeadPoseTruth(const std::string& left_frame_id);

  // One call per rendered frame, in scene-time order: the head pose at scene time `time_s`.
  // A time not after the previous one restarts the difference (twist zero for that frame).
  void update(const Eigen::Isometry3d& world_from_left, double time_s);

  bool valid() const { return current_.has_value(); }
  const std::string& childFrame() const { return child_frame_; }
  // The latest pose, stamped `stamp` (call after update()).
  geometry_msgs::TransformStamped transform(const ros::Time& stamp) const;
  nav_msgs::Odometry odometry(const ros::Time& stamp) const;
  // Body-frame (child frame) linear velocity in m/s and angular velocity in rad/s.
  Eigen::Vector3d linearVelocity() const { return linear_; }
  Eigen::Vector3d angularVelocity() const { return angular_; }

 private:
  std::string child_frame_;
  std::optional<Eigen::Isometry3d> current_;
  double time_s_ = 0.0;
  Eigen::Vector3d linear_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d angular_ = Eigen::Vector3d::Zero();
};

}  // namespace embedded_calibration_stereo
