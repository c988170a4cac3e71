#pragma once
// Helpers of the calibration-pair rostests (calibration_*.test): calibration pairs of the
// simulated head's size, what two calibration files show, the driver's diagnostics, and the
// driver as a child process (to kill it).
#include <diagnostic_msgs/DiagnosticArray.h>
#include <fcntl.h>
#include <sensor_msgs/CameraInfo.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <future>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "driver_test_utils.h"
#include "process_test_utils.h"
#include "embedded_calibration_stereo/ros/calibration_file.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace embedded_calibration_stereo::test_support {

// A rectified pair of the simulated head's size (752x480) whose fx' is `fx` in both cameras,
// as the OnlineCalibrator commits it (Bouguet R and P, right Tx = -fx' * 0.1 m).
inline std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo> pairWithFocal(double fx) {
  core::StereoRig rig;
  for (core::PinholeCamera* c : {&rig.left, &rig.right}) {
    c->width = 752;
    c->height = 480;
    c->fx = fx;
    c->fy = fx;
    c->cx = 376;
    c->cy = 240;
    c->dist = {{-0.05, 0.01, 0, 0, 0}};
  }
  rig.right_from_left.translation() = Eigen::Vector3d(-0.1, 0, 0);
  return embedded_calibration_stereo::toStereoCameraInfo(rig);
}

inline std::string fileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// What a reader of the two files sees: fx' (P[0]) of each, -1 for a missing file, -2 for one
// that does not parse (camera_calibration_parsers, as camera_info_manager reads them).
inline std::pair<double, double> shownFocals(const std::string& left_path, const std::string& right_path) {
  double focal[2];
  const std::string paths[2] = {left_path, right_path};
  for (int i = 0; i < 2; ++i) {
    struct stat st;
    sensor_msgs::CameraInfo info;
    std::string error;
    if (::stat(paths[i].c_str(), &st) != 0)
      focal[i] = -1.0;
    else
      focal[i] = embedded_calibration_stereo::readCalibrationFile(paths[i], nullptr, &info, &error) ? info.P[0] : -2.0;
  }
  return {focal[0], focal[1]};
}

// "" when the two CameraInfos are what image_geometry::StereoCameraModel needs (checked here
// directly, not with the product's checks): one frame id, equal fx', fy', cy', finite values,
// positive focal lengths, left Tx 0 and right Tx non-zero, no binning.
inline std::string pairProblem(const sensor_msgs::CameraInfo& left, const sensor_msgs::CameraInfo& right) {
  if (left.header.frame_id != right.header.frame_id) return "frame ids differ";
  for (const auto* info : {&left, &right}) {
    for (double v : info->K)
      if (!std::isfinite(v)) return "K not finite";
    for (double v : info->R)
      if (!std::isfinite(v)) return "R not finite";
    for (double v : info->P)
      if (!std::isfinite(v)) return "P not finite";
    if (!(info->P[0] > 0 && info->P[5] > 0 && info->K[0] > 0 && info->K[4] > 0)) return "focal length <= 0";
    if (info->binning_x > 1 || info->binning_y > 1) return "binning";
  }
  if (left.P[0] != right.P[0] || left.P[5] != right.P[5] || left.P[6] != right.P[6])
    return "fx', fy' or cy' differ: " + std::to_string(left.P[0]) + " / " + std::to_string(right.P[0]);
  if (left.P[3] != 0 || right.P[3] == 0) return "Tx";
  return "";
}

// Waits until this node's own log messages come back on /rosout through `log`: a message
// logged after this returns is not missed for a subscription still connecting.
inline bool waitForRosoutPipe(Collector<rosgraph_msgs::Log>& log, double timeout_s) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout_s);
  for (int n = 0; ros::WallTime::now() < end; ++n) {
    ROS_INFO("rosout pipe check %d", n);
    if (waitForLog(log, {"rosout pipe check"}, 0.2)) return true;
  }
  return false;
}

// Waits for a driver status (name containing "camera_driver") of `level` whose message
// contains `needle`; *message gets it.
inline bool waitForDriverStatus(Collector<diagnostic_msgs::DiagnosticArray>& diagnostics, uint8_t level,
                                const std::string& needle, double timeout_s, std::string* message = nullptr) {
  return diagnostics.waitFor(
      [&](const std::vector<diagnostic_msgs::DiagnosticArray::ConstPtr>& arrays) {
        for (const auto& array : arrays)
          for (const auto& s : array->status)
            if (s.name.find("camera_driver") != std::string::npos && s.level == level &&
                s.message.find(needle) != std::string::npos) {
              if (message) *message = s.message;
              return true;
            }
        return false;
      },
      timeout_s);
}

// The camera driver alone in a `nodelet standalone` child process, on the test's master, with
// private parameters given as `_name:=value` arguments and extra environment variables; its
// output goes to a log file. The child is the nodelet process itself (no roslaunch between),
// so the test sees how it ended (e.g. SIGKILL from the calibration store's test hook).
class DriverProcess : public ChildProcess {
 public:
  DriverProcess(const std::string& ns, const std::vector<std::string>& params, const std::vector<std::string>& env,
                std::string log_path)
      : ChildProcess(argv(ns, params), env, std::move(log_path), 10.0) {}

 private:
  static std::vector<std::string> argv(const std::string& ns, const std::vector<std::string>& params) {
    std::vector<std::string> all{nodeletExecutable(), "standalone", "embedded_calibration_stereo/CameraDriver",
                                 "__name:=camera_driver", "__ns:=" + ns};
    all.insert(all.end(), params.begin(), params.end());
    return all;
  }
  static std::string nodeletExecutable() {
    for (const std::string candidate : {"/usr/lib/nodelet/nodelet", "/opt/ros/noetic/lib/nodelet/nodelet"})
      if (::access(candidate.c_str(), X_OK) == 0) return candidate;
    return "/usr/lib/nodelet/nodelet";
  }
};

}  // namespace embedded_calibration_stereo::test_support
