// rostest: the driver with the sim backend, launched by driver.launch.
#include <gtest/gtest.h>
#include <image_geometry/stereo_camera_model.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <nav_msgs/Odometry.h>
#include <std_srvs/SetBool.h>
#include <tf2_msgs/TFMessage.h>

#include <set>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using test_support::Collector;

namespace {

double param(const std::string& name, double fallback) {
  double v;
  return ros::param::get("~" + name, v) ? v : fallback;
}

bool waitForDriver(double timeout_s) {
  return ros::topic::waitForMessage<CalibrationMode>("calibration_mode", ros::Duration(timeout_s)) != nullptr;
}

}  // namespace

TEST(DriverSim, PublishesAtTheConfiguredRate) {
  ros::NodeHandle nh;
  const double fps = param("fps", 10.0);
  ASSERT_TRUE(waitForDriver(20.0)) << "no calibration_mode from the driver";
  Collector<sensor_msgs::Image> left(nh, "left/image_raw");
  const size_t frames = static_cast<size_t>(3 * fps) + 1;  // about 3 s of frames
  ASSERT_TRUE(left.waitForCount(frames, 3.0 * 3)) << "fewer than " << frames << " frames";
  const auto msgs = left.snapshot();
  const double span = (msgs.back()->header.stamp - msgs.front()->header.stamp).toSec();
  const double rate = (msgs.size() - 1) / span;
  std::printf("measured rate %.2f fps over %zu frames (configured %.1f)\n", rate, msgs.size(), fps);
  EXPECT_NEAR(rate, fps, 0.1 * fps);
}

TEST(DriverSim, LeftRightAndModeShareStamps) {
  ros::NodeHandle nh;
  ASSERT_TRUE(waitForDriver(20.0));
  Collector<sensor_msgs::Image> left(nh, "left/image_raw"), right(nh, "right/image_raw");
  Collector<sensor_msgs::CameraInfo> left_info(nh, "left/camera_info"), right_info(nh, "right/camera_info");
  Collector<CalibrationMode> mode(nh, "calibration_mode");
  ASSERT_TRUE(mode.waitForCount(12, 10.0));
  ASSERT_TRUE(left.waitForCount(12, 5.0));
  ASSERT_TRUE(right.waitForCount(12, 5.0));
  ASSERT_TRUE(left_info.waitForCount(12, 5.0));
  ASSERT_TRUE(right_info.waitForCount(12, 5.0));
  auto stamps = [](const auto& msgs) {
    std::set<ros::Time> s;
    for (const auto& m : msgs) s.insert(m->header.stamp);
    return s;
  };
  const auto l = stamps(left.snapshot()), r = stamps(right.snapshot()), li = stamps(left_info.snapshot()),
             ri = stamps(right_info.snapshot());
  const auto modes = mode.snapshot();
  // Subscriptions started at slightly different frames: compare away from the edges.
  for (size_t i = 2; i + 2 < modes.size(); ++i) {
    const ros::Time t = modes[i]->header.stamp;
    EXPECT_TRUE(l.count(t)) << "mode stamp " << t << " has no left image";
    EXPECT_TRUE(r.count(t)) << "mode stamp " << t << " has no right image";
    EXPECT_TRUE(li.count(t)) << "mode stamp " << t << " has no left camera_info";
    EXPECT_TRUE(ri.count(t)) << "mode stamp " << t << " has no right camera_info";
  }
  EXPECT_EQ(left.snapshot().front()->header.frame_id, "stereo_left_optical_frame");
  // stereo_image_proc convention (default right_in_left_frame): one frame id for both cameras.
  EXPECT_EQ(right.snapshot().front()->header.frame_id, "stereo_left_optical_frame");
  EXPECT_EQ(right_info.snapshot().front()->header.frame_id, "stereo_left_optical_frame");
  EXPECT_EQ(left.snapshot().front()->encoding, "mono8");
}

// Returns how many calibration_mode frames arrived after the call until light_on == on, and
// checks the settled flags of the frames from the switch on.
void checkSwitch(Collector<CalibrationMode>& mode, bool on, int settle_frames) {
  mode.clear();
  std_srvs::SetBool srv;
  srv.request.data = on;
  ASSERT_TRUE(ros::service::call("set_light", srv));
  EXPECT_TRUE(srv.response.success);
  ASSERT_TRUE(mode.waitFor(
      [&](const std::vector<CalibrationMode::ConstPtr>& m) {
        for (size_t i = 0; i < m.size(); ++i)
          if (m[i]->light_on == on) return m.size() >= i + settle_frames + 2;
        return false;
      },
      10.0));
  const auto m = mode.snapshot();
  size_t first = 0;
  while (m[first]->light_on != on) ++first;
  EXPECT_LE(first + 1, 2u) << "light switched only at frame " << first + 1 << " after set_light";
  EXPECT_FALSE(m[first]->settled) << "first frame after the switch is marked settled";
  for (int k = 0; k < settle_frames; ++k) EXPECT_FALSE(m[first + k]->settled) << k;
  EXPECT_TRUE(m[first + settle_frames]->settled);
  EXPECT_TRUE(m[first + settle_frames + 1]->settled);
  for (size_t i = first; i < m.size(); ++i) EXPECT_EQ(m[i]->light_on, on);
}

