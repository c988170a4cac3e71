// Rectifier nodelet: rectifies each stereo frame with the calibration it was taken with, under
// stereo_image_proc's topic names; maps are rebuilt off the image thread when the CameraInfo
// changes. Topics, parameters and behaviour: docs/nodelets.md#rectifier.
#include <cv_bridge/cv_bridge.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>

#include <chrono>
#include <deque>
#include <future>
#include <memory>
#include <mutex>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <sensor_msgs/image_encodings.h>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/output_image.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/stage_diagnostics.h"
#include "embedded_calibration_stereo/ros/stereo_camera_input.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

namespace {

using sensor_msgs::CameraInfo;
using sensor_msgs::Image;

// The calibration a set of maps was built from (headers excluded).
struct CalibrationKey {
  CameraInfo left, right;
  static CameraInfo strip(const CameraInfo& info) {
    CameraInfo c = info;
    c.header = std_msgs::Header();
    return c;
  }
  CalibrationKey(const CameraInfo& l, const CameraInfo& r) : left(strip(l)), right(strip(r)) {}
  bool operator==(const CalibrationKey& o) const { return left == o.left && right == o.right; }
};

// Remap tables of both cameras and the CameraInfos of the rectification they apply.
struct StereoMaps {
  explicit StereoMaps(const CalibrationKey& k) : key(k) {}
  CalibrationKey key;
  cv::Mat left_map1, left_map2, right_map1, right_map2;
  CameraInfo left_rect, right_rect;
};

cv::Matx33d matx33(const boost::array<double, 9>& a) { return cv::Matx33d(a.data()); }
cv::Matx34d matx34(const boost::array<double, 12>& a) { return cv::Matx34d(a.data()); }

// The raw camera (K, D) with the rectification actually applied (R, P): image_rect with
// camera_info_rect is described exactly as image_raw with camera_info (equal to it for bouguet).
CameraInfo rectifiedInfo(const CameraInfo& raw, const cv::Matx33d& R, const cv::Matx34d& P) {
  CameraInfo out = raw;
  for (int i = 0; i < 9; ++i) out.R[i] = R.val[i];
  for (int i = 0; i < 12; ++i) out.P[i] = P.val[i];
  return out;
}

// Bouguet: the CameraInfo's own R and P (as image_proc does), so the maps match the P that
// stereo_image_proc reads from camera_info. Fusiello: the core computes R and P from the rig.
std::shared_ptr<const StereoMaps> buildMaps(const CalibrationKey& key, core::RectificationMethod method) {
  auto maps = std::make_shared<StereoMaps>(key);
  const cv::Size size(key.left.width, key.left.height);
  cv::Matx33d R1, R2;
  cv::Matx34d P1, P2;
  if (method == core::RectificationMethod::kBouguet) {
    R1 = matx33(key.left.R);
    R2 = matx33(key.right.R);
    P1 = matx34(key.left.P);
    P2 = matx34(key.right.P);
  } else {
    core::StereoRig rig;
    std::string error;
    if (!fromStereoCameraInfo(key.left, key.right, &rig, &error)) throw std::invalid_argument(error);
    core::RectificationOptions options;
    options.method = method;
    const core::RectificationGeometry g = core::computeRectificationGeometry(rig, options);
    R1 = g.R1;
    R2 = g.R2;
    P1 = g.P1;
    P2 = g.P2;
  }
  const auto build = [&size](const CameraInfo& info, const cv::Matx33d& R, const cv::Matx34d& P, cv::Mat* m1,
                             cv::Mat* m2) {
    cv::initUndistortRectifyMap(matx33(info.K), cv::Mat(info.D), R, P, size, CV_16SC2, *m1, *m2);
  };
  build(key.left, R1, P1, &maps->left_map1, &maps->left_map2);
  build(key.right, R2, P2, &maps->right_map1, &maps->right_map2);
  maps->left_rect = rectifiedInfo(key.left, R1, P1);
  maps->right_rect = rectifiedInfo(key.right, R2, P2);
  return maps;
}

}  // namespace

// Threads:
//  - the nodelet's (single-threaded) callback queue runs onInit, the connect callbacks and
//    frameCb; frameCb reads the publishers and the immutable options, and takes maps_mutex_ for
//    maps_, build_, building_key_ and failure_;
//  - a std::async worker runs buildMaps and stores its result under maps_mutex_ (maps_ is a
//    shared_ptr to immutable maps: a frame keeps its own reference while it is remapped);
//  - input_ (un)subscribes the inputs from the publishers' connect callbacks under its own mutex
//    (lazy_synced_input.h);
//  - modeCb (callback queue) and frameCb share epochs_ under epochs_mutex_; diagnostics_ reports
//    on a wall timer of the callback queue and guards its own counters.
class RectifierNodelet : public GuardedNodelet {
 public:
  RectifierNodelet() : GuardedNodelet("Rectifier") {}
  ~RectifierNodelet() override {
    std::future<void> build;
    {
      std::lock_guard<std::mutex> lock(maps_mutex_);
      build = std::move(build_);
    }
    if (build.valid()) build.wait();  // outside the lock: the worker takes it to store its result
  }

