// rostest: the stereo stages' input synchronisation and laziness, and the Disparity's
// dynamic_reconfigure refusals (stereo_stages.test). The stages run in a manager of their own
// process; the test feeds crafted frames and reads the master's subscriber lists.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <dynamic_reconfigure/Reconfigure.h>
#include <gtest/gtest.h>
#include <ros/master.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/Trigger.h>
#include <stereo_msgs/DisparityImage.h>

#include <algorithm>
#include <functional>
#include <opencv2/core.hpp>
#include <set>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using test_support::Collector;
using test_support::waitUntil;
using sensor_msgs::CameraInfo;
using sensor_msgs::Image;
using stereo_msgs::DisparityImage;

namespace {

constexpr int kWidth = 160, kHeight = 120;
const ros::Duration kSkew(0.003);  // right stamp - left stamp of the mismatched pairs

Image::Ptr makeImage(const ros::Time& stamp) {
  auto msg = boost::make_shared<Image>();
  msg->header.stamp = stamp;
  msg->header.frame_id = "cam";
  msg->encoding = "mono8";
  msg->width = kWidth;
  msg->height = kHeight;
  msg->step = kWidth;
  msg->data.resize(size_t(kWidth) * kHeight);
  cv::Mat bytes(1, static_cast<int>(msg->data.size()), CV_8U, msg->data.data());
  cv::RNG rng(7);  // the same texture on both sides
  rng.fill(bytes, cv::RNG::UNIFORM, 0, 256);
  return msg;
}

CameraInfo::Ptr makeInfo(const ros::Time& stamp, bool right) {
  auto info = boost::make_shared<CameraInfo>();
  info->header.stamp = stamp;
  info->header.frame_id = "cam";
  info->width = kWidth;
  info->height = kHeight;
  info->distortion_model = "plumb_bob";
  info->D.assign(5, 0.0);
  const double f = 100, cx = kWidth / 2.0, cy = kHeight / 2.0;
  info->K = {f, 0, cx, 0, f, cy, 0, 0, 1};
  info->R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  info->P = {f, 0, cx, right ? -f * 0.1 : 0.0, 0, f, cy, 0, 0, 0, 1, 0};
  return info;
}


enum class Stage { kSeparator, kRectifier, kDisparity };

// Publishes the inputs of one stage: left at `left_stamp`, right (and the right CameraInfo) at
// `right_stamp`; the Separator's calibration_mode (light off) carries the left stamp.
class Feeder {
 public:
  Feeder(ros::NodeHandle& nh, Stage stage) : stage_(stage) {
    const std::string image = stage == Stage::kSeparator ? "image_raw"
                              : stage == Stage::kRectifier ? "image_scene"
                                                           : "image_rect";
    left_ = nh.advertise<Image>("left/" + image, 5);
    right_ = nh.advertise<Image>("right/" + image, 5);
    if (stage == Stage::kSeparator) {
      mode_ = nh.advertise<CalibrationMode>("calibration_mode", 5);
    } else {
      left_info_ = nh.advertise<CameraInfo>("left/camera_info", 5);
      right_info_ = nh.advertise<CameraInfo>("right/camera_info", 5);
    }
  }
  // Every input is connected to its subscriber.
  bool connected() const {
    bool all = left_.getNumSubscribers() > 0 && right_.getNumSubscribers() > 0;
    if (stage_ == Stage::kSeparator) return all && mode_.getNumSubscribers() > 0;
    return all && left_info_.getNumSubscribers() > 0 && right_info_.getNumSubscribers() > 0;
  }
  void publish(const ros::Time& left_stamp, const ros::Time& right_stamp) {
    left_.publish(makeImage(left_stamp));
    right_.publish(makeImage(right_stamp));
    if (stage_ == Stage::kSeparator) {
      auto mode = boost::make_shared<CalibrationMode>();
      mode->header.stamp = left_stamp;
      mode->light_on = false;
      mode->settled = true;
      mode_.publish(mode);
    } else {
      left_info_.publish(makeInfo(left_stamp, false));
      right_info_.publish(makeInfo(right_stamp, true));
    }
  }

 private:
  Stage stage_;
  ros::Publisher left_, right_, left_info_, right_info_, mode_;
};

// Publishes one frame per call of `frame` at 10 Hz (the pace of a camera, not a synchronisation)
// until `done` or the timeout.
bool feedUntil(const std::function<void()>& frame, const std::function<bool()>& done, double timeout_s) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout_s);
  ros::WallRate rate(10.0);
  while (ros::WallTime::now() < end) {
    frame();
    if (done()) return true;
    rate.sleep();
  }
  return done();
}

