// render_scenario_bag, run as users run it (a child process, no ROS master): a short bag holds
// the driver's topics with the stamps, light windows and drift the options ask for, checked
// against the options (not against the tool's own code); bad input stops it with an error
// naming the option or the key.
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <nav_msgs/Odometry.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/sim/trajectory.h"
#include "embedded_calibration_stereo/test_support/run_command.h"

namespace core = embedded_calibration_stereo::core;

namespace {

const std::string kConfig = std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml";

struct Result {
  int status = -1;
  std::string output;  // stdout and stderr
};

Result runTool(const std::string& args) {
  Result r;
  r.status = core::runCommand(std::string(ECS_RENDER_SCENARIO_BAG) + " " + args + " 2>&1", &r.output);
  return r;
}

struct TempDir {
  TempDir() {
    char name[] = "/tmp/ecs_scenario_bag_XXXXXX";
    path = ::mkdtemp(name) ? name : "";
  }
  ~TempDir() {
    if (!path.empty()) std::filesystem::remove_all(path);
  }
  std::string path;
};

void writeFile(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

// The topics of launch/record.launch ground_truth:=true that the driver publishes, with their types.
const std::map<std::string, std::string>& driverTopics() {
  static const std::map<std::string, std::string> topics = {
      {"/stereo/left/image_raw", "sensor_msgs/Image"},
      {"/stereo/right/image_raw", "sensor_msgs/Image"},
      {"/stereo/left/camera_info", "sensor_msgs/CameraInfo"},
      {"/stereo/right/camera_info", "sensor_msgs/CameraInfo"},
      {"/stereo/calibration_mode", "embedded_calibration_stereo/CalibrationMode"},
      {"/stereo/ground_truth/left/image_scene", "sensor_msgs/Image"},
      {"/stereo/ground_truth/right/image_scene", "sensor_msgs/Image"},
      {"/stereo/ground_truth/left/camera_info", "sensor_msgs/CameraInfo"},
      {"/stereo/ground_truth/right/camera_info", "sensor_msgs/CameraInfo"},
      {"/stereo/ground_truth/observations", "embedded_calibration_stereo/StereoPatternObservation"},
      {"/stereo/ground_truth/head_pose", "nav_msgs/Odometry"},
      {"/tf", "tf2_msgs/TFMessage"}};
  return topics;
}

// What a 10 fps bag from stamp 1000 s holds per frame; each message's stamp, frame and fields
// are checked as it is read.
struct BagSeries {
  std::vector<bool> light, settled;  // calibration_mode
  std::vector<double> truth_fx;      // ground_truth/left/camera_info
  std::map<std::string, size_t> counts;
};

BagSeries readSeries(rosbag::View& view, const core::SimRigConfig& config) {
  BagSeries out;
  for (const rosbag::MessageInstance& m : view) {
    ++out.counts[m.getTopic()];
    const size_t k = out.counts[m.getTopic()] - 1;  // frame index of this topic's message
    const ros::Time expected_stamp = ros::Time(1000.0) + ros::Duration(k / 10.0);
    EXPECT_EQ(m.getTime(), expected_stamp) << m.getTopic() << " #" << k;
    if (auto image = m.instantiate<sensor_msgs::Image>()) {
      EXPECT_EQ(image->header.stamp, expected_stamp);
      EXPECT_EQ(image->header.frame_id, "stereo_left_optical_frame") << m.getTopic();
      EXPECT_EQ(image->encoding, "mono8");
      EXPECT_EQ(static_cast<int>(image->width), config.rig.left.width);
    } else if (auto mode = m.instantiate<embedded_calibration_stereo::CalibrationMode>()) {
      EXPECT_EQ(mode->header.stamp, expected_stamp);
      out.light.push_back(mode->light_on);
      out.settled.push_back(mode->settled);
    } else if (auto info = m.instantiate<sensor_msgs::CameraInfo>()) {
      EXPECT_EQ(info->header.stamp, expected_stamp);
      if (m.getTopic() == "/stereo/ground_truth/left/camera_info") out.truth_fx.push_back(info->K[0]);
      if (m.getTopic() == "/stereo/left/camera_info") {
        EXPECT_EQ(info->K[0], config.rig.left.fx);  // nominal
      }
    } else if (auto odom = m.instantiate<nav_msgs::Odometry>()) {
      EXPECT_EQ(odom->header.frame_id, "ground_truth/world");
      EXPECT_EQ(odom->child_frame_id, "ground_truth/stereo_left_optical_frame");
      EXPECT_EQ(odom->header.stamp, expected_stamp);
    } else if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) {
      EXPECT_EQ(tf->transforms.size(), 1u);
      if (!tf->transforms.empty()) {
        EXPECT_EQ(tf->transforms[0].child_frame_id, "ground_truth/stereo_left_optical_frame");
      }
    }
  }
  return out;
}

}  // namespace

