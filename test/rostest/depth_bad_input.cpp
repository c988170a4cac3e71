// rostest: bad inputs of the Rectifier and Disparity nodelets (depth_bad_input.test).
#include <dynamic_reconfigure/Reconfigure.h>
#include <gtest/gtest.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <stereo_msgs/DisparityImage.h>

#include <opencv2/core.hpp>
#include <set>

#include "driver_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using sensor_msgs::CameraInfo;
using sensor_msgs::Image;

namespace {

constexpr double kBaseline = 0.1;

struct Side {
  std::string encoding = "mono8";
  int width = 160, height = 120;
  bool calibrated = true;
  std::string frame_id = "cam";
  bool truncated = false;  // data shorter than height x step
};

Image::Ptr makeImage(const Side& s, const ros::Time& stamp) {
  auto msg = boost::make_shared<Image>();
  msg->header.stamp = stamp;
  msg->header.frame_id = s.frame_id;
  msg->encoding = s.encoding;
  msg->width = s.width;
  msg->height = s.height;
  const size_t pixel = s.encoding == "mono8" ? 1 : s.encoding == "bgr8" ? 3 : 4;  // 32FC1: 4
  msg->step = static_cast<uint32_t>(s.width * pixel);
  msg->data.resize(size_t(msg->step) * s.height);
  cv::Mat bytes(1, static_cast<int>(msg->data.size()), CV_8U, msg->data.data());
  cv::RNG rng(7);  // the same texture on both sides: disparity 0 everywhere
  rng.fill(bytes, cv::RNG::UNIFORM, 0, 256);
  if (s.truncated) msg->data.resize(msg->data.size() / 2);
  return msg;
}

CameraInfo::Ptr makeInfo(const Side& s, bool right, const ros::Time& stamp) {
  auto info = boost::make_shared<CameraInfo>();
  info->header.stamp = stamp;
  info->header.frame_id = s.frame_id;
  info->width = s.width;
  info->height = s.height;
  info->distortion_model = "plumb_bob";
  info->D.assign(5, 0.0);
  if (!s.calibrated) return info;  // K, R, P all zero
  const double f = 100, cx = s.width / 2.0, cy = s.height / 2.0;
  info->K = {f, 0, cx, 0, f, cy, 0, 0, 1};
  info->R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  info->P = {f, 0, cx, right ? -f * kBaseline : 0.0, 0, f, cy, 0, 0, 0, 1, 0};
  return info;
}

// Publishes frames of (left, right) on `image_topic`/camera_info of each side.
class FramePublisher {
 public:
  FramePublisher(ros::NodeHandle& nh, const std::string& image_name) {
    left_image_ = nh.advertise<Image>("left/" + image_name, 5);
    right_image_ = nh.advertise<Image>("right/" + image_name, 5);
    left_info_ = nh.advertise<CameraInfo>("left/camera_info", 5);
    right_info_ = nh.advertise<CameraInfo>("right/camera_info", 5);
  }
  // Returns the frame's stamp.
  ros::Time publish(const Side& left, const Side& right) {
    const ros::Time stamp = ros::Time::now();
    left_image_.publish(makeImage(left, stamp));
    left_info_.publish(makeInfo(left, false, stamp));
    right_image_.publish(makeImage(right, stamp));
    right_info_.publish(makeInfo(right, true, stamp));
    return stamp;
  }

 private:
  ros::Publisher left_image_, right_image_, left_info_, right_info_;
};

// Publishes the frame at 10 Hz (the pace of the feed, not a synchronisation) until `done`
// or the timeout; the stamps published are added to *stamps when given.
bool publishUntil(FramePublisher& pub, const Side& left, const Side& right, const std::function<bool()>& done,
                  double timeout_s, std::set<ros::Time>* stamps = nullptr) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout_s);
  ros::WallRate rate(10.0);
  while (ros::WallTime::now() < end) {
    const ros::Time stamp = pub.publish(left, right);
    if (stamps) stamps->insert(stamp);
    if (done()) return true;
    rate.sleep();
  }
  return done();
}

template <class Output>
bool hasStampIn(const std::vector<boost::shared_ptr<const Output>>& msgs, const std::set<ros::Time>& stamps) {
  for (const auto& m : msgs)
    if (stamps.count(m->header.stamp)) return true;
  return false;
}

template <class Output>
void expectRejected(const std::string& image_name, const std::string& output, const Side& left, const Side& right,
                    const std::vector<std::string>& needles) {
  ros::NodeHandle nh;
  Collector<Output> out(nh, output);  // subscribing makes the lazy nodelet subscribe its inputs
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 1000);
  FramePublisher pub(nh, image_name);
  std::string found;
  std::set<ros::Time> bad_stamps, good_stamps;
  const bool logged = publishUntil(
      pub, left, right, [&] { return test_support::waitForLog(log, needles, 0.0, &found); }, 15.0, &bad_stamps);
  EXPECT_TRUE(logged) << "no /rosout error containing all of: " << ::testing::PrintToString(needles);
  // Control: valid frames after the bad ones, until the output of one of them arrives. The
  // nodelet handles its input in order, so by then every bad frame has been handled. The pipe
  // is connected by now (the error came), so a few seconds are ample for a 160x120 frame.
  const bool control = publishUntil(
      pub, Side(), Side(), [&] { return hasStampIn(out.snapshot(), good_stamps); }, 5.0, &good_stamps);
  ASSERT_TRUE(control) << "no " << output << " for the valid control frames: the pipe does not work";
  EXPECT_FALSE(hasStampIn(out.snapshot(), bad_stamps)) << output << " published for a bad frame";
  if (logged) std::printf("error seen: %s\n", found.c_str());
}