const char* outputTopic(Stage stage) {
  return stage == Stage::kSeparator ? "left/image_scene" : stage == Stage::kRectifier ? "left/image_rect" : "disparity";
}

template <class Output>
std::vector<ros::Time> outputStamps(Collector<Output>& out) {
  std::vector<ros::Time> stamps;
  for (const auto& m : out.snapshot()) stamps.push_back(m->header.stamp);
  return stamps;
}

size_t countIn(const std::vector<ros::Time>& stamps, const std::set<ros::Time>& wanted) {
  return std::count_if(stamps.begin(), stamps.end(), [&](const ros::Time& t) { return wanted.count(t) > 0; });
}

// approximate_sync true: pairs 3 ms apart come out (stamped as their left image).
template <class Output>
void expectMismatchedPairsJoined(const std::string& ns, Stage stage) {
  ros::NodeHandle nh(ns);
  Collector<Output> out(nh, outputTopic(stage));  // a listener: the lazy stage subscribes its inputs
  Feeder feed(nh, stage);
  ASSERT_TRUE(waitUntil([&] { return feed.connected(); }, 15.0)) << ns << ": the inputs were not subscribed";
  std::set<ros::Time> lefts;
  const bool joined = feedUntil(
      [&] {
        const ros::Time t = ros::Time::now();
        lefts.insert(t);
        feed.publish(t, t + kSkew);
      },
      [&] { return countIn(outputStamps(out), lefts) >= 3; }, 20.0);
  EXPECT_TRUE(joined) << ns << ": fewer than 3 outputs for pairs " << kSkew.toSec() * 1e3
                      << " ms apart with approximate_sync";
  std::printf("%s: %zu outputs from %zu pairs %.0f ms apart\n", ns.c_str(), countIn(outputStamps(out), lefts),
              lefts.size(), kSkew.toSec() * 1e3);
}

// approximate_sync false: pairs 3 ms apart give nothing; a control pair of equal stamps, sent
// after them on the same connections, comes out.
template <class Output>
void expectOnlyExactPairsJoined(const std::string& ns, Stage stage) {
  ros::NodeHandle nh(ns);
  Collector<Output> out(nh, outputTopic(stage));
  Feeder feed(nh, stage);
  ASSERT_TRUE(waitUntil([&] { return feed.connected(); }, 15.0)) << ns << ": the inputs were not subscribed";
  std::set<ros::Time> mismatched, control;
  ros::WallRate rate(10.0);  // a camera's pace: each pair could be joined before the next one
  for (int i = 0; i < 10; ++i, rate.sleep()) {
    const ros::Time t = ros::Time::now();
    mismatched.insert(t);
    mismatched.insert(t + kSkew);
    feed.publish(t, t + kSkew);
  }
  const bool control_out = feedUntil(
      [&] {
        const ros::Time t = ros::Time::now();
        control.insert(t);
        feed.publish(t, t);
      },
      [&] { return countIn(outputStamps(out), control) > 0; }, 20.0);
  ASSERT_TRUE(control_out) << ns << ": no output for pairs of equal stamps (control)";
  EXPECT_EQ(countIn(outputStamps(out), mismatched), 0u) << ns << ": output for a pair 3 ms apart without "
                                                                   "approximate_sync";
  std::printf("%s: %zu outputs for %zu equal-stamp pairs, %zu for 10 pairs 3 ms apart\n", ns.c_str(),
              countIn(outputStamps(out), control), control.size(), countIn(outputStamps(out), mismatched));
}

}  // namespace

TEST(ApproximateSync, SeparatorJoinsPairsAFewMsApart) {
  expectMismatchedPairsJoined<Image>("/approx_separator", Stage::kSeparator);
}
TEST(ApproximateSync, SeparatorWithoutItJoinsOnlyEqualStamps) {
  expectOnlyExactPairsJoined<Image>("/exact_separator", Stage::kSeparator);
}
TEST(ApproximateSync, RectifierJoinsPairsAFewMsApart) {
  expectMismatchedPairsJoined<Image>("/approx_rectifier", Stage::kRectifier);
}
TEST(ApproximateSync, RectifierWithoutItJoinsOnlyEqualStamps) {
  expectOnlyExactPairsJoined<Image>("/exact_rectifier", Stage::kRectifier);
}
TEST(ApproximateSync, DisparityJoinsPairsAFewMsApart) {
  expectMismatchedPairsJoined<DisparityImage>("/approx_disparity", Stage::kDisparity);
}
TEST(ApproximateSync, DisparityWithoutItJoinsOnlyEqualStamps) {
  expectOnlyExactPairsJoined<DisparityImage>("/exact_disparity", Stage::kDisparity);
}

