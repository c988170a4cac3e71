#include "embedded_calibration_stereo/ros/sim_ground_truth.h"

#include <cv_bridge/cv_bridge.h>
#include <tf2_msgs/TFMessage.h>

#include "embedded_calibration_stereo/ros/conversions.h"

namespace embedded_calibration_stereo {

SimGroundTruth::SimGroundTruth(ros::NodeHandle& nh, image_transport::ImageTransport& it,
                               std::shared_ptr<core::SimRig> sim, const std::string& left_frame_id)
    : sim_(std::move(sim)), head_pose_(left_frame_id) {
  left_info_pub_ = nh.advertise<sensor_msgs::CameraInfo>("ground_truth/left/camera_info", 2);
  right_info_pub_ = nh.advertise<sensor_msgs::CameraInfo>("ground_truth/right/camera_info", 2);
  observations_pub_ = nh.advertise<StereoPatternObservation>("ground_truth/observations", 2);
  left_scene_pub_ = it.advertise("ground_truth/left/image_scene", 2);
  right_scene_pub_ = it.advertise("ground_truth/right/image_scene", 2);
  depth_pub_ = it.advertise("ground_truth/left/depth", 2);
  head_pose_pub_ = nh.advertise<nav_msgs::Odometry>("ground_truth/head_pose", 2);
  // As tf2_ros::TransformBroadcaster does, but with a subscriber count to skip idle work.
  tf_pub_ = nh.advertise<tf2_msgs::TFMessage>("/tf", 100);
  set_drift_srv_ = nh.advertiseService("sim/set_drift", &SimGroundTruth::setDrift, this);
}

void SimGroundTruth::publish(const core::SimFrame& truth, const std_msgs::Header& left_header,
                             const std_msgs::Header& right_header) {
  head_pose_.update(truth.world_from_left, truth.time_s);
  if (left_info_pub_.getNumSubscribers() > 0 || right_info_pub_.getNumSubscribers() > 0) {
    auto infos = toStereoCameraInfo(truth.truth);
    infos.first.header = left_header;
    infos.second.header = right_header;
    left_info_pub_.publish(boost::make_shared<sensor_msgs::CameraInfo>(infos.first));
    right_info_pub_.publish(boost::make_shared<sensor_msgs::CameraInfo>(infos.second));
  }
  if (observations_pub_.getNumSubscribers() > 0) {
    auto observations = boost::make_shared<StereoPatternObservation>(toMsg(truth.observations));
    observations->header = left_header;
    observations_pub_.publish(observations);
  }
  const std::string& encoding = sim_->config().encoding;
  if (left_scene_pub_.getNumSubscribers() > 0)
    left_scene_pub_.publish(cv_bridge::CvImage(left_header, encoding, truth.left_scene).toImageMsg());
  if (right_scene_pub_.getNumSubscribers() > 0)
    right_scene_pub_.publish(cv_bridge::CvImage(right_header, encoding, truth.right_scene).toImageMsg());
  if (depth_pub_.getNumSubscribers() > 0)
    depth_pub_.publish(cv_bridge::CvImage(left_header, "32FC1", truth.left_depth).toImageMsg());
  if (head_pose_pub_.getNumSubscribers() > 0)
    head_pose_pub_.publish(boost::make_shared<nav_msgs::Odometry>(head_pose_.odometry(left_header.stamp)));
  if (tf_pub_.getNumSubscribers() > 0) {
    auto tf = boost::make_shared<tf2_msgs::TFMessage>();
    tf->transforms.push_back(head_pose_.transform(left_header.stamp));
    tf_pub_.publish(tf);
  }
}

bool SimGroundTruth::setDrift(SetRigDrift::Request& req, SetRigDrift::Response& res) {
  core::DriftRequest drift;
  drift.focal_scale = req.focal_scale;
  drift.thermal_rate_deg_per_s = req.thermal_rate_deg_per_s;
  for (int i = 0; i < 3; ++i) {
    drift.right_rotation_deg[i] = req.right_rotation_deg[i];
    drift.knock_rotation_deg[i] = req.knock_rotation_deg[i];
    drift.knock_translation_m[i] = req.knock_translation_m[i];
  }
  drift.reset = req.reset;
  const std::string refusal = sim_->setDrift(drift);
  res.success = refusal.empty();
  res.message = res.success ? "drift applied" : refusal;
  return true;
}

}  // namespace embedded_calibration_stereo