TEST(DriverSim, SetLightSwitchesWithinTwoFramesAndMarksSettling) {
  ros::NodeHandle nh;
  ASSERT_TRUE(waitForDriver(20.0));
  ASSERT_TRUE(ros::service::waitForService("set_light", ros::Duration(10.0)));
  Collector<CalibrationMode> mode(nh, "calibration_mode");
  ASSERT_TRUE(mode.waitForCount(2, 5.0));
  const int settle = static_cast<int>(param("settle_frames", 2));
  checkSwitch(mode, true, settle);
  checkSwitch(mode, false, settle);
}

TEST(DriverSim, GroundTruthAndDriftService) {
  ros::NodeHandle nh;
  ASSERT_TRUE(waitForDriver(20.0));
  std::string config_path;
  ASSERT_TRUE(ros::param::get("~sim_config", config_path));
  const core::SimRigConfig config = core::loadSimRigConfig(config_path);

  // Published calibration (no file yet: the nominal rig) and the truth both carry Tx.
  const auto left = ros::topic::waitForMessage<sensor_msgs::CameraInfo>("left/camera_info", ros::Duration(5));
  const auto right = ros::topic::waitForMessage<sensor_msgs::CameraInfo>("right/camera_info", ros::Duration(5));
  ASSERT_TRUE(left && right);
  image_geometry::StereoCameraModel model;
  ASSERT_TRUE(model.fromCameraInfo(left, right));
  EXPECT_NEAR(model.baseline(), config.rig.baseline(), 1e-9);

  Collector<sensor_msgs::CameraInfo> gt_left(nh, "ground_truth/left/camera_info"),
      gt_right(nh, "ground_truth/right/camera_info");
  Collector<embedded_calibration_stereo::StereoPatternObservation> observations(nh, "ground_truth/observations");
  Collector<sensor_msgs::Image> depth(nh, "ground_truth/left/depth"), scene(nh, "ground_truth/left/image_scene"),
      scene_right(nh, "ground_truth/right/image_scene");
  ASSERT_TRUE(gt_left.waitForCount(1, 5.0));
  ASSERT_TRUE(gt_right.waitForCount(1, 5.0));
  ASSERT_TRUE(observations.waitForCount(1, 5.0));
  ASSERT_TRUE(depth.waitForCount(1, 5.0));
  ASSERT_TRUE(scene.waitForCount(1, 5.0));
  ASSERT_TRUE(scene_right.waitForCount(1, 5.0));
  EXPECT_EQ(depth.snapshot().back()->encoding, "32FC1");
  EXPECT_EQ(gt_left.snapshot().back()->K[0], config.rig.left.fx);
  EXPECT_NEAR(gt_right.snapshot().back()->P[3], -gt_right.snapshot().back()->P[0] * config.rig.baseline(), 1e-6);

  // Zoom: the truth's focal length follows the drift request.
  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.03;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  const double zoomed = 1.03 * config.rig.left.fx;
  EXPECT_TRUE(gt_left.waitFor(
      [&](const std::vector<sensor_msgs::CameraInfo::ConstPtr>& m) { return std::abs(m.back()->K[0] - zoomed) < 1e-6; },
      5.0))
      << "ground truth fx stays " << gt_left.snapshot().back()->K[0] << ", expected " << zoomed;
  drift.request = embedded_calibration_stereo::SetRigDrift::Request();
  drift.request.focal_scale = 1.0;
  drift.request.reset = true;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  EXPECT_TRUE(drift.response.success);
}

