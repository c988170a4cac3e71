// rostest: CameraInfo pairs that would abort image_geometry, on the whole simulated head
// (calibration_pair_mismatch.test). The head's disparity is the witness that the manager (one
// process for every nodelet) is alive.
#include <gtest/gtest.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/SetCameraInfo.h>
#include <stereo_msgs/DisparityImage.h>

#include <filesystem>
#include <functional>
#include <limits>
#include <opencv2/core.hpp>

#include "calibration_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using sensor_msgs::CameraInfo;
using sensor_msgs::Image;
using stereo_msgs::DisparityImage;

namespace {

// The head's disparity keeps coming: `n` more messages within `timeout_s`.
bool headDisparityFlows(Collector<DisparityImage>& disparity, size_t n, double timeout_s) {
  return disparity.waitForCount(disparity.snapshot().size() + n, timeout_s);
}

// A crafted 160x120 stereo frame (same random texture on both sides) with a valid rectified
// CameraInfo pair of one frame id; `corrupt` spoils the pair.
struct CraftedFrames {
  CraftedFrames(const std::string& ns, const std::string& image_name) {
    ros::NodeHandle nh(ns);
    left_image = nh.advertise<Image>("left/" + image_name, 5);
    right_image = nh.advertise<Image>("right/" + image_name, 5);
    left_info = nh.advertise<CameraInfo>("left/camera_info", 5);
    right_info = nh.advertise<CameraInfo>("right/camera_info", 5);
  }
  void publish(const std::function<void(CameraInfo&, CameraInfo&)>& corrupt) {
    const ros::Time stamp = ros::Time::now();
    auto image = boost::make_shared<Image>();
    image->header.stamp = stamp;
    image->header.frame_id = "cam";
    image->encoding = "mono8";
    image->width = 160;
    image->height = 120;
    image->step = 160;
    image->data.resize(160 * 120);
    cv::Mat bytes(1, static_cast<int>(image->data.size()), CV_8U, image->data.data());
    cv::RNG rng(7);
    rng.fill(bytes, cv::RNG::UNIFORM, 0, 256);
    CameraInfo infos[2];
    for (int i = 0; i < 2; ++i) {
      CameraInfo& info = infos[i];
      info.header = image->header;
      info.width = 160;
      info.height = 120;
      info.distortion_model = "plumb_bob";
      info.D.assign(5, 0.0);
      info.K = {100, 0, 80, 0, 100, 60, 0, 0, 1};
      info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
      info.P = {100, 0, 80, i == 1 ? -10.0 : 0.0, 0, 100, 60, 0, 0, 0, 1, 0};
    }
    if (corrupt) corrupt(infos[0], infos[1]);
    left_image.publish(image);
    right_image.publish(image);
    left_info.publish(boost::make_shared<CameraInfo>(infos[0]));
    right_info.publish(boost::make_shared<CameraInfo>(infos[1]));
  }
  ros::Publisher left_image, right_image, left_info, right_info;
};

// Feeds frames at 10 Hz (the pace of the feed, not a synchronisation) until `done`.
bool feedUntil(CraftedFrames& frames, const std::function<void(CameraInfo&, CameraInfo&)>& corrupt,
               const std::function<bool()>& done, double timeout_s) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout_s);
  ros::WallRate rate(10.0);
  while (ros::WallTime::now() < end) {
    frames.publish(corrupt);
    if (done()) return true;
    rate.sleep();
  }
  return done();
}

struct BadPair {
  std::string name;
  std::function<void(CameraInfo&, CameraInfo&)> corrupt;
  std::vector<std::string> needles;  // the error names the topic and the field
};

std::vector<BadPair> badPairs(const std::string& ns) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  return {
      {"right fx' differs",
       [](CameraInfo&, CameraInfo& r) { r.P[0] = 104.0; },
       {ns + "/right/camera_info", "fx' (P[0])"}},
      {"right binning 1000",
       [](CameraInfo&, CameraInfo& r) { r.binning_x = r.binning_y = 1000; },
       {ns + "/right/camera_info", "binning"}},
      {"left cy' differs",
       [](CameraInfo& l, CameraInfo&) { l.P[6] = 61.0; },
       {ns + "/right/camera_info", "cy' (P[6])"}},
      {"NaN in the left R", [nan](CameraInfo& l, CameraInfo&) { l.R[4] = nan; }, {ns + "/left/camera_info", "R[4]"}},
      {"NaN in the right P", [nan](CameraInfo&, CameraInfo& r) { r.P[5] = nan; }, {ns + "/right/camera_info", "P[5]"}},
  };
}