template <class Output>
void expectAccepted(const std::string& image_name, const std::string& output) {
  ros::NodeHandle nh;
  Collector<Output> out(nh, output);
  FramePublisher pub(nh, image_name);
  EXPECT_TRUE(publishUntil(
      pub, Side(), Side(), [&] { return !out.snapshot().empty(); }, 15.0))
      << "no " << output << " for a valid frame";
}

Side withEncoding(const std::string& e) {
  Side s;
  s.encoding = e;
  return s;
}
Side withWidth(int w) {
  Side s;
  s.width = w;
  return s;
}
Side truncated() {
  Side s;
  s.truncated = true;
  return s;
}
Side uncalibrated() {
  Side s;
  s.calibrated = false;
  return s;
}

}  // namespace

TEST(RectifierBadInput, ValidFrameIsRectified) { expectAccepted<Image>("image_scene", "left/image_rect"); }
TEST(RectifierBadInput, SizeMismatch) {
  expectRejected<Image>("image_scene", "left/image_rect", Side(), withWidth(128), {"right/image_scene", "size"});
}
TEST(RectifierBadInput, EncodingMismatch) {
  expectRejected<Image>("image_scene", "left/image_rect", Side(), withEncoding("bgr8"),
                        {"right/image_scene", "encoding"});
}
TEST(RectifierBadInput, UncalibratedCameraInfo) {
  expectRejected<Image>("image_scene", "left/image_rect", uncalibrated(), Side(),
                        {"left/camera_info", "uncalibrated"});
}
// Both images unreadable in every frame: each camera's topic is named (the left camera's error,
// which comes first, must not hide the right camera's).
TEST(RectifierBadInput, MalformedImagesOfBothCamerasAreBothNamed) {
  expectRejected<Image>("image_scene", "left/image_rect", truncated(), truncated(),
                        {"image dropped on", "left/image_scene", "fewer than height x step"});
  expectRejected<Image>("image_scene", "left/image_rect", truncated(), truncated(),
                        {"image dropped on", "right/image_scene", "fewer than height x step"});
}
TEST(RectifierBadInput, UnsupportedEncoding) {
  expectRejected<Image>("image_scene", "left/image_rect", withEncoding("32FC1"), withEncoding("32FC1"),
                        {"left/image_scene", "unsupported encoding"});
}

using stereo_msgs::DisparityImage;
TEST(DisparityBadInput, ValidFrameGivesDisparity) { expectAccepted<DisparityImage>("image_rect", "disparity"); }
TEST(DisparityBadInput, SizeMismatch) {
  expectRejected<DisparityImage>("image_rect", "disparity", Side(), withWidth(128), {"right/image_rect", "size"});
}
TEST(DisparityBadInput, EncodingMismatch) {
  expectRejected<DisparityImage>("image_rect", "disparity", Side(), withEncoding("bgr8"),
                                 {"right/image_rect", "encoding"});
}
TEST(DisparityBadInput, UncalibratedCameraInfo) {
  expectRejected<DisparityImage>("image_rect", "disparity", Side(), uncalibrated(),
                                 {"right/camera_info", "uncalibrated"});
}
// image_geometry::StereoCameraModel asserts equal frame ids (and aborts in this build): refused.
TEST(DisparityBadInput, FrameIdMismatch) {
  Side right;
  right.frame_id = "other";
  expectRejected<DisparityImage>("image_rect", "disparity", Side(), right, {"right/camera_info", "frame id"});
}
TEST(DisparityBadInput, UnsupportedEncoding) {
  expectRejected<DisparityImage>("image_rect", "disparity", withEncoding("32FC1"), withEncoding("32FC1"),
                                 {"left/image_rect", "unsupported encoding"});
}

int intParameter(const dynamic_reconfigure::Config& config, const std::string& name) {
  for (const auto& p : config.ints)
    if (p.name == name) return p.value;
  ADD_FAILURE() << "no parameter " << name << " in the returned config";
  return -1;
}

// dynamic_reconfigure values the matcher cannot use are clamped, with a warning, and the
// clamped values are what the server reports; disparity still flows.
TEST(DisparityReconfigure, InvalidRangeAndWindowAreClampedWithAWarning) {
  ros::NodeHandle nh;
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 1000);
  ASSERT_TRUE(ros::service::waitForService("disparity/set_parameters", ros::Duration(10)));
  dynamic_reconfigure::Reconfigure srv;
  dynamic_reconfigure::IntParameter range, window;
  range.name = "disparity_range";
  range.value = 40;  // not a multiple of 16
  window.name = "correlation_window_size";
  window.value = 6;  // even
  srv.request.config.ints = {range, window};
  // Repeated until /rosout (connected asynchronously) has delivered the warning.
  bool logged = false;
  for (int attempt = 0; attempt < 20 && !logged; ++attempt) {
    ASSERT_TRUE(ros::service::call("disparity/set_parameters", srv));
    EXPECT_EQ(intParameter(srv.response.config, "disparity_range"), 48);
    EXPECT_EQ(intParameter(srv.response.config, "correlation_window_size") % 2, 1);
    logged = test_support::waitForLog(log, {"clamped", "disparity_range 40 -> 48"}, 0.5);
  }
  EXPECT_TRUE(logged) << "no clamping warning on /rosout";
  expectAccepted<stereo_msgs::DisparityImage>("image_rect", "disparity");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "depth_bad_input_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
