#include "embedded_calibration_stereo/ros/stereo_camera_input.h"

#include <utility>

#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

StereoCameraInput::StereoCameraInput(const ros::NodeHandle& nh, const ros::NodeHandle& private_nh,
                                     const std::string& image_name, bool approximate_sync, int queue_size,
                                     Callback callback)
    : LazySyncedInput(nh, private_nh,
                      {"left/" + image_name, "left/camera_info", "right/" + image_name, "right/camera_info"},
                      approximate_sync, queue_size, std::move(callback)) {}

std::string StereoCameraInput::checkFrame(const sensor_msgs::Image& left, const sensor_msgs::CameraInfo& left_info,
                                          const sensor_msgs::Image& right,
                                          const sensor_msgs::CameraInfo& right_info) const {
  std::string problem =
      checkImagePair(left, leftImageTopic(), right, rightImageTopic(), {"mono8", "bgr8", "rgb8"});
  if (problem.empty()) problem = checkCameraInfo(left_info, leftInfoTopic(), left);
  if (problem.empty()) problem = checkCameraInfo(right_info, rightInfoTopic(), right);
  if (problem.empty()) problem = checkRectifiedPair(left_info, leftInfoTopic(), right_info, rightInfoTopic());
  return problem;
}

}  // namespace embedded_calibration_stereo