TEST(RenderScenarioBag, WritesTheDriversTopicsWithTheScheduleAndTheDrift) {
  TempDir dir;
  ASSERT_FALSE(dir.path.empty());
  const std::string bag_path = dir.path + "/short.bag";
  // 2 s at 10 fps, a window every 1 s (3 settled frames after 1 settling frame), a 3 % zoom at 1.45 s.
  writeFile(dir.path + "/drift.yaml", "- {time_s: 1.45, focal_scale: 1.03}\n");
  const Result r = runTool("--config " + kConfig + " --out " + bag_path + " --seconds 2 --fps 10 --period 1" +
                           " --calibration-frames 3 --settle-frames 1 --start 1000 --drift " + dir.path +
                           "/drift.yaml");
  ASSERT_EQ(r.status, 0) << r.output;
  std::printf("%s", r.output.c_str());
  EXPECT_NE(r.output.find("wrote " + bag_path), std::string::npos) << r.output;
  ASSERT_TRUE(std::filesystem::exists(bag_path));
  EXPECT_FALSE(std::filesystem::exists(bag_path + ".active"));

  const core::SimRigConfig config = core::loadSimRigConfig(kConfig);
  rosbag::Bag bag(bag_path, rosbag::bagmode::Read);
  rosbag::View view(bag);
  std::map<std::string, std::string> types;
  for (const rosbag::ConnectionInfo* c : view.getConnections()) types[c->topic] = c->datatype;
  const std::map<std::string, std::string>& expected = driverTopics();
  EXPECT_EQ(types, expected);

  const BagSeries series = readSeries(view, config);
  const std::vector<bool>& light = series.light;
  const std::vector<bool>& settled = series.settled;
  const std::vector<double>& truth_fx = series.truth_fx;
  std::map<std::string, size_t> counts = series.counts;
  for (const auto& [topic, type] : expected) EXPECT_EQ(counts[topic], 20u) << topic;
  // Windows at frames 0 and 10 (every 1 s from the first frame): 1 settling + 3 settled frames on.
  std::vector<bool> expected_light(20, false), expected_settled(20, true);
  for (int start : {0, 10}) {
    for (int k = start; k < start + 4; ++k) expected_light[k] = true;
    expected_settled[start] = false;      // switched on
    expected_settled[start + 4] = false;  // switched off
  }
  EXPECT_EQ(light, expected_light);
  EXPECT_EQ(settled, expected_settled);
  // The zoom at 1.45 s: the truth's fx is nominal up to frame 14 (1.4 s) and 1.03 x from frame 15.
  ASSERT_EQ(truth_fx.size(), 20u);
  for (size_t k = 0; k < truth_fx.size(); ++k)
    EXPECT_NEAR(truth_fx[k], (k < 15 ? 1.0 : 1.03) * config.rig.left.fx, 1e-9) << "frame " << k;
}

// A moving head (drive_photo): ground_truth/head_pose and /tf of frame k are the scenario's
// trajectory evaluated here at k / fps, and the twist is the velocity of that trajectory
// half-way through the frame period (by a fine central difference in the world, independent of
// the tool's frame-to-frame difference).
TEST(RenderScenarioBag, HeadPoseFollowsTheTrajectory) {
  const std::string scenario = std::string(ECS_SOURCE_DIR) + "/config/drive_photo.yaml";
  const core::SimRigConfig config = core::loadSimRigConfig(scenario);
  ASSERT_FALSE(config.trajectory.isStatic()) << "drive_photo should move";
  TempDir dir;
  ASSERT_FALSE(dir.path.empty());
  const std::string bag_path = dir.path + "/drive.bag";
  const double fps = 10.0;
  const Result r = runTool("--config " + scenario + " --out " + bag_path + " --seconds 1.5 --fps 10 --start 50");
  ASSERT_EQ(r.status, 0) << r.output;
  rosbag::Bag bag(bag_path, rosbag::bagmode::Read);
  size_t k = 0, tf_count = 0;
  double largest_move_m = 0.0;
  for (const rosbag::MessageInstance& m :
       rosbag::View(bag, rosbag::TopicQuery(std::vector<std::string>{"/stereo/ground_truth/head_pose", "/tf"}))) {
    if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) {
      ASSERT_EQ(tf->transforms.size(), 1u);
      const double t = (tf->transforms[0].header.stamp - ros::Time(50.0)).toSec();
      const Eigen::Isometry3d truth = core::trajectoryPose(config.trajectory, t);
      const auto& tr = tf->transforms[0].transform.translation;
      EXPECT_NEAR((Eigen::Vector3d(tr.x, tr.y, tr.z) - truth.translation()).norm(), 0.0, 1e-9) << "tf at " << t;
      ++tf_count;
      continue;
    }
    const auto odom = m.instantiate<nav_msgs::Odometry>();
    ASSERT_TRUE(odom);
    const double t = k / fps;
    EXPECT_NEAR((odom->header.stamp - ros::Time(50.0)).toSec(), t, 1e-6);
    const Eigen::Isometry3d truth = core::trajectoryPose(config.trajectory, t);
    const auto& p = odom->pose.pose;
    const Eigen::Quaterniond q(p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z);
    EXPECT_NEAR((Eigen::Vector3d(p.position.x, p.position.y, p.position.z) - truth.translation()).norm(), 0.0, 1e-9)
        << "frame " << k;
    EXPECT_LT(q.angularDistance(Eigen::Quaterniond(truth.rotation())), 1e-9) << "frame " << k;
    largest_move_m = std::max(largest_move_m, (truth.translation() - core::trajectoryPose(config.trajectory, 0.0).translation()).norm());
    if (k > 0) {
      // Velocity half-way through the period, in the body frame there.
      const double mid = t - 0.5 / fps, h = 1e-4;
      const Eigen::Isometry3d a = core::trajectoryPose(config.trajectory, mid - h);
      const Eigen::Isometry3d b = core::trajectoryPose(config.trajectory, mid + h);
      const Eigen::Isometry3d c = core::trajectoryPose(config.trajectory, mid);
      const Eigen::Vector3d v_body = c.rotation().transpose() * (b.translation() - a.translation()) / (2 * h);
      const Eigen::AngleAxisd turn(a.rotation().transpose() * b.rotation());
      const Eigen::Vector3d w_body = turn.axis() * turn.angle() / (2 * h);
      const auto& tw = odom->twist.twist;
      // A mean over the period against the midpoint value: second order in the period.
      EXPECT_NEAR((Eigen::Vector3d(tw.linear.x, tw.linear.y, tw.linear.z) - v_body).norm(), 0.0, 0.02 + 0.02 * v_body.norm())
          << "frame " << k << ": linear velocity, expected " << v_body.transpose();
      EXPECT_NEAR((Eigen::Vector3d(tw.angular.x, tw.angular.y, tw.angular.z) - w_body).norm(), 0.0, 0.02 + 0.05 * w_body.norm())
          << "frame " << k << ": angular velocity, expected " << w_body.transpose();
    }
    ++k;
  }
  EXPECT_EQ(k, 15u);
  EXPECT_EQ(tf_count, 15u);
  EXPECT_GT(largest_move_m, 0.5) << "the head hardly moved: the comparison would be weak";
}

