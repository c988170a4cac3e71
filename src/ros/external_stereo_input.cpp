#include "embedded_calibration_stereo/ros/external_stereo_input.h"

#include <vector>

namespace embedded_calibration_stereo {

ExternalStereoInput::ExternalStereoInput(ros::NodeHandle& nh, ros::NodeHandle& pnh,
                                         image_transport::ImageTransport& it, const Options& options, Frame frame,
                                         Report warn, Report unreadable)
    : frame_(std::move(frame)), unreadable_(std::move(unreadable)) {
  const image_transport::TransportHints hints("raw", ros::TransportHints(), pnh);
  left_sub_.subscribe(it, "driver/left/image_raw", options.queue_size, hints);
  right_sub_.subscribe(it, "driver/right/image_raw", options.queue_size, hints);
  left_info_sub_.subscribe(nh, "driver/left/camera_info", options.queue_size);
  right_info_sub_.subscribe(nh, "driver/right/camera_info", options.queue_size);
  // Arrivals per topic, to name the missing one when no frame can be matched.
  arrivals_ = std::make_unique<core::InputArrivalWatch>(
      std::vector<std::string>{"image on " + topic(0), "camera_info on " + topic(1), "image on " + topic(2),
                               "camera_info on " + topic(3)},
      "the driver's images and camera_info arrive but do not pair by stamp");
  left_sub_.registerCallback([this](const sensor_msgs::ImageConstPtr&) { arrivals_->arrived(0); });
  left_info_sub_.registerCallback([this](const sensor_msgs::CameraInfoConstPtr&) { arrivals_->arrived(1); });
  right_sub_.registerCallback([this](const sensor_msgs::ImageConstPtr&) { arrivals_->arrived(2); });
  right_info_sub_.registerCallback([this](const sensor_msgs::CameraInfoConstPtr&) { arrivals_->arrived(3); });
  admit(pnh, std::move(warn));
  synchronise(options);
}

std::string ExternalStereoInput::topic(int index) const {
  switch (index) {
    case 0: return left_sub_.getTopic();
    case 1: return left_info_sub_.getTopic();
    case 2: return right_sub_.getTopic();
    default: return right_info_sub_.getTopic();
  }
}

bool ExternalStereoInput::readable(int index, const Image& image) const {
  const std::string problem = malformedImage(image);
  if (!problem.empty()) unreadable_("cannot read the image on " + topic(index) + ": " + problem);
  return problem.empty();
}

void ExternalStereoInput::admit(ros::NodeHandle& pnh, Report warn) {
  guard_ = std::make_unique<StampGuard>(std::vector<std::string>{topic(0), topic(1), topic(2), topic(3)},
                                        readStampTolerance(pnh), "LightController", std::move(warn));
  const auto admit_image = [this](size_t index) {
    return [this, index](const ros::MessageEvent<Image const>& event) {
      const Image& image = *event.getMessage();
      return readable(static_cast<int>(index), image) && guard_->admit(index, image.header.stamp);
    };
  };
  const auto admit_info = [this](size_t index) {
    return [this, index](const ros::MessageEvent<CameraInfo const>& event) {
      return guard_->admit(index, event.getMessage()->header.stamp);
    };
  };
  left_admit_ = std::make_unique<AdmissionFilter<Image>>(left_sub_, admit_image(0));
  left_info_admit_ = std::make_unique<AdmissionFilter<CameraInfo>>(left_info_sub_, admit_info(1));
  right_admit_ = std::make_unique<AdmissionFilter<Image>>(right_sub_, admit_image(2));
  right_info_admit_ = std::make_unique<AdmissionFilter<CameraInfo>>(right_info_sub_, admit_info(3));
}

void ExternalStereoInput::synchronise(const Options& options) {
  if (options.approximate_sync) {
    approximate_sync_ = std::make_unique<message_filters::Synchronizer<ApproximatePolicy>>(
        ApproximatePolicy(options.queue_size), *left_admit_, *left_info_admit_, *right_admit_, *right_info_admit_);
    if (options.max_interval_s > 0) approximate_sync_->setMaxIntervalDuration(ros::Duration(options.max_interval_s));
    approximate_sync_->registerCallback(&ExternalStereoInput::onFrame, this);
  } else {
    exact_sync_ = std::make_unique<message_filters::Synchronizer<ExactPolicy>>(
        ExactPolicy(options.queue_size), *left_admit_, *left_info_admit_, *right_admit_, *right_info_admit_);
    exact_sync_->registerCallback(&ExternalStereoInput::onFrame, this);
  }
}

void ExternalStereoInput::onFrame(const sensor_msgs::ImageConstPtr& left, const sensor_msgs::CameraInfoConstPtr& left_info,
                                  const sensor_msgs::ImageConstPtr& right,
                                  const sensor_msgs::CameraInfoConstPtr& right_info) {
  arrivals_->frameIn();
  frame_(left, left_info, right, right_info);
}

}  // namespace embedded_calibration_stereo