// Each bad pair on the topics of the stage in `ns`: an error naming topic and field, no output,
// the head's disparity still flowing; then a good pair gives output again.
template <class Output>
void expectDroppedAndResumed(const std::string& ns, const std::string& image_name, const std::string& output) {
  ros::NodeHandle nh("/stereo");
  Collector<DisparityImage> head(nh, "disparity", 10);
  ASSERT_TRUE(head.waitForCount(1, 30.0)) << "control: no disparity from the head";
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 2000);
  CraftedFrames frames(ns, image_name);
  for (const BadPair& bad : badPairs(ns)) {
    SCOPED_TRACE(ns + ": " + bad.name);
    Collector<Output> out(nh, ns + "/" + output);  // subscribing makes the lazy stage subscribe
    log.clear();
    std::string found;
    EXPECT_TRUE(feedUntil(
        frames, bad.corrupt, [&] { return test_support::waitForLog(log, bad.needles, 0.0, &found); }, 15.0))
        << "no error naming " << ::testing::PrintToString(bad.needles);
    feedUntil(
        frames, bad.corrupt, [] { return false; }, 1.0);
    EXPECT_EQ(out.snapshot().size(), 0u) << output << " published from a bad pair";
    EXPECT_TRUE(headDisparityFlows(head, 3, 10.0)) << "the manager died";
    std::printf("  %-20s -> %s\n", bad.name.c_str(), found.c_str());
    EXPECT_TRUE(feedUntil(
        frames, nullptr, [&] { return !out.snapshot().empty(); }, 15.0))
        << "no " << output << " from the next good pair";
  }
}

}  // namespace

TEST(CalibrationPairMismatch, DisparityDropsBadPairsAndResumes) {
  expectDroppedAndResumed<DisparityImage>("/fed_disparity", "image_rect", "disparity");
}

TEST(CalibrationPairMismatch, RectifierDropsBadPairsAndResumes) {
  expectDroppedAndResumed<Image>("/fed_rectifier", "image_scene", "left/image_rect");
}

// The OnlineCalibrator reads the calibration in force from left|right/camera_info: a pair of one
// stamp whose P disagree (published here beside the driver's) is dropped with an error naming
// the topic and the field; the head goes on.
TEST(CalibrationPairMismatch, OnlineCalibratorDropsABadPair) {
  ros::NodeHandle nh("/stereo");
  Collector<DisparityImage> head(nh, "disparity", 10);
  Collector<CameraInfo> left(nh, "left/camera_info", 10), right(nh, "right/camera_info", 10);
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 2000);
  ASSERT_TRUE(head.waitForCount(1, 30.0)) << "control: no disparity from the head";
  ASSERT_TRUE(left.waitForCount(1, 5.0));
  ASSERT_TRUE(right.waitForCount(1, 5.0));
  ros::Publisher left_pub = nh.advertise<CameraInfo>("left/camera_info", 5);
  ros::Publisher right_pub = nh.advertise<CameraInfo>("right/camera_info", 5);
  const std::vector<std::string> needles = {"OnlineCalibrator", "/stereo/right/camera_info", "fx' (P[0])"};
  std::string found;
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(15.0);
  ros::WallRate rate(10.0);
  while (ros::WallTime::now() < end && !test_support::waitForLog(log, needles, 0.0, &found)) {
    auto l = boost::make_shared<CameraInfo>(*left.snapshot().back());
    auto r = boost::make_shared<CameraInfo>(*right.snapshot().back());
    l->header.stamp = r->header.stamp = ros::Time::now();  // a stamp of no driver frame
    r->P[0] *= 1.03;
    left_pub.publish(l);
    right_pub.publish(r);
    rate.sleep();
  }
  EXPECT_TRUE(test_support::waitForLog(log, needles, 0.0, &found)) << "no error from the OnlineCalibrator";
  std::printf("  %s\n", found.c_str());
  EXPECT_TRUE(headDisparityFlows(head, 3, 10.0)) << "the manager died";
}

