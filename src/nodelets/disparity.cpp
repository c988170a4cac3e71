// Disparity nodelet: disparity, points2 and disparity_mask of rectified stereo frames with
// stereo_image_proc's topic and parameter names; the matcher is the core's DisparityComputer,
// configured by dynamic_reconfigure. Topics, parameters and behaviour: docs/nodelets.md#disparity.
#include <cv_bridge/cv_bridge.h>
#include <dynamic_reconfigure/server.h>
#include <image_geometry/stereo_camera_model.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <stereo_msgs/DisparityImage.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <memory>
#include <mutex>

#include "embedded_calibration_stereo/DisparityConfig.h"
#include "embedded_calibration_stereo/DisparityCoverage.h"
#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/stage_diagnostics.h"
#include "embedded_calibration_stereo/ros/stereo_camera_input.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

namespace {

using sensor_msgs::CameraInfo;
using sensor_msgs::Image;

core::DisparityOptions toOptions(const DisparityConfig& c) {
  core::DisparityOptions o;
  // stereo_image_proc's stereo_algorithm, when set, wins (its parameter files carry it).
  o.algorithm = c.stereo_algorithm == 0 ? "bm" : c.stereo_algorithm == 1 ? "sgbm" : c.algorithm;
  o.prefilter_size = c.prefilter_size;
  o.prefilter_cap = c.prefilter_cap;
  o.correlation_window_size = c.correlation_window_size;
  o.min_disparity = c.min_disparity;
  o.disparity_range = c.disparity_range;
  o.uniqueness_ratio = c.uniqueness_ratio;
  o.texture_threshold = c.texture_threshold;
  o.speckle_size = c.speckle_size;
  o.speckle_range = c.speckle_range;
  o.P1 = static_cast<int>(std::lround(c.P1));
  o.P2 = static_cast<int>(std::lround(c.P2));
  o.disp12MaxDiff = c.disp12MaxDiff;
  o.sgbm_mode = c.fullDP ? "hh" : c.sgbm_mode;  // stereo_image_proc: fullDP = MODE_HH
  o.left_right_check = c.lr_check;
  o.subpixel = c.subpixel;
  o.fill_holes = c.hole_filling;
  o.sgm_census_threshold = c.sgm_census_threshold;
  o.sgm_paths = c.sgm_paths;
  o.sgm_P1 = c.sgm_P1;
  o.sgm_P2 = c.sgm_P2;
  o.sgm_edge_scale = c.sgm_edge_scale;
  o.median_size = c.median_size;
  return o;
}

void toConfig(const core::DisparityOptions& o, DisparityConfig* c) {
  c->algorithm = o.algorithm;
  c->prefilter_size = o.prefilter_size;
  c->prefilter_cap = o.prefilter_cap;
  c->correlation_window_size = o.correlation_window_size;
  c->min_disparity = o.min_disparity;
  c->disparity_range = o.disparity_range;
  c->uniqueness_ratio = o.uniqueness_ratio;
  c->texture_threshold = o.texture_threshold;
  c->speckle_size = o.speckle_size;
  c->speckle_range = o.speckle_range;
  c->P1 = o.P1;
  c->P2 = o.P2;
  c->disp12MaxDiff = o.disp12MaxDiff;
  if (!c->fullDP) c->sgbm_mode = o.sgbm_mode;
  c->sgm_census_threshold = o.sgm_census_threshold;
  c->sgm_paths = o.sgm_paths;
  c->sgm_P1 = o.sgm_P1;
  c->sgm_P2 = o.sgm_P2;
  c->sgm_edge_scale = o.sgm_edge_scale;
  c->median_size = o.median_size;
}

// A mono8 view of a mono8 (shared, no copy) or colour (converted) image.
cv::Mat monoView(const sensor_msgs::ImageConstPtr& msg) {
  if (msg->encoding == "mono8") return cv_bridge::toCvShare(msg)->image;
  return cv_bridge::toCvShare(msg, "mono8")->image;
}

// RGB of the left pixel packed in a float, as stereo_image_proc's point_cloud2 does.
float packedRgb(const cv::Mat& image, const std::string& encoding, int u, int v) {
  uint8_t r, g, b;
  if (encoding == "mono8") {
    r = g = b = image.at<uint8_t>(v, u);
  } else {
    const cv::Vec3b& p = image.at<cv::Vec3b>(v, u);
    const bool bgr = encoding == "bgr8";
    r = p[bgr ? 2 : 0];
    g = p[1];
    b = p[bgr ? 0 : 2];
  }
  const uint32_t rgb = (uint32_t(r) << 16) | (uint32_t(g) << 8) | uint32_t(b);
  float packed;
  std::memcpy(&packed, &rgb, sizeof(packed));
  return packed;
}

}  // namespace

