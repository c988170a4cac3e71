#pragma once
// Ceres functors of the bundle adjuster's rigid device model (BoardPoseMode::kDeviceModel):
// every virtual corner is a corner of its board's grid, placed in the device by the board's
// placement, in the rig by ONE device pose and reflected by its copy's chain of mirror planes.
//
// Parameter blocks (all doubles):
//   device_pose[7] = qx, qy, qz, qw (Eigen order, unit), tx, ty, tz: rig_from_device (metres)
//   board_pose[7]  = the same for device_from_board: the board's placement in the housing
//   plane[4]       = nx, ny, nz (unit), d: the mirror plane n . x = d in the rig frame
// plus the intrinsics[9] and extrinsics[6] blocks of reprojection_cost.h.
// The corner in the board frame (Chessboard::cornerInBoard) is a constant: a printed board's
// grid is exact; its placement is known to the manufacturing tolerance and may be refined.
//
// Threading: the functors are immutable after construction; Ceres may evaluate them from
// several threads at once.
#include <ceres/autodiff_cost_function.h>
#include <ceres/dynamic_autodiff_cost_function.h>
#include <ceres/rotation.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "embedded_calibration_stereo/core/calibration/reprojection_cost.h"

namespace embedded_calibration_stereo::core {

constexpr int kDevicePoseSize = 7;
constexpr int kMirrorPlaneSize = 4;

// Reflects p in place through the plane n . x = d: p - 2 (n . p - d) n (n unit).
template <typename T>
void reflectThroughPlane(const T* plane, T* p) {
  const T s = T(2.0) * (plane[0] * p[0] + plane[1] * p[1] + plane[2] * p[2] - plane[3]);
  for (int i = 0; i < 3; ++i) p[i] -= s * plane[i];
}

// A pose block applied to a point.
template <typename T>
Eigen::Matrix<T, 3, 1> transformByPose(const T* pose, const Eigen::Matrix<T, 3, 1>& p) {
  const Eigen::Map<const Eigen::Quaternion<T>> rotation(pose);
  const Eigen::Map<const Eigen::Matrix<T, 3, 1>> translation(pose + 4);
  return rotation * p + translation;
}

// Board corner -> virtual corner in the rig frame: board placement, device pose, then the
// chain's planes in order (device side first), as CalibrationDevice::virtualBoards() composes
// them.
template <typename T>
Eigen::Matrix<T, 3, 1> virtualDeviceCornerInRig(const T* device_pose, const T* board_pose,
                                                const Eigen::Vector3d& corner_in_board,
                                                T const* const* planes, int plane_count) {
  Eigen::Matrix<T, 3, 1> p =
      transformByPose(device_pose, boardCornerInRig(board_pose, corner_in_board));
  for (int i = 0; i < plane_count; ++i) reflectThroughPlane(planes[i], p.data());
  return p;
}

// A corner of the device seen by one camera through one mirror copy.
// Parameter blocks: intrinsics[9], device_pose[7], board_pose[7], [extrinsics[6] for the right
// camera], then plane[4] for each plane of the copy's chain.
class DeviceCornerReprojectionCost {
 public:
  DeviceCornerReprojectionCost(const Eigen::Vector3d& corner_in_board,
                               const Eigen::Vector2d& pixel, bool right_camera, int plane_count)
      : corner_(corner_in_board), pixel_(pixel), right_(right_camera), planes_(plane_count) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& corner_in_board,
                                     const Eigen::Vector2d& pixel, bool right_camera,
                                     int plane_count) {
    auto* cost = new ceres::DynamicAutoDiffCostFunction<DeviceCornerReprojectionCost>(
        new DeviceCornerReprojectionCost(corner_in_board, pixel, right_camera, plane_count));
    cost->AddParameterBlock(kIntrinsicsSize);
    cost->AddParameterBlock(kDevicePoseSize);
    cost->AddParameterBlock(kDevicePoseSize);
    if (right_camera) cost->AddParameterBlock(kExtrinsicsSize);
    for (int i = 0; i < plane_count; ++i) cost->AddParameterBlock(kMirrorPlaneSize);
    cost->SetNumResiduals(2);
    return cost;
  }

  template <typename T>
  bool operator()(T const* const* blocks, T* residual) const {
    const int first_plane = right_ ? 4 : 3;
    Eigen::Matrix<T, 3, 1> p =
        virtualDeviceCornerInRig(blocks[1], blocks[2], corner_, blocks + first_plane, planes_);
    if (right_) p = rightFromLeft(blocks[3], p);
    return pixelResidual(blocks[0], p, pixel_, residual);
  }

 private:
  Eigen::Vector3d corner_;
  Eigen::Vector2d pixel_;
  bool right_;
  int planes_;
};

