#pragma once
// Two pinhole cameras and the rigid transform between their optical frames.
#include <Eigen/Geometry>
#include <string>

#include "embedded_calibration_stereo/core/geometry/camera_model.h"

namespace embedded_calibration_stereo::core {

struct StereoRig {
  PinholeCamera left;
  PinholeCamera right;
  // Maps points from the left optical frame to the right optical frame:
  // p_right = right_from_left * p_left. For a conventional rig its translation is
  // about (-baseline, 0, 0).
  Eigen::Isometry3d right_from_left = Eigen::Isometry3d::Identity();

  double baseline() const { return right_from_left.translation().norm(); }
  // Pose of the right optical frame in the left one (what tf broadcasts left -> right).
  Eigen::Isometry3d leftFromRight() const { return right_from_left.inverse(); }
  std::string validate() const;
};

// Angle of the rotation R_a^T R_b in degrees.
double rotationAngleDeg(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b);
// Rotation from a rotation vector (the axis times the angle, radians), as Ceres' angle-axis
// parameter blocks hold it; rotationVector() is its inverse, with the angle in [0, pi].
Eigen::Matrix3d rotationFromVector(const Eigen::Vector3d& rotvec);
Eigen::Vector3d rotationVector(const Eigen::Matrix3d& rotation);
// Rotation from a rotation vector given in degrees.
Eigen::Matrix3d rotationFromVectorDeg(const Eigen::Vector3d& rotvec_deg);

}  // namespace embedded_calibration_stereo::core