namespace {

// The nodes the master lists as subscribers of `topic`.
std::set<std::string> subscribersOf(const std::string& topic) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  std::set<std::string> nodes;
  if (!ros::master::execute("getSystemState", args, result, payload, true)) {
    ADD_FAILURE() << "getSystemState failed";
    return nodes;
  }
  XmlRpc::XmlRpcValue& subscribers = payload[1];
  for (int i = 0; i < subscribers.size(); ++i) {
    if (static_cast<std::string>(subscribers[i][0]) != topic) continue;
    for (int j = 0; j < subscribers[i][1].size(); ++j) nodes.insert(static_cast<std::string>(subscribers[i][1][j]));
  }
  return nodes;
}

const std::vector<std::string> kLazyInputs = {"/lazy/left/image_raw", "/lazy/right/image_raw", "/lazy/calibration_mode",
                                              "/lazy/ground_truth/left/image_scene",
                                              "/lazy/ground_truth/right/image_scene"};
constexpr const char* kManager = "/stages_manager";

// The number of the Separator's inputs its manager subscribes to.
size_t lazyInputsSubscribed() {
  size_t n = 0;
  for (const std::string& topic : kLazyInputs) n += subscribersOf(topic).count(kManager);
  return n;
}

}  // namespace

// The Separator (teach_from_ground_truth: frame and ground-truth inputs) subscribes nothing until
// someone subscribes to image_scene, unsubscribes when nobody listens any more, and subscribes
// for a teach requested without a listener.
TEST(SeparatorLaziness, SubscribesOnlyForAListenerOrATeach) {
  ros::NodeHandle nh;
  // Its diagnostics come from a timer started in onInit: the Separator is up, onInit done.
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics(nh, "/diagnostics", 1000);
  ASSERT_TRUE(diagnostics.waitFor(
      [](const std::vector<diagnostic_msgs::DiagnosticArray::ConstPtr>& arrays) {
        for (const auto& a : arrays)
          for (const auto& s : a->status)
            if (s.name.rfind("lazy/separator", 0) == 0) return true;
        return false;
      },
      30.0))
      << "no diagnostics from the lazy Separator";
  EXPECT_EQ(lazyInputsSubscribed(), 0u) << "inputs subscribed without a listener";

  {
    Collector<Image> listener(nh, "/lazy/left/image_scene");
    EXPECT_TRUE(waitUntil([] { return lazyInputsSubscribed() == kLazyInputs.size(); }, 15.0))
        << "a listener of image_scene did not make the Separator subscribe all its inputs ("
        << lazyInputsSubscribed() << " of " << kLazyInputs.size() << ")";
  }
  EXPECT_TRUE(waitUntil([] { return lazyInputsSubscribed() == 0; }, 15.0))
      << "inputs still subscribed after the last listener left (" << lazyInputsSubscribed() << ")";

  std_srvs::Trigger teach;
  ASSERT_TRUE(ros::service::call("/lazy/separator/teach", teach));
  EXPECT_TRUE(waitUntil([] { return lazyInputsSubscribed() == kLazyInputs.size(); }, 15.0))
      << "a teach without listener did not subscribe the inputs (" << lazyInputsSubscribed() << ")";
}

// A learning Separator (device_template learn) with no listener subscribes its inputs until it
// has learned its first template: the first burst must be seen from its start.
TEST(SeparatorLaziness, ALearningSeparatorSubscribesUntilItsFirstTemplate) {
  const std::vector<std::string> inputs = {"/learning/left/image_raw", "/learning/right/image_raw",
                                           "/learning/calibration_mode"};
  const auto subscribed = [&] {
    size_t n = 0;
    for (const std::string& topic : inputs) n += subscribersOf(topic).count(kManager);
    return n;
  };
  EXPECT_TRUE(waitUntil([&] { return subscribed() == inputs.size(); }, 30.0))
      << "a learning Separator without a template did not subscribe its inputs (" << subscribed() << " of "
      << inputs.size() << ")";
}

