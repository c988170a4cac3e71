#include "embedded_calibration_stereo/ros/head_pose_truth.h"

#include "embedded_calibration_stereo/ros/conversions.h"

namespace embedded_calibration_stereo {

std::string groundTruthFrame(const std::string& frame_id) {
  const size_t start = frame_id.rfind('/', 0) == 0 ? 1 : 0;
  return kGroundTruthPrefix + frame_id.substr(start);
}

HeadPoseTruth::HeadPoseTruth(const std::string& left_frame_id) : child_frame_(groundTruthFrame(left_frame_id)) {}

void HeadPoseTruth::update(const Eigen::Isometry3d& world_from_left, double time_s) {
  if (current_ && time_s > time_s_) {
    const double dt = time_s - time_s_;
    // The motion over the last period in the current body frame: previous_from_current.
    const Eigen::Isometry3d delta = current_->inverse() * world_from_left;
    const Eigen::AngleAxisd rotation(delta.rotation());
    angular_ = rotation.axis() * rotation.angle() / dt;
    // The displacement seen from the body frame half-way through the rotation: exact in
    // direction for a constant twist (an arc), where the current frame would be off by half the
    // frame's turn.
    const Eigen::Matrix3d world_from_mid =
        current_->rotation() * Eigen::AngleAxisd(0.5 * rotation.angle(), rotation.axis()).toRotationMatrix();
    linear_ = world_from_mid.transpose() * (world_from_left.translation() - current_->translation()) / dt;
  } else {
    linear_.setZero();
    angular_.setZero();
  }
  current_ = world_from_left;
  time_s_ = time_s;
}

geometry_msgs::TransformStamped HeadPoseTruth::transform(const ros::Time& stamp) const {
  return toTransformStamped(current_.value_or(Eigen::Isometry3d::Identity()), kGroundTruthWorldFrame, child_frame_,
                            stamp);
}

nav_msgs::Odometry HeadPoseTruth::odometry(const ros::Time& stamp) const {
  const geometry_msgs::TransformStamped t = transform(stamp);
  nav_msgs::Odometry msg;
  msg.header = t.header;
  msg.child_frame_id = child_frame_;
  msg.pose.pose.position.x = t.transform.translation.x;
  msg.pose.pose.position.y = t.transform.translation.y;
  msg.pose.pose.position.z = t.transform.translation.z;
  msg.pose.pose.orientation = t.transform.rotation;
  msg.twist.twist.linear.x = linear_.x();
  msg.twist.twist.linear.y = linear_.y();
  msg.twist.twist.linear.z = linear_.z();
  msg.twist.twist.angular.x = angular_.x();
  msg.twist.twist.angular.y = angular_.y();
  msg.twist.twist.angular.z = angular_.z();
  return msg;  // covariances stay zero: the truth is exact
}

}  // namespace embedded_calibration_stereo
