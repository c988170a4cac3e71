#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

#include <cmath>

namespace embedded_calibration_stereo::core {

std::string StereoRig::validate() const {
  std::string e = left.validate();
  if (!e.empty()) return "left." + e;
  e = right.validate();
  if (!e.empty()) return "right." + e;
  if (!(baseline() > 0)) return "right_from_left.translation must be non-zero";
  return "";
}

double rotationAngleDeg(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  // Via the quaternion (atan2-based in Eigen): acos of the trace loses precision near 0.
  const Eigen::AngleAxisd aa(Eigen::Quaterniond(a.transpose() * b));
  return std::abs(aa.angle()) * 180.0 / M_PI;
}

Eigen::Matrix3d rotationFromVector(const Eigen::Vector3d& rotvec) {
  const double angle = rotvec.norm();
  if (angle < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, rotvec / angle).toRotationMatrix();
}

Eigen::Vector3d rotationVector(const Eigen::Matrix3d& rotation) {
  const Eigen::AngleAxisd aa(rotation);
  return aa.angle() * aa.axis();
}

Eigen::Matrix3d rotationFromVectorDeg(const Eigen::Vector3d& rotvec_deg) {
  return rotationFromVector(rotvec_deg * (M_PI / 180.0));
}

}  // namespace embedded_calibration_stereo::core
