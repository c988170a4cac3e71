#pragma once
// The left/right image + CameraInfo input shared by the image nodelets (Rectifier, Disparity):
// four subscriber filters joined by an ExactTime or ApproximateTime synchroniser (parameter
// `approximate_sync`, as in stereo_image_proc), subscribed lazily by the owner's connect
// callback.
//
// Threads: subscribe()/unsubscribe() are called from the owner's connect callbacks and onInit,
// which must serialise them under the owner's connect mutex; the frame callback runs on the
// nodelet's callback queue.
#include <image_transport/image_transport.h>
#include <image_transport/subscriber_filter.h>
#include <message_filters/subscriber.h>
#include <message_filters/sync_policies/approximate_time.h>
#include <message_filters/sync_policies/exact_time.h>
#include <message_filters/synchronizer.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <functional>
#include <memory>
#include <string>

namespace embedded_calibration_stereo {

class StereoCameraInput {
 public:
  using FrameCallback = std::function<void(
      const sensor_msgs::ImageConstPtr& left, const sensor_msgs::CameraInfoConstPtr& left_info,
      const sensor_msgs::ImageConstPtr& right, const sensor_msgs::CameraInfoConstPtr& right_info)>;

  StereoCameraInput(bool approximate_sync, int queue_size, FrameCallback callback);

  // Subscribes left|right/<image_name> and left|right/camera_info (raw transport) unless
  // already subscribed.
  void subscribe(image_transport::ImageTransport& it, ros::NodeHandle& nh,
                 const ros::NodeHandle& private_nh, const std::string& image_name);
  void unsubscribe();
  bool subscribed() const { return subscribed_; }

  // Resolved topic names, for error messages.
  std::string leftImageTopic() const { return left_image_.getTopic(); }
  std::string rightImageTopic() const { return right_image_.getTopic(); }
  std::string leftInfoTopic() const { return left_info_.getTopic(); }
  std::string rightInfoTopic() const { return right_info_.getTopic(); }

  // The first problem of a synchronised frame, named by these topics (stereo_input_check.h):
  // an image pair of mono8, bgr8 or rgb8, and each CameraInfo matching its image; "" if none.
  std::string checkFrame(const sensor_msgs::Image& left, const sensor_msgs::CameraInfo& left_info,
                         const sensor_msgs::Image& right, const sensor_msgs::CameraInfo& right_info) const;

 private:
  using Image = sensor_msgs::Image;
  using CameraInfo = sensor_msgs::CameraInfo;
  using ExactPolicy = message_filters::sync_policies::ExactTime<Image, CameraInfo, Image, CameraInfo>;
  using ApproximatePolicy =
      message_filters::sync_policies::ApproximateTime<Image, CameraInfo, Image, CameraInfo>;

  // message_filters binds member functions only: forwards to callback_.
  void onFrame(const sensor_msgs::ImageConstPtr& left, const sensor_msgs::CameraInfoConstPtr& left_info,
               const sensor_msgs::ImageConstPtr& right,
               const sensor_msgs::CameraInfoConstPtr& right_info) {
    callback_(left, left_info, right, right_info);
  }

  const int queue_size_;
  const FrameCallback callback_;
  image_transport::SubscriberFilter left_image_, right_image_;
  message_filters::Subscriber<CameraInfo> left_info_, right_info_;
  std::unique_ptr<message_filters::Synchronizer<ExactPolicy>> exact_sync_;
  std::unique_ptr<message_filters::Synchronizer<ApproximatePolicy>> approximate_sync_;
  bool subscribed_ = false;
};

}  // namespace embedded_calibration_stereo
