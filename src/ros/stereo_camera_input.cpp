#include "embedded_calibration_stereo/ros/stereo_camera_input.h"

#include "embedded_calibration_stereo/ros/stereo_input_check.h"

#include <utility>

namespace embedded_calibration_stereo {

StereoCameraInput::StereoCameraInput(bool approximate_sync, int queue_size, FrameCallback callback)
    : queue_size_(queue_size), callback_(std::move(callback)) {
  if (approximate_sync) {
    approximate_sync_ = std::make_unique<message_filters::Synchronizer<ApproximatePolicy>>(
        ApproximatePolicy(queue_size), left_image_, left_info_, right_image_, right_info_);
    approximate_sync_->registerCallback(&StereoCameraInput::onFrame, this);
  } else {
    exact_sync_ = std::make_unique<message_filters::Synchronizer<ExactPolicy>>(
        ExactPolicy(queue_size), left_image_, left_info_, right_image_, right_info_);
    exact_sync_->registerCallback(&StereoCameraInput::onFrame, this);
  }
}

void StereoCameraInput::subscribe(image_transport::ImageTransport& it, ros::NodeHandle& nh,
                                  const ros::NodeHandle& private_nh, const std::string& image_name) {
  if (subscribed_) return;
  subscribed_ = true;
  const image_transport::TransportHints hints("raw", ros::TransportHints(), private_nh);
  left_image_.subscribe(it, "left/" + image_name, queue_size_, hints);
  left_info_.subscribe(nh, "left/camera_info", queue_size_);
  right_image_.subscribe(it, "right/" + image_name, queue_size_, hints);
  right_info_.subscribe(nh, "right/camera_info", queue_size_);
}

void StereoCameraInput::unsubscribe() {
  left_image_.unsubscribe();
  left_info_.unsubscribe();
  right_image_.unsubscribe();
  right_info_.unsubscribe();
  subscribed_ = false;
}

std::string StereoCameraInput::checkFrame(const Image& left, const CameraInfo& left_info, const Image& right,
                                          const CameraInfo& right_info) const {
  std::string problem =
      checkImagePair(left, leftImageTopic(), right, rightImageTopic(), {"mono8", "bgr8", "rgb8"});
  if (problem.empty()) problem = checkCameraInfo(left_info, leftInfoTopic(), left);
  if (problem.empty()) problem = checkCameraInfo(right_info, rightInfoTopic(), right);
  return problem;
}

}  // namespace embedded_calibration_stereo
