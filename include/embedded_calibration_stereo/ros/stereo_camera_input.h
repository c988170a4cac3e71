#pragma once
// The left/right image + CameraInfo input of the image nodelets (Rectifier, Disparity):
// left|right/<image_name> with left|right/camera_info, joined by ExactTime or ApproximateTime
// and subscribed lazily (lazy_synced_input.h, which also says which threads touch it).
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <string>

#include "embedded_calibration_stereo/ros/lazy_synced_input.h"

namespace embedded_calibration_stereo {

class StereoCameraInput
    : public LazySyncedInput<sensor_msgs::Image, sensor_msgs::CameraInfo, sensor_msgs::Image, sensor_msgs::CameraInfo> {
 public:
  // Callback arguments: left image, left CameraInfo, right image, right CameraInfo.
  StereoCameraInput(const ros::NodeHandle& nh, const ros::NodeHandle& private_nh, const std::string& image_name,
                    bool approximate_sync, int queue_size, Callback callback);

  // Resolved topic names, for error messages.
  const std::string& leftImageTopic() const { return topic(0); }
  const std::string& leftInfoTopic() const { return topic(1); }
  const std::string& rightImageTopic() const { return topic(2); }
  const std::string& rightInfoTopic() const { return topic(3); }

  // The first problem of a synchronised frame, named by these topics (stereo_input_check.h):
  // an image pair of mono8, bgr8 or rgb8, each CameraInfo valid for its image, and the two
  // CameraInfos a rectified stereo pair (checkRectifiedPair); "" if none.
  std::string checkFrame(const sensor_msgs::Image& left, const sensor_msgs::CameraInfo& left_info,
                         const sensor_msgs::Image& right, const sensor_msgs::CameraInfo& right_info) const;
};

}  // namespace embedded_calibration_stereo
