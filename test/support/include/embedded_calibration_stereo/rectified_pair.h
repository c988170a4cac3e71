#pragma once
// A rectified CameraInfo pair of a 752x480 head whose cameras share fx' (as the OnlineCalibrator
// commits one), for tests of what receives calibrations. Header-only: the test support library
// does not link the ROS glue.
#include <sensor_msgs/CameraInfo.h>

#include <cstdint>
#include <utility>

#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace embedded_calibration_stereo::test_support {

constexpr uint32_t kPairWidth = 752, kPairHeight = 480;

// A 752x480 head with strong barrel distortion and a 12 cm baseline; its cameras differ only in
// the right one's fx.
inline core::StereoRig headRig(double right_fx = 648.7) {
  core::StereoRig rig;
  rig.left.width = kPairWidth;
  rig.left.height = kPairHeight;
  rig.left.fx = 652.4;
  rig.left.fy = 651.3;
  rig.left.cx = 372.9;
  rig.left.cy = 243.4;
  rig.left.dist = {-0.281, 0.0712, 0.00031, -0.00052, 0.0};
  rig.right = rig.left;
  rig.right.fx = right_fx;
  rig.right_from_left.translation() << -0.1203, 0.0004, 0.0011;
  return rig;
}

inline std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo> pairWithFocal(double fx) {
  core::StereoRig rig;
  for (core::PinholeCamera* c : {&rig.left, &rig.right}) {
    c->width = kPairWidth;
    c->height = kPairHeight;
    c->fx = fx;
    c->fy = fx;
    c->cx = 376;
    c->cy = 240;
  }
  rig.right_from_left.translation() = Eigen::Vector3d(-0.1, 0, 0);
  return toStereoCameraInfo(rig);
}

}  // namespace embedded_calibration_stereo::test_support