// Threads:
//  - the nodelet's (single-threaded) callback queue runs onInit, the connect callbacks, the
//    dynamic_reconfigure callback and frameCb;
//  - computer_mutex_ guards computer_ (replaced by configCb, used by frameCb) so the class stays
//    correct should the callbacks ever run on a multi-threaded queue;
//  - input_ (un)subscribes the inputs from the publishers' connect callbacks under its own mutex
//    (lazy_synced_input.h);
//  - diagnostics_ reports on a wall timer of the callback queue and guards its own counters.
class DisparityNodelet : public GuardedNodelet {
 public:
  DisparityNodelet() : GuardedNodelet("Disparity") {}

 private:


  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const ParameterReader read(pnh);
    const int queue_size = read.atLeast("queue_size", 5, 1);
    const bool approximate = read.get("approximate_sync", false);
    checkReconfigureTypes<DisparityConfig>(read);  // the server would ignore a wrongly typed value
    input_ = std::make_unique<StereoCameraInput>(
        nh, pnh, "image_rect", approximate, queue_size,
        [this](const auto& l, const auto& li, const auto& r, const auto& ri) { frameCb(l, li, r, ri); });
    diagnostics_ = std::make_unique<StageDiagnostics>(nh, pnh, "disparity");
    reconfigure_ = std::make_unique<dynamic_reconfigure::Server<DisparityConfig>>(reconfigure_mutex_, pnh);
    reconfigure_->setCallback([this](DisparityConfig& config, uint32_t) { configCb(config); });

