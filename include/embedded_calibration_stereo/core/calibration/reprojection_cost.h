#pragma once
// Ceres reprojection functors of the stereo bundle adjuster (plumb_bob distortion from
// plumb_bob_distortion.h, templated so that Ceres differentiates them automatically).
//
// Parameter blocks (all doubles):
//   intrinsics[9]  = fx, fy, cx, cy, k1, k2, p1, p2, k3   (skew is fixed at zero)
//   board_pose[7]  = qx, qy, qz, qw (Eigen order, unit), tx, ty, tz: rig_from_board, i.e. the
//                    virtual board in the left optical frame (metres)
//   extrinsics[6]  = rotation vector (rad), translation (m) of right_from_left
// Residual: predicted minus observed raw pixel (2 values).
//
// Threading: the functors are immutable after construction; Ceres may evaluate them from
// several threads at once.
#include <ceres/autodiff_cost_function.h>
#include <ceres/rotation.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "embedded_calibration_stereo/core/geometry/plumb_bob_distortion.h"

namespace embedded_calibration_stereo::core {

constexpr int kIntrinsicsSize = 9;
constexpr int kBoardPoseSize = 7;
constexpr int kExtrinsicsSize = 6;

// Index of each intrinsic in the intrinsics block.
enum IntrinsicIndex { kFx = 0, kFy, kCx, kCy, kK1, kK2, kP1, kP2, kK3 };

// k1..k3 follow each other in CameraInfo.D order, so intrinsics + kK1 is plumb_bob's d[5].
static_assert(kK2 == kK1 + 1 && kP1 == kK1 + 2 && kP2 == kK1 + 3 && kK3 == kK1 + 4 &&
                  kIntrinsicsSize == kK1 + plumb_bob::kCoefficientCount,
              "the intrinsics block must hold the distortion in CameraInfo.D order");

// A point in a camera's optical frame -> raw pixel with the plumb_bob model of OpenCV/ROS.
template <typename T>
void projectPlumbBob(const T* intrinsics, const T* point, T* pixel) {
  const T x = point[0] / point[2];
  const T y = point[1] / point[2];
  T xd, yd;
  plumb_bob::distort(intrinsics + kK1, x, y, &xd, &yd);
  pixel[0] = intrinsics[kFx] * xd + intrinsics[kCx];
  pixel[1] = intrinsics[kFy] * yd + intrinsics[kCy];
}

// A point in the left optical frame -> the right optical frame, through extrinsics[6].
template <typename T>
Eigen::Matrix<T, 3, 1> rightFromLeft(const T* extrinsics, const Eigen::Matrix<T, 3, 1>& p_left) {
  Eigen::Matrix<T, 3, 1> p_right;
  ceres::AngleAxisRotatePoint(extrinsics, p_left.data(), p_right.data());
  for (int i = 0; i < 3; ++i) p_right[i] += extrinsics[3 + i];
  return p_right;
}

// Predicted minus observed pixel of a point in a camera's optical frame. False for a point
// behind the camera: not a valid evaluation point, Ceres backs off.
template <typename T>
bool pixelResidual(const T* intrinsics, const Eigen::Matrix<T, 3, 1>& point,
                   const Eigen::Vector2d& observed, T* residual) {
  if (!(point[2] > T(0.0))) return false;
  T pixel[2];
  projectPlumbBob(intrinsics, point.data(), pixel);
  residual[0] = pixel[0] - T(observed.x());
  residual[1] = pixel[1] - T(observed.y());
  return true;
}

// Board corner (local board coordinates) -> point in the left optical (rig) frame.
template <typename T>
Eigen::Matrix<T, 3, 1> boardCornerInRig(const T* board_pose, const Eigen::Vector3d& corner) {
  const Eigen::Map<const Eigen::Quaternion<T>> rotation(board_pose);
  const Eigen::Map<const Eigen::Matrix<T, 3, 1>> translation(board_pose + 4);
  return rotation * corner.cast<T>() + translation;
}

// A corner seen by the left camera, whose optical frame is the rig frame.
// Parameters: intrinsics[9], board_pose[7].
class LeftCornerReprojectionCost {
 public:
  LeftCornerReprojectionCost(const Eigen::Vector3d& corner_in_board, const Eigen::Vector2d& pixel)
      : corner_(corner_in_board), pixel_(pixel) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& corner_in_board,
                                     const Eigen::Vector2d& pixel) {
    return new ceres::AutoDiffCostFunction<LeftCornerReprojectionCost, 2, kIntrinsicsSize,
                                           kBoardPoseSize>(
        new LeftCornerReprojectionCost(corner_in_board, pixel));
  }

  template <typename T>
  bool operator()(const T* intrinsics, const T* board_pose, T* residual) const {
    return pixelResidual(intrinsics, boardCornerInRig(board_pose, corner_), pixel_, residual);
  }

 private:
  Eigen::Vector3d corner_;
  Eigen::Vector2d pixel_;
};

// A corner seen by the right camera, reached from the rig frame through right_from_left.
// Parameters: intrinsics[9], board_pose[7], extrinsics[6].
class RightCornerReprojectionCost {
 public:
  RightCornerReprojectionCost(const Eigen::Vector3d& corner_in_board, const Eigen::Vector2d& pixel)
      : corner_(corner_in_board), pixel_(pixel) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& corner_in_board,
                                     const Eigen::Vector2d& pixel) {
    return new ceres::AutoDiffCostFunction<RightCornerReprojectionCost, 2, kIntrinsicsSize,
                                           kBoardPoseSize, kExtrinsicsSize>(
        new RightCornerReprojectionCost(corner_in_board, pixel));
  }

  template <typename T>
  bool operator()(const T* intrinsics, const T* board_pose, const T* extrinsics,
                  T* residual) const {
    const Eigen::Matrix<T, 3, 1> p_left = boardCornerInRig(board_pose, corner_);
    return pixelResidual(intrinsics, rightFromLeft(extrinsics, p_left), pixel_, residual);
  }

 private:
  Eigen::Vector3d corner_;
  Eigen::Vector2d pixel_;
};

}  // namespace embedded_calibration_stereo::core