// Scene time is frame index / fps, not the wall clock: under a thermal drift (a rotation of the
// right camera growing with scene time) the truth's rotation moves by exactly rate / fps per
// frame (an integer number of frames between two received messages); the wall clock would add
// the capture thread's wake-up jitter.
TEST(DriverSim, SceneTimeIsTheFrameIndexOverFps) {
  ros::NodeHandle nh;
  ASSERT_TRUE(waitForDriver(20.0));
  const double fps = param("fps", 10.0);
  const double rate_deg_per_s = 1.0;
  Collector<sensor_msgs::CameraInfo> gt_left(nh, "ground_truth/left/camera_info"),
      gt_right(nh, "ground_truth/right/camera_info");
  ASSERT_TRUE(gt_right.waitForCount(1, 5.0));
  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.0;
  drift.request.thermal_rate_deg_per_s = rate_deg_per_s;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  gt_left.clear();
  gt_right.clear();
  ASSERT_TRUE(gt_right.waitForCount(12, 5.0));
  ASSERT_TRUE(gt_left.waitForCount(12, 5.0));
  const auto lefts = gt_left.snapshot(), rights = gt_right.snapshot();
  drift.request.thermal_rate_deg_per_s = 0.0;
  drift.request.reset = true;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  EXPECT_TRUE(drift.response.success);

  // Rotation angle of right_from_left per message, pairing left and right by stamp.
  std::vector<std::pair<ros::Time, Eigen::Matrix3d>> rotations;
  for (const auto& r : rights)
    for (const auto& l : lefts)
      if (l->header.stamp == r->header.stamp) {
        core::StereoRig rig;
        std::string error;
        ASSERT_TRUE(embedded_calibration_stereo::fromStereoCameraInfo(*l, *r, &rig, &error)) << error;
        rotations.emplace_back(r->header.stamp, rig.right_from_left.rotation());
      }
  ASSERT_GE(rotations.size(), 8u);
  const double step_deg = rate_deg_per_s / fps;
  double worst = 0.0;
  for (size_t i = 1; i < rotations.size(); ++i) {
    const Eigen::AngleAxisd turn(rotations[i - 1].second.transpose() * rotations[i].second);
    const double frames = turn.angle() * 180.0 / M_PI / step_deg;
    EXPECT_GE(std::lround(frames), 1) << "message " << i;
    worst = std::max(worst, std::abs(frames - std::round(frames)));
  }
  std::printf("thermal drift between frames: largest departure from a whole number of frames %.2e\n", worst);
  // Rounding leaves ~1e-11; the wall clock's wake-up jitter (microseconds at least) >= 1e-5.
  EXPECT_LT(worst, 1e-7) << "the truth's rotation does not advance by whole frames of 1/fps";
}

// The head pose truth: on ground_truth/head_pose and /tf under the ground_truth/ prefix, stamped
// as the images. The default scenario's head is static: the world frame is the left optical
// frame at t = 0, so every pose is the identity and the velocity zero.
TEST(DriverSim, GroundTruthHeadPose) {
  ros::NodeHandle nh;
  ASSERT_TRUE(waitForDriver(20.0));
  Collector<sensor_msgs::Image> left(nh, "left/image_raw");
  Collector<nav_msgs::Odometry> pose(nh, "ground_truth/head_pose");
  Collector<tf2_msgs::TFMessage> tf(nh, "/tf");
  ASSERT_TRUE(pose.waitForCount(10, 5.0)) << "no ground_truth/head_pose";
  ASSERT_TRUE(tf.waitForCount(10, 5.0)) << "no /tf";
  ASSERT_TRUE(left.waitForCount(10, 5.0));
  std::set<ros::Time> image_stamps;
  for (const auto& m : left.snapshot()) image_stamps.insert(m->header.stamp);
  size_t matched = 0;
  for (const auto& m : pose.snapshot()) {
    EXPECT_EQ(m->header.frame_id, "ground_truth/world");
    EXPECT_EQ(m->child_frame_id, "ground_truth/stereo_left_optical_frame");
    matched += image_stamps.count(m->header.stamp);
    const auto& p = m->pose.pose;
    EXPECT_NEAR(p.position.x, 0.0, 1e-12);
    EXPECT_NEAR(p.position.y, 0.0, 1e-12);
    EXPECT_NEAR(p.position.z, 0.0, 1e-12);
    EXPECT_NEAR(std::abs(p.orientation.w), 1.0, 1e-12);
    const auto& v = m->twist.twist;
    EXPECT_NEAR(std::abs(v.linear.x) + std::abs(v.linear.y) + std::abs(v.linear.z), 0.0, 1e-12);
    EXPECT_NEAR(std::abs(v.angular.x) + std::abs(v.angular.y) + std::abs(v.angular.z), 0.0, 1e-12);
  }
  // Subscriptions start at slightly different frames: most, not all, poses have their image.
  EXPECT_GE(matched + 2, pose.snapshot().size()) << "head poses not stamped as the images";
  for (const auto& m : tf.snapshot())
    for (const auto& t : m->transforms) {
      EXPECT_EQ(t.header.frame_id, "ground_truth/world");
      EXPECT_EQ(t.child_frame_id, "ground_truth/stereo_left_optical_frame");
      EXPECT_NEAR(t.transform.translation.z, 0.0, 1e-12);
      EXPECT_NEAR(std::abs(t.transform.rotation.w), 1.0, 1e-12);
    }
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "driver_sim_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