namespace {

template <class Parameter>
const Parameter* find(const std::vector<Parameter>& parameters, const std::string& name) {
  for (const auto& p : parameters)
    if (p.name == name) return &p;
  ADD_FAILURE() << "no parameter " << name << " in the returned config";
  return nullptr;
}

int intParameter(const dynamic_reconfigure::Config& config, const std::string& name) {
  const auto* p = find(config.ints, name);
  return p ? p->value : -1;
}

std::string stringParameter(const dynamic_reconfigure::Config& config, const std::string& name) {
  const auto* p = find(config.strs, name);
  return p ? p->value : "";
}

dynamic_reconfigure::IntParameter intValue(const std::string& name, int value) {
  dynamic_reconfigure::IntParameter p;
  p.name = name;
  p.value = value;
  return p;
}

// The first disparity output, fed until one satisfies `accept`.
DisparityImage::ConstPtr disparityWhere(Feeder& feed, Collector<DisparityImage>& out,
                                        const std::function<bool(const DisparityImage&)>& accept) {
  DisparityImage::ConstPtr found;
  feedUntil(
      [&] {
        const ros::Time t = ros::Time::now();
        feed.publish(t, t);
      },
      [&] {
        for (const auto& m : out.snapshot())
          if (accept(*m)) found = m;
        return found != nullptr;
      },
      20.0);
  return found;
}

}  // namespace

// Values the Disparity cannot use (an unknown algorithm, a range not a multiple of 16, an even
// window) are replaced, with one warning naming each; the server reports the values in force and
// the output follows them (min/max disparity, and the valid window of stereo_image_proc's
// definition: x from range + min + window/2 - 1), a value set before and not sent again is kept,
// and disparity keeps flowing.
TEST(DisparityReconfigure, UnusableValuesAreReplacedWithAWarningAndTheRestKept) {
  ros::NodeHandle nh("/reconfigure");
  Collector<DisparityImage> out(nh, "disparity", 1000);
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 1000);
  Feeder feed(nh, Stage::kDisparity);
  ASSERT_TRUE(ros::service::waitForService("/reconfigure/disparity/set_parameters", ros::Duration(20)));
  // Control: the initial configuration (launch: sad, range 16) is in force.
  const auto first = disparityWhere(feed, out, [](const DisparityImage&) { return true; });
  ASSERT_TRUE(first) << "no disparity with the initial configuration";
  EXPECT_EQ(first->min_disparity, 0);
  EXPECT_EQ(first->max_disparity, 15);

  dynamic_reconfigure::Reconfigure valid;
  valid.request.config.ints = {intValue("min_disparity", 2)};
  ASSERT_TRUE(ros::service::call("/reconfigure/disparity/set_parameters", valid));
  EXPECT_EQ(intParameter(valid.response.config, "min_disparity"), 2);

  dynamic_reconfigure::Reconfigure bad;
  dynamic_reconfigure::StrParameter algorithm;
  algorithm.name = "algorithm";
  algorithm.value = "census";
  bad.request.config.strs = {algorithm};
  bad.request.config.ints = {intValue("disparity_range", 40), intValue("correlation_window_size", 6)};
  // Repeated until /rosout (connected asynchronously) has delivered the warnings.
  bool logged = false;
  std::string found;
  for (int attempt = 0; attempt < 20 && !logged; ++attempt) {
    ASSERT_TRUE(ros::service::call("/reconfigure/disparity/set_parameters", bad));
    logged = test_support::waitForLog(log, {"clamped", "algorithm census -> sgbm"}, 0.5, &found) &&
             test_support::waitForLog(log, {"clamped", "disparity_range 40 -> 48"}, 0.5) &&
             test_support::waitForLog(log, {"clamped", "correlation_window_size 6 -> 7"}, 0.5);
  }
  EXPECT_TRUE(logged) << "no warning naming each replaced value on /rosout";
  std::printf("warning: %s\n", found.c_str());
  const dynamic_reconfigure::Config& reported = bad.response.config;
  EXPECT_EQ(stringParameter(reported, "algorithm"), "sgbm");
  EXPECT_EQ(intParameter(reported, "disparity_range"), 48);
  EXPECT_EQ(intParameter(reported, "correlation_window_size"), 7);
  EXPECT_EQ(intParameter(reported, "min_disparity"), 2) << "a value not sent again was changed";

  // The running matcher uses what the server reports (frames stamped after the call).
  const ros::Time reconfigured = ros::Time::now();
  const auto after =
      disparityWhere(feed, out, [&](const DisparityImage& m) { return m.header.stamp > reconfigured; });
  ASSERT_TRUE(after) << "no disparity after the reconfiguration";
  EXPECT_EQ(after->min_disparity, 2);
  EXPECT_EQ(after->max_disparity, 2 + 48 - 1);
  EXPECT_EQ(after->valid_window.x_offset, 48u + 2u + 7u / 2u - 1u);
  EXPECT_EQ(after->valid_window.y_offset, 7u / 2u);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "stereo_stages_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
