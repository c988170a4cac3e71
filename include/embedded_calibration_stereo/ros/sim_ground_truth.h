#pragma once
// The CameraDriver's sim backend extras (docs/nodelets.md#cameradriver): the ground-truth
// topics of each rendered frame (ground_truth/..., /tf) and the sim/set_drift service.
// Ground truth costs conversions and copies: it is published only on topics somebody listens
// to, but the head pose is updated every frame (its velocity is a difference over consecutive
// frames).
//
// Threads: publish() on one thread (the driver's capture thread); the service runs on the
// manager's callback threads and touches only the SimRig (thread-safe drift).
#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <std_msgs/Header.h>

#include <memory>
#include <string>

#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/ros/head_pose_truth.h"

namespace embedded_calibration_stereo {

class SimGroundTruth {
 public:
  /// Advertises the ground-truth topics and sim/set_drift in `nh`'s namespace.
  SimGroundTruth(ros::NodeHandle& nh, image_transport::ImageTransport& it, std::shared_ptr<core::SimRig> sim,
                 const std::string& left_frame_id);
  /// One frame's truth, with the headers of its published images.
  void publish(const core::SimFrame& truth, const std_msgs::Header& left_header, const std_msgs::Header& right_header);
  /// Drops the service (before the manager's callback queues go).
  void shutdown() { set_drift_srv_.shutdown(); }

 private:
  bool setDrift(SetRigDrift::Request& req, SetRigDrift::Response& res);

  std::shared_ptr<core::SimRig> sim_;
  HeadPoseTruth head_pose_;
  ros::Publisher left_info_pub_, right_info_pub_, observations_pub_, head_pose_pub_, tf_pub_;
  image_transport::Publisher left_scene_pub_, right_scene_pub_, depth_pub_;
  ros::ServiceServer set_drift_srv_;
};

}  // namespace embedded_calibration_stereo
