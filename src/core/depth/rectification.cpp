#include "embedded_calibration_stereo/core/depth/rectification.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace embedded_calibration_stereo::core {

RectificationMethod parseRectificationMethod(const std::string& name) {
  if (name == "bouguet") return RectificationMethod::kBouguet;
  if (name == "fusiello") return RectificationMethod::kFusiello;
  throw std::invalid_argument("rectification method '" + name +
                              "' unknown; expected 'bouguet' or 'fusiello'");
}

std::string toString(RectificationMethod method) {
  return method == RectificationMethod::kBouguet ? "bouguet" : "fusiello";
}

cv::Matx33d cameraMatrix(const PinholeCamera& camera) {
  return cv::Matx33d(camera.fx, camera.skew, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1);
}

cv::Mat distortionVector(const PinholeCamera& camera) {
  cv::Mat d(1, 5, CV_64F);
  for (int i = 0; i < 5; ++i) d.at<double>(i) = camera.dist[i];
  return d;
}

namespace {

cv::Matx33d toMatx(const Eigen::Matrix3d& m) {
  cv::Matx33d out;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out(r, c) = m(r, c);
  return out;
}

// Q of a horizontal rectified pair with equal principal points (OpenCV's form).
cv::Matx44d disparityToDepthMatrix(double f, double cx, double cy, double baseline) {
  return cv::Matx44d(1, 0, 0, -cx,  //
                     0, 1, 0, -cy,  //
                     0, 0, 0, f,    //
                     0, 0, 1.0 / baseline, 0);
}

RectificationGeometry bouguet(const StereoRig& rig, double alpha) {
  const cv::Size size(rig.left.width, rig.left.height);
  const cv::Matx33d R = toMatx(rig.right_from_left.linear());
  const Eigen::Vector3d t = rig.right_from_left.translation();
  cv::Mat R1, R2, P1, P2, Q;
  cv::stereoRectify(cameraMatrix(rig.left), distortionVector(rig.left), cameraMatrix(rig.right),
                    distortionVector(rig.right), size, R, cv::Vec3d(t.x(), t.y(), t.z()), R1, R2,
                    P1, P2, Q, cv::CALIB_ZERO_DISPARITY, alpha, size);
  RectificationGeometry g;
  g.size = size;
  g.R1 = cv::Matx33d(R1);
  g.R2 = cv::Matx33d(R2);
  g.P1 = cv::Matx34d(P1);
  g.P2 = cv::Matx34d(P2);
  g.Q = cv::Matx44d(Q);
  return g;
}

// Rectified pixel of a raw pixel, for a camera rotated by R_rect and an ideal focal f with
// principal point (0, 0); used to centre the common principal point.
cv::Point2d rectifiedOffset(const PinholeCamera& cam, const Eigen::Matrix3d& R_rect, double f,
                            double u, double v) {
  const Eigen::Vector2d xn = cam.pixelToNormalized(Eigen::Vector2d(u, v));
  const Eigen::Vector3d ray = R_rect * Eigen::Vector3d(xn.x(), xn.y(), 1.0);
  return {f * ray.x() / ray.z(), f * ray.y() / ray.z()};
}

// Fusiello, Trucco, Verri (2000): both cameras are rotated to a common orientation whose x axis
// is the baseline, y axis orthogonal to x and to the old left optical axis; both get one K.
RectificationGeometry fusiello(const StereoRig& rig) {
  const Eigen::Matrix3d R = rig.right_from_left.linear();
  const Eigen::Vector3d c2 = -R.transpose() * rig.right_from_left.translation();  // left frame
  const Eigen::Vector3d v1 = c2.normalized();
  if (std::abs(v1.x()) < std::abs(v1.y()))
    throw std::invalid_argument("fusiello rectification needs a mainly horizontal baseline");
  if (v1.x() < 0)  // the rectified images would come out upside down
    throw std::invalid_argument(
        "fusiello rectification: the right camera must lie right of the left one "
        "(right_from_left translation x < 0)");
  const Eigen::Vector3d old_z_left(0, 0, 1);
  const Eigen::Vector3d v2 = old_z_left.cross(v1).normalized();
  const Eigen::Vector3d v3 = v1.cross(v2);
  Eigen::Matrix3d R_rect;  // rows: new axes expressed in the old left frame
  R_rect.row(0) = v1.transpose();
  R_rect.row(1) = v2.transpose();
  R_rect.row(2) = v3.transpose();
  const Eigen::Matrix3d R1 = R_rect;
  const Eigen::Matrix3d R2 = R_rect * R.transpose();

  // Common intrinsics: the mean focal length, and the principal point that puts the mean of
  // both rectified image centres at the centre of the rectified image.
  const double f = 0.25 * (rig.left.fx + rig.left.fy + rig.right.fx + rig.right.fy);
  const double uc = 0.5 * (rig.left.width - 1), vc = 0.5 * (rig.left.height - 1);
  const cv::Point2d o1 = rectifiedOffset(rig.left, R1, f, rig.left.cx, rig.left.cy);
  const cv::Point2d o2 = rectifiedOffset(rig.right, R2, f, rig.right.cx, rig.right.cy);
  const double cx = uc - 0.5 * (o1.x + o2.x);
  const double cy = vc - 0.5 * (o1.y + o2.y);
  const double baseline = c2.norm();

  RectificationGeometry g;
  g.size = cv::Size(rig.left.width, rig.left.height);
  g.R1 = toMatx(R1);
  g.R2 = toMatx(R2);
  g.P1 = cv::Matx34d(f, 0, cx, 0, 0, f, cy, 0, 0, 0, 1, 0);
  g.P2 = cv::Matx34d(f, 0, cx, -f * baseline, 0, f, cy, 0, 0, 0, 1, 0);
  g.Q = disparityToDepthMatrix(f, cx, cy, baseline);
  return g;
}

}  // namespace