// Pre-alignment of the device model to virtual board poses estimated freely: the device
// corner's virtual position minus the freely estimated one, in millimetres (3 residuals).
// Parameter blocks: device_pose[7], board_pose[7], then plane[4] for each plane of the chain.
class DeviceCornerAlignmentCost {
 public:
  DeviceCornerAlignmentCost(const Eigen::Vector3d& corner_in_board,
                            const Eigen::Vector3d& target_in_rig, int plane_count)
      : corner_(corner_in_board), target_(target_in_rig), planes_(plane_count) {}

  static ceres::CostFunction* Create(const Eigen::Vector3d& corner_in_board,
                                     const Eigen::Vector3d& target_in_rig, int plane_count) {
    auto* cost = new ceres::DynamicAutoDiffCostFunction<DeviceCornerAlignmentCost>(
        new DeviceCornerAlignmentCost(corner_in_board, target_in_rig, plane_count));
    cost->AddParameterBlock(kDevicePoseSize);
    cost->AddParameterBlock(kDevicePoseSize);
    for (int i = 0; i < plane_count; ++i) cost->AddParameterBlock(kMirrorPlaneSize);
    cost->SetNumResiduals(3);
    return cost;
  }

  template <typename T>
  bool operator()(T const* const* blocks, T* residual) const {
    const Eigen::Matrix<T, 3, 1> p =
        virtualDeviceCornerInRig(blocks[0], blocks[1], corner_, blocks + 2, planes_);
    for (int i = 0; i < 3; ++i) residual[i] = T(1000.0) * (p[i] - T(target_[i]));
    return true;
  }

 private:
  Eigen::Vector3d corner_;
  Eigen::Vector3d target_;
  int planes_;
};

// Prior of a pose block (the device pose, a board's placement) around its nominal value:
// small-angle rotation difference over angle_tolerance_rad and translation difference over
// position_tolerance_m (6 residuals).
class DevicePosePriorCost {
 public:
  DevicePosePriorCost(const Eigen::Quaterniond& nominal_rotation,
                      const Eigen::Vector3d& nominal_translation, double angle_tolerance_rad,
                      double position_tolerance_m)
      : rotation_(nominal_rotation),
        translation_(nominal_translation),
        angle_tol_(angle_tolerance_rad),
        position_tol_(position_tolerance_m) {}

  static ceres::CostFunction* Create(const Eigen::Isometry3d& nominal, double angle_tolerance_rad,
                                     double position_tolerance_m) {
    return new ceres::AutoDiffCostFunction<DevicePosePriorCost, 6, kDevicePoseSize>(
        new DevicePosePriorCost(Eigen::Quaterniond(nominal.linear()), nominal.translation(),
                                angle_tolerance_rad, position_tolerance_m));
  }

  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    const Eigen::Map<const Eigen::Quaternion<T>> q(pose);
    const Eigen::Quaternion<T> delta = rotation_.cast<T>().conjugate() * q;
    const T sign = delta.w() < T(0.0) ? T(-1.0) : T(1.0);  // q and -q are the same rotation
    for (int i = 0; i < 3; ++i) {
      residual[i] = sign * T(2.0) * delta.vec()[i] / T(angle_tol_);
      residual[3 + i] = (pose[4 + i] - T(translation_[i])) / T(position_tol_);
    }
    return true;
  }

 private:
  Eigen::Quaterniond rotation_;
  Eigen::Vector3d translation_;
  double angle_tol_, position_tol_;
};

// Weak prior of a mirror plane around its nominal value (4 residuals: normal difference, which
// is the tilt angle for small tilts, and distance difference).
class MirrorPlanePriorCost {
 public:
  MirrorPlanePriorCost(const Eigen::Vector4d& nominal, double angle_tolerance_rad,
                       double position_tolerance_m)
      : nominal_(nominal), angle_tol_(angle_tolerance_rad), position_tol_(position_tolerance_m) {}

  static ceres::CostFunction* Create(const Eigen::Vector4d& nominal, double angle_tolerance_rad,
                                     double position_tolerance_m) {
    return new ceres::AutoDiffCostFunction<MirrorPlanePriorCost, 4, kMirrorPlaneSize>(
        new MirrorPlanePriorCost(nominal, angle_tolerance_rad, position_tolerance_m));
  }

  template <typename T>
  bool operator()(const T* plane, T* residual) const {
    for (int i = 0; i < 3; ++i) residual[i] = (plane[i] - T(nominal_[i])) / T(angle_tol_);
    residual[3] = (plane[3] - T(nominal_[3])) / T(position_tol_);
    return true;
  }

 private:
  Eigen::Vector4d nominal_;
  double angle_tol_, position_tol_;
};

}  // namespace embedded_calibration_stereo::core
