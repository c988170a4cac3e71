#pragma once
// Helpers of the rostests around calibration/health: the last verdict in words, a stereo pair
// sent to the driver, a calibration with the right camera tilted.
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <cmath>
#include <string>
#include <utility>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace embedded_calibration_stereo::test_support {

inline const char* healthStateName(uint8_t state) {
  static const char* names[] = {"UNKNOWN", "GOOD", "DEGRADED", "BAD"};
  return state < 4 ? names[state] : "?";
}

// "last health: epoch N STATE: reason", for a failure message.
inline std::string lastHealth(Collector<embedded_calibration_stereo::CalibrationHealth>& health) {
  const auto all = health.snapshot();
  if (all.empty()) return "no calibration/health message";
  const auto& h = *all.back();
  return "last health: epoch " + std::to_string(h.epoch) + " " + healthStateName(h.state) + ": " + h.reason;
}

// Both cameras' set_camera_info (left, then right, as a stereo calibrator), under `prefix`
// (e.g. "/stereo/"; empty: relative names); each must be answered success.
inline void setPair(const std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo>& pair,
                    const std::string& prefix = "") {
  for (const bool left : {true, false}) {
    sensor_msgs::SetCameraInfo srv;
    srv.request.camera_info = left ? pair.first : pair.second;
    const std::string service = prefix + (left ? "left" : "right") + "/set_camera_info";
    ASSERT_TRUE(ros::service::call(service, srv)) << service;
    ASSERT_TRUE(srv.response.success) << service << ": " << srv.response.status_message;
  }
}

// The pair with the right camera turned by `degrees` about x (a wrong calibration, or a knock).
inline std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo> tilted(const sensor_msgs::CameraInfo& left,
                                                                          const sensor_msgs::CameraInfo& right,
                                                                          double degrees) {
  core::StereoRig rig;
  std::string error;
  EXPECT_TRUE(embedded_calibration_stereo::fromStereoCameraInfo(left, right, &rig, &error)) << error;
  rig.right_from_left.linear() =
      Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix() *
      rig.right_from_left.linear();
  return embedded_calibration_stereo::toStereoCameraInfo(rig);
}

}  // namespace embedded_calibration_stereo::test_support
