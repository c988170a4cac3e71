#pragma once
// Rigid-body trajectories of the simulated world (ROS-free): the head's pose (left optical frame
// in the world frame) and each moving panel's pose, as pure functions of the scene time, so a
// run is deterministic and frames can be rendered in any order.
//
// Kinds (all relative to `start`, the pose at t = 0; frames are optical: x right, y down,
// z forward):
// - static: always `start` (identity by default: the world frame is the rig frame).
// - drive: forward along z at speed_m_s with a heading that oscillates about the vertical
//   (y) axis, peak yaw rate yaw_rate_amplitude_deg_s over yaw_period_s, plus small vertical,
//   pitch and roll vibration (bumps). With loop_s > 0 the head drives forward for loop_s / 2
//   and backs along the same path for loop_s / 2, so it stays inside a finite world.
// - handheld: free 6-DoF motion, per axis a sum of two sinusoids (period P and P / 3) of the
//   given amplitude, each axis with its own phase.
// - waypoints: timed poses; translation linear or Catmull-Rom spline, rotation slerp; held
//   before the first and after the last.
// For every kind but drive, loop_s > 0 repeats the motion: pose(t) = pose(t mod loop_s).
//
// Threading: plain data and pure functions.
#include <Eigen/Geometry>
#include <string>
#include <vector>
#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo::core {

struct SimWaypoint {
  double t_s = 0.0;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
};

struct SimTrajectory {
  enum class Kind { kStatic, kDrive, kHandheld, kWaypoints };
  Kind kind = Kind::kStatic;
  Eigen::Isometry3d start = Eigen::Isometry3d::Identity();  // pose at t = 0
  double loop_s = 0.0;  // 0: no loop

  // drive
  double speed_m_s = 0.0;
  double yaw_rate_amplitude_deg_s = 0.0, yaw_period_s = 10.0;
  double bump_amplitude_m = 0.0, pitch_amplitude_deg = 0.0, roll_amplitude_deg = 0.0;
  double bump_period_s = 0.5;

  // handheld: per axis (x, y, z)
  Eigen::Vector3d translation_amplitude_m = Eigen::Vector3d::Zero();
  Eigen::Vector3d translation_period_s = Eigen::Vector3d::Constant(4.0);
  Eigen::Vector3d rotation_amplitude_deg = Eigen::Vector3d::Zero();
  Eigen::Vector3d rotation_period_s = Eigen::Vector3d::Constant(4.0);

  // waypoints
  bool spline = false;  // translation: false = linear, true = Catmull-Rom
  std::vector<SimWaypoint> waypoints;

  bool isStatic() const { return kind == Kind::kStatic; }
  // Empty string when valid, otherwise "<key>: <problem>" with the key relative to the
  // trajectory section (e.g. "waypoints[2].t_s: ...").
  std::string validate() const;  // "parameter: problem", empty when usable
  ConfigProblem problem() const;
};

const char* trajectoryKindName(SimTrajectory::Kind kind);

// world_from_body at scene time t (seconds).
Eigen::Isometry3d trajectoryPose(const SimTrajectory& trajectory, double time_s);

}  // namespace embedded_calibration_stereo::core