TEST(RenderScenarioBag, RefusesBadInputNamingIt) {
  TempDir dir;
  ASSERT_FALSE(dir.path.empty());
  const std::string out = " --out " + dir.path + "/bad.bag --seconds 0.2 --fps 10";
  struct Case {
    std::string what, args, drift_text;
    std::vector<std::string> needles;  // all must appear in the error
  };
  const std::vector<Case> cases = {
      {"missing config", "--config " + dir.path + "/none.yaml", "", {"--config", dir.path + "/none.yaml", "not found"}},
      {"no config option", "", "", {"--config is required"}},
      {"bad number", "--config " + kConfig + " --period soon", "", {"--period", "'soon' is not a number"}},
      {"unknown option", "--config " + kConfig + " --frobnicate", "", {"unknown option '--frobnicate'"}},
      {"drift not a number", "--config " + kConfig, "- {time_s: 0.1, focal_scale: 1.01}\n- {time_s: 0.2, focal_scale: big}\n",
       {"--drift", "drift[1].focal_scale", "must be a number"}},
      {"drift unknown key", "--config " + kConfig, "- {time_s: 0.1, knock_rotaton_deg: [0, 1, 0]}\n",
       {"drift[0].knock_rotaton_deg", "unknown field"}},
      {"drift without time", "--config " + kConfig, "- {focal_scale: 1.01}\n", {"drift[0].time_s", "missing"}},
      {"drift vector", "--config " + kConfig, "- {time_s: 0, right_rotation_deg: [0, 1]}\n",
       {"drift[0].right_rotation_deg", "list of 3 numbers"}},
      {"drift refused by the rig", "--config " + kConfig, "- {time_s: 0, thermal_rate_deg_per_s: 5}\n",
       {"drift[0]", "thermal_rate_deg_per_s must be finite and within"}},
      {"drift not a list", "--config " + kConfig, "focal_scale: 1.01\n", {"drift", "missing"}},
      {"drift not YAML", "--config " + kConfig, "- {time_s: [1, \n", {"drift.yaml", "malformed YAML"}},
  };
  for (const Case& c : cases) {
    std::string args = c.args + out;
    if (!c.drift_text.empty()) {
      writeFile(dir.path + "/drift.yaml", c.drift_text);
      args += " --drift " + dir.path + "/drift.yaml";
    }
    const Result r = runTool(args);
    EXPECT_NE(r.status, 0) << c.what << ": accepted\n" << r.output;
    for (const std::string& needle : c.needles)
      EXPECT_NE(r.output.find(needle), std::string::npos) << c.what << ": no '" << needle << "' in\n" << r.output;
    EXPECT_FALSE(std::filesystem::exists(dir.path + "/bad.bag")) << c.what;
    EXPECT_FALSE(std::filesystem::exists(dir.path + "/bad.bag.active")) << c.what;
  }
  // Control: the same arguments with a valid drift script make the bag.
  writeFile(dir.path + "/drift.yaml", "- {time_s: 0.1, focal_scale: 1.01}\n");
  const Result ok = runTool("--config " + kConfig + out + " --drift " + dir.path + "/drift.yaml");
  EXPECT_EQ(ok.status, 0) << ok.output;
  EXPECT_TRUE(std::filesystem::exists(dir.path + "/bad.bag"));
}
