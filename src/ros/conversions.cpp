#include "embedded_calibration_stereo/ros/conversions.h"

#include <diagnostic_msgs/DiagnosticStatus.h>

#include <cmath>
#include <sensor_msgs/distortion_models.h>

#include "embedded_calibration_stereo/core/depth/rectification.h"

namespace embedded_calibration_stereo {
namespace {

// Fields shared by the mono and stereo messages: size, model, K, D.
sensor_msgs::CameraInfo intrinsicsMsg(const core::PinholeCamera& camera) {
  sensor_msgs::CameraInfo info;
  info.width = static_cast<uint32_t>(camera.width);
  info.height = static_cast<uint32_t>(camera.height);
  info.distortion_model = sensor_msgs::distortion_models::PLUMB_BOB;
  info.D.assign(camera.dist.begin(), camera.dist.end());
  const cv::Matx33d k = core::cameraMatrix(camera);
  for (int i = 0; i < 9; ++i) info.K[i] = k.val[i];
  return info;
}

void setRectification(const cv::Matx33d& r, const cv::Matx34d& p, sensor_msgs::CameraInfo* info) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) info->R[3 * i + j] = r(i, j);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 4; ++j) info->P[4 * i + j] = p(i, j);
}

Eigen::Matrix3d rotationOf(const boost::array<double, 9>& r) {
  Eigen::Matrix3d m;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) m(i, j) = r[3 * i + j];
  return m;
}

}  // namespace

sensor_msgs::CameraInfo toCameraInfo(const core::PinholeCamera& camera) {
  sensor_msgs::CameraInfo info = intrinsicsMsg(camera);
  info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  const cv::Matx33d k = core::cameraMatrix(camera);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) info.P[4 * i + j] = k(i, j);
    info.P[4 * i + 3] = 0.0;
  }
  return info;
}

std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo> toStereoCameraInfo(
    const core::StereoRig& rig, double alpha) {
  sensor_msgs::CameraInfo left = intrinsicsMsg(rig.left);
  sensor_msgs::CameraInfo right = intrinsicsMsg(rig.right);
  // Bouguet is the rectification CameraInfo's R and P mean to stereo_image_proc (and the
  // rectifier's bouguet method applies them as they are).
  core::RectificationOptions options;
  options.method = core::RectificationMethod::kBouguet;
  options.alpha = alpha;
  const core::RectificationGeometry g = core::computeRectificationGeometry(rig, options);
  setRectification(g.R1, g.P1, &left);
  setRectification(g.R2, g.P2, &right);
  return {left, right};
}

uint8_t toDiagnosticLevel(core::StatusSummary::Level level) {
  using diagnostic_msgs::DiagnosticStatus;
  switch (level) {
    case core::StatusSummary::Level::kOk:
      return DiagnosticStatus::OK;
    case core::StatusSummary::Level::kWarn:
      return DiagnosticStatus::WARN;
    case core::StatusSummary::Level::kError:
      break;
  }
  return DiagnosticStatus::ERROR;
}

std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo> fallbackCameraInfos(
    const std::optional<core::StereoRig>& nominal, int width, int height) {
  if (nominal && nominal->left.width == width && nominal->left.height == height) return toStereoCameraInfo(*nominal);
  sensor_msgs::CameraInfo left, right;
  left.width = right.width = static_cast<uint32_t>(width);
  left.height = right.height = static_cast<uint32_t>(height);
  return {left, right};
}