 private:


  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const ParameterReader read(pnh);
    const std::string method_name = read.get("rectification_method", "bouguet");
    try {
      method_ = core::parseRectificationMethod(method_name);
    } catch (const std::exception& e) {
      throw core::ConfigError("rectification_method", e.what());
    }
    const int queue_size = read.atLeast("queue_size", 5, 1);
    const bool approximate = read.get("approximate_sync", false);
    input_ = std::make_unique<StereoCameraInput>(
        nh, pnh, "image_scene", approximate, queue_size,
        [this](const auto& l, const auto& li, const auto& r, const auto& ri) { frameCb(l, li, r, ri); });
    image_transport::ImageTransport it(nh);
    const auto image_cb = input_->imageConnectCallback();
    const auto info_cb = input_->connectCallback();
    left_pub_ = it.advertise("left/image_rect", 1, image_cb, image_cb);
    right_pub_ = it.advertise("right/image_rect", 1, image_cb, image_cb);
    left_color_pub_ = it.advertise("left/image_rect_color", 1, image_cb, image_cb);
    right_color_pub_ = it.advertise("right/image_rect_color", 1, image_cb, image_cb);
    left_info_pub_ = nh.advertise<CameraInfo>("left/camera_info_rect", 1, info_cb, info_cb);
    right_info_pub_ = nh.advertise<CameraInfo>("right/camera_info_rect", 1, info_cb, info_cb);
    for (const image_transport::Publisher* pub : {&left_pub_, &right_pub_, &left_color_pub_, &right_color_pub_})
      input_->watch(*pub);
    input_->watch(left_info_pub_);
    input_->watch(right_info_pub_);
    diagnostics_ = std::make_unique<StageDiagnostics>(nh, pnh, "rectifier");
    diagnostics_->set("method", method_name);
    diagnostics_->set("maps", "none yet");
    // Only to name the epoch of the maps in the diagnostics (frames are matched to maps by their
    // CameraInfo, never by this).
    mode_sub_ = nh.subscribe("calibration_mode", 10, &RectifierNodelet::modeCb, this);
    input_->start();  // subscribes the inputs while someone listens to an output
    NODELET_INFO("Rectifier: %s rectification, %s sync, queue %d", method_name.c_str(),
                 approximate ? "approximate" : "exact", queue_size);
  }

  void reportError(const std::string& message) {
    if (errors_.shouldReport(message)) NODELET_ERROR("Rectifier: frame dropped: %s", message.c_str());
  }

  void modeCb(const CalibrationMode::ConstPtr& mode) {
    std::lock_guard<std::mutex> lock(epochs_mutex_);
    epochs_.emplace_back(mode->header.stamp, mode->calibration_epoch);
    if (epochs_.size() > 30) epochs_.pop_front();
  }

  // The calibration epoch of the frame of `stamp`, or "" when its calibration_mode was not seen.
  std::string epochOf(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(epochs_mutex_);
    for (const auto& e : epochs_)
      if (e.first == stamp) return std::to_string(e.second);
    return "";
  }

  void frameCb(const sensor_msgs::ImageConstPtr& left, const sensor_msgs::CameraInfoConstPtr& left_info,
               const sensor_msgs::ImageConstPtr& right, const sensor_msgs::CameraInfoConstPtr& right_info) {
    diagnostics_->frameIn();
    const auto start = std::chrono::steady_clock::now();
    std::string problem = input_->checkFrame(*left, *left_info, *right, *right_info);
    if (!problem.empty()) return reportError(problem);

    const std::shared_ptr<const StereoMaps> maps = mapsFor(CalibrationKey(*left_info, *right_info), &problem);
    if (!maps) {
      diagnostics_->set("maps", problem.empty() ? "building" : "failed: " + problem);
      if (!problem.empty()) reportError(input_->leftInfoTopic() + ", " + input_->rightInfoTopic() + ": " + problem);
      return;
    }
    try {
      publishRectified(*left, *right, *maps);
    } catch (const std::exception& e) {  // cv_bridge or OpenCV: skip the frame
      return reportError(input_->leftImageTopic() + ": " + e.what());
    }
    auto left_rect = boost::make_shared<CameraInfo>(maps->left_rect);
    auto right_rect = boost::make_shared<CameraInfo>(maps->right_rect);
    left_rect->header = left_info->header;
    right_rect->header = right_info->header;
    left_info_pub_.publish(left_rect);
    right_info_pub_.publish(right_rect);
    diagnostics_->framePublished(
        left->header.stamp, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
    diagnostics_->set("maps", "ready");
    const std::string epoch = epochOf(left->header.stamp);
    if (!epoch.empty()) diagnostics_->set("calibration epoch", epoch);
  }

  // The maps of `key` if they are ready; otherwise starts building them (one build at a time)
  // and returns null (with *problem set when this calibration failed to build).
  std::shared_ptr<const StereoMaps> mapsFor(const CalibrationKey& key, std::string* problem) {
    std::lock_guard<std::mutex> lock(maps_mutex_);
    if (maps_ && maps_->key == key) return maps_;
    if (failure_ && failure_->first == key) {
      *problem = failure_->second;
      return nullptr;
    }
    if (build_.valid() && build_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return nullptr;
    NODELET_INFO("Rectifier: calibration changed, building %s maps", core::toString(method_).c_str());
    build_ = std::async(std::launch::async, [this, key] {
      std::shared_ptr<const StereoMaps> maps;
      std::string error;
      try {
        maps = buildMaps(key, method_);
      } catch (const std::exception& e) {
        error = std::string("cannot rectify: ") + e.what();
      }
      std::lock_guard<std::mutex> lock(maps_mutex_);
      if (maps) {
        maps_ = maps;
        diagnostics_->set("maps built", std::to_string(++maps_built_));
      } else {
        failure_ = std::make_unique<std::pair<CalibrationKey, std::string>>(key, error);
      }
    });
    return nullptr;
  }

  // Remaps both images into new messages' own buffers (no extra copy; side by side, see
  // core::remapStereoPair), then publishes them; a message is not touched after publishing.
  void publishRectified(const Image& left, const Image& right, const StereoMaps& maps) {
    const boost::shared_ptr<void> no_owner;  // the callers hold the messages
    const cv_bridge::CvImageConstPtr left_in = cv_bridge::toCvShare(left, no_owner);
    const cv_bridge::CvImageConstPtr right_in = cv_bridge::toCvShare(right, no_owner);
    diagnostics_->checkShared(left_in->image, left);
    diagnostics_->checkShared(right_in->image, right);
    OutputImage left_out = newImageLike(left), right_out = newImageLike(right);
    core::remapStereoPair(left_in->image, right_in->image, maps.left_map1, maps.left_map2,
                         maps.right_map1, maps.right_map2, &left_out.view, &right_out.view);
    publishBoth(left_out, left_pub_, left_color_pub_);
    publishBoth(right_out, right_pub_, right_color_pub_);
  }

  // image_rect (mono8) and image_rect_color (the input's encoding) of one rectified image: the
  // same message when it is mono8, else a mono8 conversion made only while someone listens.
  static void publishBoth(const OutputImage& rectified, const image_transport::Publisher& mono,
                          const image_transport::Publisher& color) {
    const std::string& encoding = rectified.msg->encoding;
    if (encoding == sensor_msgs::image_encodings::MONO8) {
      mono.publish(rectified.msg);
      color.publish(rectified.msg);
      return;
    }
    if (mono.getNumSubscribers() > 0) {
      sensor_msgs::Image like;  // the header and size only
      like.header = rectified.msg->header;
      like.height = rectified.msg->height;
      like.width = rectified.msg->width;
      like.encoding = sensor_msgs::image_encodings::MONO8;
      OutputImage grey = newImageLike(like);
      const bool rgb = encoding == sensor_msgs::image_encodings::RGB8;
      cv::cvtColor(rectified.view, grey.view, rgb ? cv::COLOR_RGB2GRAY : cv::COLOR_BGR2GRAY);
      mono.publish(grey.msg);
    }
    color.publish(rectified.msg);
  }

  core::RectificationMethod method_ = core::RectificationMethod::kBouguet;
  std::unique_ptr<StereoCameraInput> input_;  // created in onInit, before any callback
  image_transport::Publisher left_pub_, right_pub_;              // image_rect: mono8
  image_transport::Publisher left_color_pub_, right_color_pub_;  // image_rect_color: the input's encoding
  ros::Publisher left_info_pub_, right_info_pub_;
  ErrorThrottle errors_{5.0};
  std::unique_ptr<StageDiagnostics> diagnostics_;  // created in onInit, before any callback
  ros::Subscriber mode_sub_;
  std::mutex epochs_mutex_;
  std::deque<std::pair<ros::Time, uint32_t>> epochs_;  // (stamp, calibration_epoch), newest last

  std::mutex maps_mutex_;
  std::shared_ptr<const StereoMaps> maps_;
  std::future<void> build_;
  std::unique_ptr<std::pair<CalibrationKey, std::string>> failure_;
  uint64_t maps_built_ = 0;  // under maps_mutex_
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::RectifierNodelet, nodelet::Nodelet)
