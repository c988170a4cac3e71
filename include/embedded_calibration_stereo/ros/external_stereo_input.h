#pragma once
// The LightController's input (docs/nodelets.md#lightcontroller): an external driver's
// driver/left|right/image_raw and driver/left|right/camera_info, counted as they arrive
// (core::InputArrivalWatch names the silent ones), filtered before the synchroniser (stamps far
// from the other inputs' and unreadable images never reach it, whose queue they would fill:
// stamp_guard.h) and paired into stereo frames by stamp (ExactTime), or by nearest stamps
// (ApproximateTime) for two independent drivers.
//
// Threads: the callbacks run on the node handle's callback queue (the nodelet's, single-threaded);
// arrivals() is for that thread too. Nothing is delivered before the constructor returns.
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

#include "embedded_calibration_stereo/core/driver/input_arrivals.h"
#include "embedded_calibration_stereo/ros/lazy_synced_input.h"
#include "embedded_calibration_stereo/ros/stamp_guard.h"

namespace embedded_calibration_stereo {

class ExternalStereoInput {
 public:
  using Frame = std::function<void(const sensor_msgs::ImageConstPtr&, const sensor_msgs::CameraInfoConstPtr&,
                                   const sensor_msgs::ImageConstPtr&, const sensor_msgs::CameraInfoConstPtr&)>;
  struct Options {
    bool approximate_sync = true;
    double max_interval_s = 0.0;  // ApproximateTime's limit on a set's stamp spread; 0 = none
    int queue_size = 5;
  };

  using Report = std::function<void(const std::string&)>;
  /// Subscribes in `nh` (images raw, hints from `pnh`; stamp_tolerance_s from `pnh`); `frame`
  /// gets each paired stereo frame, `warn` the StampGuard's warnings, `unreadable` each image
  /// dropped before pairing because its data cannot be read ("cannot read the image on TOPIC:
  /// why"; every one: the caller throttles).
  ExternalStereoInput(ros::NodeHandle& nh, ros::NodeHandle& pnh, image_transport::ImageTransport& it,
                      const Options& options, Frame frame, Report warn, Report unreadable);

  /// The resolved topics: 0 left image, 1 left camera_info, 2 right image, 3 right camera_info.
  std::string topic(int index) const;
  /// The arrivals of the four topics and the frames paired (for naming a silent topic).
  core::InputArrivalWatch& arrivals() { return *arrivals_; }

 private:
  using Image = sensor_msgs::Image;
  using CameraInfo = sensor_msgs::CameraInfo;
  using ExactPolicy = message_filters::sync_policies::ExactTime<Image, CameraInfo, Image, CameraInfo>;
  using ApproximatePolicy = message_filters::sync_policies::ApproximateTime<Image, CameraInfo, Image, CameraInfo>;

  void admit(ros::NodeHandle& pnh, Report warn);
  bool readable(int index, const Image& image) const;
  void synchronise(const Options& options);
  void onFrame(const sensor_msgs::ImageConstPtr& left, const sensor_msgs::CameraInfoConstPtr& left_info,
               const sensor_msgs::ImageConstPtr& right, const sensor_msgs::CameraInfoConstPtr& right_info);

  Frame frame_;
  Report unreadable_;
  image_transport::SubscriberFilter left_sub_, right_sub_;
  message_filters::Subscriber<CameraInfo> left_info_sub_, right_info_sub_;
  std::unique_ptr<core::InputArrivalWatch> arrivals_;
  std::unique_ptr<StampGuard> guard_;  // the subscribers -> the admissions -> the synchroniser
  std::unique_ptr<AdmissionFilter<Image>> left_admit_, right_admit_;
  std::unique_ptr<AdmissionFilter<CameraInfo>> left_info_admit_, right_info_admit_;
  std::unique_ptr<message_filters::Synchronizer<ExactPolicy>> exact_sync_;
  std::unique_ptr<message_filters::Synchronizer<ApproximatePolicy>> approximate_sync_;
};

}  // namespace embedded_calibration_stereo