bool fromCameraInfo(const sensor_msgs::CameraInfo& info, core::PinholeCamera* camera,
                    std::string* error) {
  auto fail = [error](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  if (!info.distortion_model.empty() &&
      info.distortion_model != sensor_msgs::distortion_models::PLUMB_BOB)
    return fail("distortion_model '" + info.distortion_model + "' is not plumb_bob");
  if (info.D.size() != 0 && info.D.size() != 4 && info.D.size() != 5)
    return fail("D has " + std::to_string(info.D.size()) + " coefficients (plumb_bob takes 4 or 5)");
  if (info.width == 0 || info.height == 0) return fail("width and height must be > 0");
  core::PinholeCamera c;
  c.width = static_cast<int>(info.width);
  c.height = static_cast<int>(info.height);
  c.fx = info.K[0];
  c.skew = info.K[1];
  c.cx = info.K[2];
  c.fy = info.K[4];
  c.cy = info.K[5];
  if (!(c.fx > 0.0) || !(c.fy > 0.0))
    return fail("focal length K[0]/K[4] must be > 0 (fx=" + std::to_string(c.fx) +
                ", fy=" + std::to_string(c.fy) + ")");
  c.dist = {{0, 0, 0, 0, 0}};
  for (size_t i = 0; i < info.D.size(); ++i) c.dist[i] = info.D[i];
  const std::string why = c.validate();
  if (!why.empty()) return fail(why);
  *camera = c;
  return true;
}

bool fromStereoCameraInfo(const sensor_msgs::CameraInfo& left,
                          const sensor_msgs::CameraInfo& right, core::StereoRig* rig,
                          std::string* error) {
  core::StereoRig result;
  std::string why;
  if (!fromCameraInfo(left, &result.left, &why)) {
    if (error) *error = "left: " + why;
    return false;
  }
  if (!fromCameraInfo(right, &result.right, &why)) {
    if (error) *error = "right: " + why;
    return false;
  }
  const double fx_rect = right.P[0], fy_rect = right.P[5];
  if (!(fx_rect > 0.0) || !(fy_rect > 0.0)) {
    if (error) *error = "right: P has no positive focal length";
    return false;
  }
  const Eigen::Vector3d t_rect(right.P[3] / fx_rect, right.P[7] / fy_rect, right.P[11]);
  const Eigen::Matrix3d r1 = rotationOf(left.R), r2 = rotationOf(right.R);
  // p_rect_right = R1 p_left + t_rect and p_right = R2^T p_rect_right.
  Eigen::Isometry3d right_from_left = Eigen::Isometry3d::Identity();
  right_from_left.linear() = r2.transpose() * r1;
  right_from_left.translation() = r2.transpose() * t_rect;
  result.right_from_left = right_from_left;
  *rig = result;
  return true;
}

BoardObservation toMsg(const core::BoardCorners& corners) {
  BoardObservation msg;
  msg.board_id = static_cast<uint16_t>(corners.board_id);
  msg.corner_ids.assign(corners.corner_ids.begin(), corners.corner_ids.end());
  msg.u = corners.u;
  msg.v = corners.v;
  return msg;
}

core::BoardCorners fromMsg(const BoardObservation& msg) {
  core::BoardCorners corners;
  corners.board_id = msg.board_id;
  corners.corner_ids.assign(msg.corner_ids.begin(), msg.corner_ids.end());
  corners.u = msg.u;
  corners.v = msg.v;
  return corners;
}

StereoPatternObservation toMsg(const core::StereoObservation& observation) {
  StereoPatternObservation msg;
  msg.header.stamp.fromSec(observation.stamp);
  for (const auto& b : observation.left) msg.left.push_back(toMsg(b));
  for (const auto& b : observation.right) msg.right.push_back(toMsg(b));
  msg.scene.reserve(observation.scene.size());
  for (const core::SceneMatch& m : observation.scene) {
    SceneMatch s;
    s.left_u = m.left_u, s.left_v = m.left_v, s.right_u = m.right_u, s.right_v = m.right_v;
    msg.scene.push_back(s);
  }
  return msg;
}

core::StereoObservation fromMsg(const StereoPatternObservation& msg) {
  core::StereoObservation observation;
  observation.stamp = msg.header.stamp.toSec();
  for (const auto& b : msg.left) observation.left.push_back(fromMsg(b));
  for (const auto& b : msg.right) observation.right.push_back(fromMsg(b));
  observation.scene.reserve(msg.scene.size());
  for (const SceneMatch& s : msg.scene) observation.scene.push_back({s.left_u, s.left_v, s.right_u, s.right_v});
  return observation;
}

geometry_msgs::Pose toPoseMsg(const Eigen::Isometry3d& parent_from_child) {
  geometry_msgs::Pose pose;
  const Eigen::Vector3d t = parent_from_child.translation();
  const Eigen::Quaterniond q(parent_from_child.rotation());
  pose.position.x = t.x();
  pose.position.y = t.y();
  pose.position.z = t.z();
  pose.orientation.x = q.x();
  pose.orientation.y = q.y();
  pose.orientation.z = q.z();
  pose.orientation.w = q.w();
  return pose;
}

Eigen::Isometry3d fromPoseMsg(const geometry_msgs::Pose& pose) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = Eigen::Quaterniond(pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z)
                   .normalized()
                   .toRotationMatrix();
  t.translation() = Eigen::Vector3d(pose.position.x, pose.position.y, pose.position.z);
  return t;
}

geometry_msgs::TransformStamped toTransformStamped(const Eigen::Isometry3d& parent_from_child,
                                                   const std::string& parent_frame,
                                                   const std::string& child_frame,
                                                   const ros::Time& stamp) {
  geometry_msgs::TransformStamped msg;
  msg.header.stamp = stamp;
  msg.header.frame_id = parent_frame;
  msg.child_frame_id = child_frame;
  const geometry_msgs::Pose pose = toPoseMsg(parent_from_child);
  msg.transform.translation.x = pose.position.x;
  msg.transform.translation.y = pose.position.y;
  msg.transform.translation.z = pose.position.z;
  msg.transform.rotation = pose.orientation;
  return msg;
}

}  // namespace embedded_calibration_stereo
