#pragma once
// Conversions between the core types (core::PinholeCamera, core::StereoRig, core::BoardCorners,
// core::StereoObservation, Eigen::Isometry3d) and ROS messages.
//
// CameraInfo conventions (as in sensor_msgs/CameraInfo, image_geometry and stereo_image_proc):
//  - distortion_model "plumb_bob", D = [k1, k2, p1, p2, k3];
//  - K the raw camera matrix; R the rectifying rotation; P the projection of the rectified
//    camera: P = [fx' 0 cx' Tx; 0 fy' cy' Ty; 0 0 1 0];
//  - for a stereo pair, R and P are the core's Bouguet rectification (core::
//    computeRectificationGeometry: cv::stereoRectify, zero disparity at infinity, alpha 0 unless
//    asked) so that the right P has Tx = -fx' * baseline and
//    image_geometry::StereoCameraModel::baseline() equals the rig's baseline.
// All functions are pure and thread-safe.
#include <Eigen/Geometry>
#include <geometry_msgs/Pose.h>
#include <geometry_msgs/TransformStamped.h>
#include <sensor_msgs/CameraInfo.h>
#include <optional>
#include <string>
#include <utility>

#include "embedded_calibration_stereo/BoardObservation.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/core/driver/status_summary.h"
#include "embedded_calibration_stereo/core/geometry/camera_model.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo {

// Monocular CameraInfo of one camera: plumb_bob K and D, R = I, P = [K | 0].
// The header is left empty; the caller stamps it.
sensor_msgs::CameraInfo toCameraInfo(const core::PinholeCamera& camera);

// Left and right CameraInfo of a stereo rig with its Bouguet rectification
// (core::computeRectificationGeometry): R1/R2 rotate each raw optical frame into the common
// rectified frame, P1/P2 share fx', fy', cx', cy' and P2(0,3) = -fx' * baseline. `alpha` is
// cv::stereoRectify's: 0 zooms so that every rectified pixel is valid, 1 keeps every raw pixel,
// -1 is OpenCV's default scaling. Throws std::invalid_argument when the rig is not usable
// (invalid camera, zero baseline, left and right sizes differ).
std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo> toStereoCameraInfo(
    const core::StereoRig& rig, double alpha = 0.0);

// diagnostic_msgs::DiagnosticStatus's level (OK, WARN, ERROR) of a core summary.
uint8_t toDiagnosticLevel(core::StatusSummary::Level level);

// What a driver publishes before any calibration is stored: the nominal cameras of the drawing
// (toStereoCameraInfo) when they have the image's size, otherwise uncalibrated messages that
// carry only the size (K all zero: image_geometry and the consumers' checks call it uncalibrated).
std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo> fallbackCameraInfos(
    const std::optional<core::StereoRig>& nominal, int width, int height);

// K and D of a CameraInfo as a core camera (R and P are ignored). Accepts plumb_bob (or an
// empty model) with 0, 4 or 5 coefficients. Returns false and explains why in *error when the
// message cannot be represented (other model, non-positive focal length, zero size).
bool fromCameraInfo(const sensor_msgs::CameraInfo& info, core::PinholeCamera* camera,
                    std::string* error);

// A stereo rig from the left and right CameraInfo of a rectified pair (as produced by
// toStereoCameraInfo or by any stereo calibrator following the same conventions):
// right_from_left = R2^T * [R1 | t_rect], t_rect = (P2(0,3)/fx', P2(1,3)/fy', P2(2,3)).
// Returns false and explains why in *error when either camera is unusable.
bool fromStereoCameraInfo(const sensor_msgs::CameraInfo& left,
                          const sensor_msgs::CameraInfo& right, core::StereoRig* rig,
                          std::string* error);

// Board corners <-> BoardObservation (board_id and corner ids must fit uint16).
BoardObservation toMsg(const core::BoardCorners& corners);
core::BoardCorners fromMsg(const BoardObservation& msg);

// Stereo observation <-> StereoPatternObservation. The stamp is carried by the header (the
// core stamp is in seconds); frame_id is set by the caller.
StereoPatternObservation toMsg(const core::StereoObservation& observation);
core::StereoObservation fromMsg(const StereoPatternObservation& msg);

// A rigid transform <-> geometry_msgs/Pose (the child frame's pose in the parent's).
geometry_msgs::Pose toPoseMsg(const Eigen::Isometry3d& parent_from_child);
Eigen::Isometry3d fromPoseMsg(const geometry_msgs::Pose& pose);

// A rigid transform as a TransformStamped from `parent_frame` to `child_frame`: the pose of the
// child frame expressed in the parent frame (tf convention: p_parent = T * p_child).
geometry_msgs::TransformStamped toTransformStamped(const Eigen::Isometry3d& parent_from_child,
                                                   const std::string& parent_frame,
                                                   const std::string& child_frame,
                                                   const ros::Time& stamp);

}  // namespace embedded_calibration_stereo