// set_camera_info of one camera alone (camera_calibration run on the left camera): staged, the
// depth chain never sees it, and after the pair timeout it is discarded with an ERROR; binning
// is refused; then a stereo calibration (left, then right) goes through and depth resumes
// with it.
TEST(CalibrationPairMismatch, SetCameraInfoOfOneCameraNeverStopsDepth) {
  ros::NodeHandle nh("/stereo");
  std::string dir;
  ASSERT_TRUE(ros::param::get("/stereo/calibration_dir", dir));
  Collector<DisparityImage> head(nh, "disparity", 10);
  Collector<CameraInfo> left(nh, "left/camera_info", 10), right(nh, "right/camera_info", 10);
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics(nh, "/diagnostics", 200);
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 2000);
  ASSERT_TRUE(head.waitForCount(1, 30.0)) << "control: no disparity from the head";
  ASSERT_TRUE(left.waitForCount(1, 5.0));
  ASSERT_TRUE(right.waitForCount(1, 5.0));
  const CameraInfo left_before = *left.snapshot().back(), right_before = *right.snapshot().back();

  sensor_msgs::SetCameraInfo srv;
  srv.request.camera_info = left_before;
  srv.request.camera_info.P[0] *= 1.03;  // a P of its own for the left camera, R kept: half of a new pair
  srv.request.camera_info.P[5] *= 1.03;
  ASSERT_TRUE(ros::service::call("left/set_camera_info", srv));
  std::printf("  left alone: success %d, %s\n", srv.response.success, srv.response.status_message.c_str());
  EXPECT_TRUE(srv.response.success);
  EXPECT_EQ(srv.response.status_message.rfind("staged:", 0), 0u) << srv.response.status_message;
  EXPECT_TRUE(headDisparityFlows(head, 5, 15.0)) << "depth stopped (the manager died?)";
  EXPECT_EQ(left.snapshot().back()->P[0], left_before.P[0]) << "a half pair was published";
  std::string found;
  EXPECT_TRUE(test_support::waitForLog(log, {"staged left calibration discarded"}, 10.0, &found));
  EXPECT_TRUE(test_support::waitForDriverStatus(diagnostics, diagnostic_msgs::DiagnosticStatus::ERROR,
                                            "staged left calibration discarded", 5.0));
  EXPECT_EQ(test_support::shownFocals(dir + "/left.yaml", dir + "/right.yaml"), std::make_pair(-1.0, -1.0))
      << "a calibration file was written";

  srv.request.camera_info = right_before;
  srv.request.camera_info.binning_x = srv.request.camera_info.binning_y = 1000;
  ASSERT_TRUE(ros::service::call("right/set_camera_info", srv));
  EXPECT_FALSE(srv.response.success);
  EXPECT_NE(srv.response.status_message.find("binning"), std::string::npos) << srv.response.status_message;
  EXPECT_TRUE(headDisparityFlows(head, 3, 10.0)) << "depth stopped (the manager died?)";

  // A stereo calibration: both cameras' focal lengths 2 % longer, left then right.
  CameraInfo new_left = left_before, new_right = right_before;
  for (CameraInfo* info : {&new_left, &new_right})
    for (const int i : {0, 4}) info->K[i] *= 1.02;
  for (CameraInfo* info : {&new_left, &new_right})
    for (const int i : {0, 3, 5}) info->P[i] *= 1.02;
  for (const bool is_left : {true, false}) {
    srv.request.camera_info = is_left ? new_left : new_right;
    ASSERT_TRUE(ros::service::call(std::string(is_left ? "left" : "right") + "/set_camera_info", srv));
    EXPECT_TRUE(srv.response.success) << srv.response.status_message;
  }
  EXPECT_TRUE(head.waitFor([&](const auto& m) { return std::abs(m.back()->f - new_right.P[0]) < 1e-3; }, 15.0))
      << "no disparity with the new calibration";
  const auto shown = test_support::shownFocals(dir + "/left.yaml", dir + "/right.yaml");
  EXPECT_NEAR(shown.first, new_left.P[0], 1e-3);
  EXPECT_NEAR(shown.second, new_right.P[0], 1e-3);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibration_pair_mismatch_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  std::string dir;  // the launch file's temporary calibration folder
  if (ros::param::get("/stereo/calibration_dir", dir) && dir.rfind("/tmp/", 0) == 0) std::filesystem::remove_all(dir);
  return result;
}