RectificationGeometry computeRectificationGeometry(const StereoRig& rig,
                                                   const RectificationOptions& options) {
  const std::string problem = rig.validate();
  if (!problem.empty()) throw std::invalid_argument("rectification: rig invalid: " + problem);
  if (rig.left.width != rig.right.width || rig.left.height != rig.right.height)
    throw std::invalid_argument("rectification: left and right image sizes differ");
  return options.method == RectificationMethod::kBouguet ? bouguet(rig, options.alpha)
                                                         : fusiello(rig);
}

void remapStereoPair(const cv::Mat& left_in, const cv::Mat& right_in, const cv::Mat& left_map1,
                     const cv::Mat& left_map2, const cv::Mat& right_map1, const cv::Mat& right_map2,
                     cv::Mat* left_out, cv::Mat* right_out) {
  const cv::Mat* in[2] = {&left_in, &right_in};
  const cv::Mat* map1[2] = {&left_map1, &right_map1};
  const cv::Mat* map2[2] = {&left_map2, &right_map2};
  cv::Mat* out[2] = {left_out, right_out};
  cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& images) {
    for (int i = images.start; i < images.end; ++i)  // nested: cv::remap runs on this thread
      cv::remap(*in[i], *out[i], *map1[i], *map2[i], cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  }, 2);
}

RectificationMaps RectificationMaps::build(const StereoRig& rig,
                                           const RectificationOptions& options) {
  RectificationMaps maps;
  maps.method_ = options.method;
  maps.geometry_ = computeRectificationGeometry(rig, options);
  const RectificationGeometry& g = maps.geometry_;
  cv::initUndistortRectifyMap(cameraMatrix(rig.left), distortionVector(rig.left), g.R1, g.P1,
                              g.size, CV_16SC2, maps.left_map1_, maps.left_map2_);
  cv::initUndistortRectifyMap(cameraMatrix(rig.right), distortionVector(rig.right), g.R2, g.P2,
                              g.size, CV_16SC2, maps.right_map1_, maps.right_map2_);
  return maps;
}

void RectificationMaps::rectify(const cv::Mat& left_raw, const cv::Mat& right_raw,
                                cv::Mat* left_rect, cv::Mat* right_rect) const {
  if (left_raw.size() != geometry_.size || right_raw.size() != geometry_.size)
    throw std::invalid_argument("rectify: image size differs from the calibrated size " +
                                std::to_string(geometry_.size.width) + "x" +
                                std::to_string(geometry_.size.height));
  if (left_rect->data == left_raw.data || right_rect->data == right_raw.data ||
      left_rect == right_rect)
    throw std::invalid_argument("rectify: outputs must be distinct and not alias the inputs");
  remapStereoPair(left_raw, right_raw, left_map1_, left_map2_, right_map1_, right_map2_, left_rect,
                  right_rect);
}

std::pair<cv::Mat, cv::Mat> RectificationMaps::rectify(const cv::Mat& left_raw,
                                                       const cv::Mat& right_raw) const {
  std::pair<cv::Mat, cv::Mat> out;
  rectify(left_raw, right_raw, &out.first, &out.second);
  return out;
}

}  // namespace embedded_calibration_stereo::core