    const auto cb = input_->connectCallback();
    disparity_pub_ = nh.advertise<stereo_msgs::DisparityImage>("disparity", 1, cb, cb);
    points_pub_ = nh.advertise<sensor_msgs::PointCloud2>("points2", 1, cb, cb);
    mask_pub_ = nh.advertise<Image>("disparity_mask", 1, cb, cb);
    // Not watched: listening to the coverage alone does not start the matcher.
    coverage_pub_ = nh.advertise<DisparityCoverage>("disparity_coverage", 5);
    input_->watch(disparity_pub_);
    input_->watch(points_pub_);
    input_->watch(mask_pub_);
    input_->start();  // subscribes the inputs while someone listens to an output
  }

  // Invalid values are clamped (with a warning) and the clamped values shown in the config.
  void configCb(DisparityConfig& config) {
    core::DisparityOptions options = toOptions(config);
    const std::vector<std::string> changes = options.clamp();
    for (const auto& change : changes) NODELET_WARN("Disparity: parameter clamped: %s", change.c_str());
    toConfig(options, &config);
    try {
      auto computer = std::make_unique<core::DisparityComputer>(options);
      std::lock_guard<std::mutex> lock(computer_mutex_);
      computer_ = std::move(computer);
      diagnostics_->set("algorithm", options.algorithm);
      diagnostics_->set("disparities", std::to_string(options.min_disparity) + ".." +
                                           std::to_string(options.min_disparity + options.disparity_range - 1));
      NODELET_INFO("Disparity: %s, disparities %d..%d, window %d", options.algorithm.c_str(), options.min_disparity,
                   options.min_disparity + options.disparity_range - 1, options.correlation_window_size);
    } catch (const std::exception& e) {  // clamp() makes this unreachable unless the core disagrees
      NODELET_ERROR("Disparity: configuration refused, keeping the previous one: %s", e.what());
    }
  }

  void reportError(const std::string& message) {
    if (errors_.shouldReport(message)) NODELET_ERROR("Disparity: frame dropped: %s", message.c_str());
  }

  void frameCb(const sensor_msgs::ImageConstPtr& left, const sensor_msgs::CameraInfoConstPtr& left_info,
               const sensor_msgs::ImageConstPtr& right, const sensor_msgs::CameraInfoConstPtr& right_info) {
    diagnostics_->frameIn();
    const auto start = std::chrono::steady_clock::now();
    std::string problem = input_->checkFrame(*left, *left_info, *right, *right_info);
    if (problem.empty())
      problem = checkSameFrame(*left_info, input_->leftInfoTopic(), *right_info, input_->rightInfoTopic());
    if (!problem.empty()) return reportError(problem);
    // The checks above are what image_geometry asserts (abort in this build); the pair may differ
    // by round-off in fx', fy', cy', which image_geometry compares exactly.
    sensor_msgs::CameraInfo aligned_right = *right_info;
    alignRectifiedPair(*left_info, &aligned_right);
    image_geometry::StereoCameraModel model;
    model.fromCameraInfo(*left_info, aligned_right);

    // The matcher writes straight into the outgoing message's buffer (NaN where invalid); the
    // cloud is made from it, then invalid pixels get stereo_image_proc's value, then both go out.
    stereo_msgs::DisparityImagePtr disparity_msg;
    sensor_msgs::ImagePtr mask_msg;
    cv::Mat disparity, mask;
    core::DisparityOptions options;
    try {
      const cv::Mat left_mono = monoView(left), right_mono = monoView(right);
      diagnostics_->checkShared(left_mono, *left);
      diagnostics_->checkShared(right_mono, *right);
      std::lock_guard<std::mutex> lock(computer_mutex_);
      if (!computer_) return;
      options = computer_->options();
      disparity_msg = newDisparityMsg(left_mono.size(), options, model, *left_info, &disparity);
      if (mask_pub_.getNumSubscribers() > 0) mask_msg = newMaskMsg(left_mono.size(), *left_info, &mask);
      computer_->compute(left_mono, right_mono, &disparity, mask_msg ? &mask : nullptr);
    } catch (const std::exception& e) {  // e.g. an image narrower than the disparity range
      return reportError(input_->leftImageTopic() + ": " + e.what());
    }
    if (coverage_pub_.getNumSubscribers() > 0) {
      auto coverage = boost::make_shared<DisparityCoverage>();
      coverage->header = left_info->header;
      coverage->valid_fraction = static_cast<float>(cv::countNonZero(disparity == disparity)) /
                                 static_cast<float>(disparity.total());  // NaN != NaN: invalid
      coverage_pub_.publish(coverage);
    }
    sensor_msgs::PointCloud2Ptr cloud;
    if (points_pub_.getNumSubscribers() > 0) cloud = toPointCloud(disparity, model, left, *left_info);
    if (disparity_pub_.getNumSubscribers() > 0) {
      markInvalid(&disparity, static_cast<float>(options.min_disparity - 1));
      disparity_pub_.publish(disparity_msg);
    }
    if (cloud) points_pub_.publish(cloud);
    if (mask_msg) mask_pub_.publish(mask_msg);
    diagnostics_->framePublished(
        left->header.stamp, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
  }

  // stereo_image_proc's DisparityImage (32FC1) for an image of `size`, its pixels not yet
  // written; *pixels is set to a header over them.
  static stereo_msgs::DisparityImagePtr newDisparityMsg(cv::Size size, const core::DisparityOptions& o,
                                                        const image_geometry::StereoCameraModel& model,
                                                        const CameraInfo& left_info, cv::Mat* pixels) {
    auto msg = boost::make_shared<stereo_msgs::DisparityImage>();
    msg->header = left_info.header;
    Image& image = msg->image;
    image.header = left_info.header;
    image.height = size.height;
    image.width = size.width;
    image.encoding = "32FC1";
    image.step = image.width * sizeof(float);
    image.data.resize(static_cast<size_t>(image.step) * image.height);
    *pixels = cv::Mat(size, CV_32FC1, image.data.data(), image.step);
    msg->f = model.right().fx();
    msg->T = model.baseline();
    msg->min_disparity = o.min_disparity;
    msg->max_disparity = o.min_disparity + o.disparity_range - 1;
    msg->delta_d = o.subpixel ? 1.0f / 16 : 1.0f;
    // The window where a match is possible, as stereo_image_proc computes it.
    const int border = o.windowRadius();
    const int left = o.disparity_range + o.min_disparity + border - 1;
    const int wtf = o.min_disparity >= 0 ? border + o.min_disparity : std::max(border, -o.min_disparity);
    const int right = size.width - wtf;
    const int top = border, bottom = size.height - border;
    msg->valid_window.x_offset = std::max(left, 0);
    msg->valid_window.y_offset = std::max(top, 0);
    msg->valid_window.width = std::max(right - left, 0);
    msg->valid_window.height = std::max(bottom - top, 0);
    return msg;
  }

  // A mono8 image for the disparity's mask, its pixels not yet written; *pixels is set to a
  // header over them.
  static sensor_msgs::ImagePtr newMaskMsg(cv::Size size, const CameraInfo& left_info, cv::Mat* pixels) {
    auto msg = boost::make_shared<Image>();
    msg->header = left_info.header;
    msg->height = size.height;
    msg->width = size.width;
    msg->encoding = "mono8";
    msg->step = msg->width;
    msg->data.resize(static_cast<size_t>(msg->step) * msg->height);
    *pixels = cv::Mat(size, CV_8UC1, msg->data.data(), msg->step);
    return msg;
  }

  // stereo_image_proc's convention: invalid pixels hold min_disparity - 1 (the core's are NaN).
  static void markInvalid(cv::Mat* disparity, float invalid) { cv::patchNaNs(*disparity, invalid); }

  // xyz (metres, rectified left frame) + rgb; invalid points are NaN (not dense).
  static sensor_msgs::PointCloud2Ptr toPointCloud(const cv::Mat& disparity,
                                                  const image_geometry::StereoCameraModel& model,
                                                  const sensor_msgs::ImageConstPtr& left, const CameraInfo& left_info) {
    auto cloud = boost::make_shared<sensor_msgs::PointCloud2>();
    cloud->header = left_info.header;
    cloud->height = disparity.rows;
    cloud->width = disparity.cols;
    cloud->is_bigendian = false;
    cloud->is_dense = false;
    sensor_msgs::PointCloud2Modifier modifier(*cloud);
    modifier.setPointCloud2FieldsByString(2, "xyz", "rgb");
    const cv::Matx44d Q = model.reprojectionMatrix();
    const cv::Mat colour = cv_bridge::toCvShare(left)->image;
    const float nan = std::numeric_limits<float>::quiet_NaN();
    sensor_msgs::PointCloud2Iterator<float> x(*cloud, "x"), y(*cloud, "y"), z(*cloud, "z"), rgb(*cloud, "rgb");
    for (int v = 0; v < disparity.rows; ++v) {
      const float* d = disparity.ptr<float>(v);
      for (int u = 0; u < disparity.cols; ++u, ++x, ++y, ++z, ++rgb) {
        // image_geometry's Q is scaled (Q(0,0) = fy * Tx, ...): apply it in full.
        const cv::Vec4d p = Q * cv::Vec4d(u, v, d[u], 1.0);
        if (!core::isValidDisparity(d[u]) || !(p[2] / p[3] > 0)) {
          *x = *y = *z = nan;
        } else {
          *x = static_cast<float>(p[0] / p[3]);
          *y = static_cast<float>(p[1] / p[3]);
          *z = static_cast<float>(p[2] / p[3]);
        }
        *rgb = packedRgb(colour, left->encoding, u, v);
      }
    }
    return cloud;
  }

  std::unique_ptr<StereoCameraInput> input_;  // created in onInit, before any callback
  ros::Publisher disparity_pub_, points_pub_, mask_pub_, coverage_pub_;
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<DisparityConfig>> reconfigure_;
  ErrorThrottle errors_{5.0};
  std::unique_ptr<StageDiagnostics> diagnostics_;  // created in onInit, before any callback

  std::mutex computer_mutex_;
  std::unique_ptr<core::DisparityComputer> computer_;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::DisparityNodelet, nodelet::Nodelet)
