// The one plumb_bob distortion (plumb_bob_distortion.h) against OpenCV's own implementation of
// the model (cv::projectPoints, with its analytic Jacobian), on every path that uses it: the
// double-precision projection and Jacobian of PinholeCamera and the simulator's ray maps, and
// the Ceres-templated reprojection costs evaluated with Jets. Strong coefficients on every term
// (k1, k2, p1, p2, k3) over a grid covering the whole image, so that a wrong sign or factor in
// any term shows; round trips through our own inverse could not show it.
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <vector>

#include "../../src/core/sim/camera_rays.h"
#include "embedded_calibration_stereo/core/calibration/reprojection_cost.h"
#include "embedded_calibration_stereo/core/geometry/camera_model.h"
#include "embedded_calibration_stereo/core/geometry/plumb_bob_distortion.h"

namespace embedded_calibration_stereo::core {
namespace {

// A wide-angle lens: every coefficient large enough to move the image edge by pixels (p1, p2
// by ~5-10 px at the corners), still invertible over the image.
PinholeCamera strongCamera() {
  PinholeCamera c;
  c.width = 752;
  c.height = 480;
  c.fx = 640.5;
  c.fy = 655.25;
  c.cx = 381.7;
  c.cy = 233.1;
  c.dist = {{-0.32, 0.14, 0.012, -0.009, -0.025}};
  return c;
}

cv::Matx33d K(const PinholeCamera& c) { return cv::Matx33d(c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1); }
cv::Mat D(const PinholeCamera& c) { return cv::Mat(cv::Matx<double, 1, 5>(c.dist.data()), true); }

// Normalised undistorted coordinates (z = 1) of a grid of raw pixels over the whole image,
// border included, found by OpenCV's own undistortion (so the grid covers the image exactly).
std::vector<cv::Point3d> gridOverImage(const PinholeCamera& c) {
  std::vector<cv::Point2d> raw;
  for (int v = 0; v <= c.height; v += 24)
    for (int u = 0; u <= c.width; u += 24)
      raw.emplace_back(std::min(u, c.width - 1), std::min(v, c.height - 1));
  std::vector<cv::Point2d> normalised;
  cv::undistortPoints(raw, normalised, K(c), D(c), cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 200, 1e-14));
  std::vector<cv::Point3d> points;
  for (const cv::Point2d& n : normalised) points.emplace_back(n.x, n.y, 1.0);
  return points;
}

// OpenCV's projection of points in the camera frame and its 2N x 15 Jacobian (columns: rvec 3,
// tvec 3, fx fy, cx cy, k1 k2 p1 p2 k3).
void openCvProjection(const PinholeCamera& c, const std::vector<cv::Point3d>& points,
                      std::vector<cv::Point2d>* pixels, cv::Mat* jacobian) {
  cv::projectPoints(points, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K(c), D(c), *pixels,
                    *jacobian);
  ASSERT_EQ(jacobian->cols, 15);
}

TEST(PlumbBobDistortion, ProjectionMatchesOpenCvOverTheWholeImage) {
  const PinholeCamera c = strongCamera();
  const std::vector<cv::Point3d> points = gridOverImage(c);
  std::vector<cv::Point2d> reference;
  cv::Mat jacobian;
  openCvProjection(c, points, &reference, &jacobian);
  double worst = 0.0, largest_tangential_shift = 0.0;
  for (size_t i = 0; i < points.size(); ++i) {
    // At several depths: the projection divides by z first.
    for (double z : {0.5, 1.0, 7.0}) {
      Eigen::Vector2d px;
      ASSERT_TRUE(c.project(Eigen::Vector3d(points[i].x, points[i].y, 1.0) * z, &px));
      worst = std::max(worst, (px - Eigen::Vector2d(reference[i].x, reference[i].y)).norm());
    }
    PinholeCamera radial_only = c;
    radial_only.dist[2] = radial_only.dist[3] = 0.0;
    largest_tangential_shift = std::max(
        largest_tangential_shift,
        (c.normalizedToPixel({points[i].x, points[i].y}) -
         radial_only.normalizedToPixel({points[i].x, points[i].y}))
            .norm());
  }
  EXPECT_LT(worst, 1e-9) << "px, over " << points.size() << " points";
  // The grid reaches the corners, where the tangential terms matter: the test can see them.
  EXPECT_GT(largest_tangential_shift, 3.0) << "px";
}

TEST(PlumbBobDistortion, JacobianMatchesOpenCvOverTheWholeImage) {
  const PinholeCamera c = strongCamera();
  const std::vector<cv::Point3d> points = gridOverImage(c);
  std::vector<cv::Point2d> reference;
  cv::Mat jacobian;
  openCvProjection(c, points, &reference, &jacobian);
  double worst_rel = 0.0, worst_inverse_rel = 0.0;
  const sim::CameraRays rays = sim::computeCameraRays(c);
  for (size_t i = 0; i < points.size(); ++i) {
    double xd, yd;
    Eigen::Matrix2d J;
    plumb_bob::distortWithJacobian(c.dist.data(), points[i].x, points[i].y, &xd, &yd, &J);
    EXPECT_NEAR(c.fx * xd + c.cx, reference[i].x, 1e-9);
    EXPECT_NEAR(c.fy * yd + c.cy, reference[i].y, 1e-9);
    // At z = 1 with zero rotation, d(u, v)/d(tx, ty) = diag(fx, fy) * d(xd, yd)/d(x, y).
    Eigen::Matrix2d reference_J;
    for (int r = 0; r < 2; ++r)
      for (int k = 0; k < 2; ++k) reference_J(r, k) = jacobian.at<double>(2 * i + r, 3 + k);
    Eigen::Matrix2d ours = J;
    ours.row(0) *= c.fx;
    ours.row(1) *= c.fy;
    worst_rel = std::max(worst_rel, (ours - reference_J).norm() / reference_J.norm());
    // The simulator's d(x, y)/d(u, v) (anti-aliasing footprints) is its inverse.
    double inverse[4];
    rays.jacobian(points[i].x, points[i].y, inverse);
    const Eigen::Matrix2d reference_inverse = reference_J.inverse();
    const Eigen::Matrix2d sim_inverse = Eigen::Map<Eigen::Matrix<double, 2, 2, Eigen::RowMajor>>(inverse);
    worst_inverse_rel = std::max(worst_inverse_rel, (sim_inverse - reference_inverse).norm() /
                                                        reference_inverse.norm());
  }
  EXPECT_LT(worst_rel, 1e-12);
  EXPECT_LT(worst_inverse_rel, 1e-12);
}

TEST(PlumbBobDistortion, SimulatorRayMapsAreOpenCvsUndistortion) {
  const PinholeCamera c = strongCamera();
  const sim::CameraRays rays = sim::computeCameraRays(c);
  // Every ray of the map, projected by OpenCV, lands back on its pixel centre (the maps hold
  // floats: about 1e-7 relative, i.e. well under 1e-3 px).
  std::vector<cv::Point3d> points;
  std::vector<cv::Point2d> centres;
  for (int v = 0; v < c.height; v += 13)
    for (int u = 0; u < c.width; u += 13) {
      points.emplace_back(rays.x.at<float>(v, u), rays.y.at<float>(v, u), 1.0);
      centres.emplace_back(u, v);
    }
  std::vector<cv::Point2d> projected;
  cv::projectPoints(points, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K(c), D(c), projected);
  double worst = 0.0;
  for (size_t i = 0; i < points.size(); ++i) worst = std::max(worst, cv::norm(projected[i] - centres[i]));
  EXPECT_LT(worst, 1e-3) << "px";
}

TEST(PlumbBobDistortion, UndistortionInvertsOpenCvsProjection) {
  const PinholeCamera c = strongCamera();
  const std::vector<cv::Point3d> points = gridOverImage(c);
  std::vector<cv::Point2d> raw;
  cv::Mat jacobian;
  openCvProjection(c, points, &raw, &jacobian);
  double worst = 0.0;
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector2d n = c.pixelToNormalized(Eigen::Vector2d(raw[i].x, raw[i].y));
    worst = std::max(worst, (n - Eigen::Vector2d(points[i].x, points[i].y)).norm());
  }
  EXPECT_LT(worst, 1e-10) << "normalised units";
}

// The Ceres path: the templated costs, evaluated by Ceres (Jets for the derivatives), against
// cv::projectPoints for the pixel and its Jacobian with respect to fx, fy, cx, cy, k1..k3.
TEST(PlumbBobDistortion, CeresCostsMatchOpenCvProjectionAndJacobian) {
  const PinholeCamera c = strongCamera();
  std::array<double, kIntrinsicsSize> intrinsics = {
      {c.fx, c.fy, c.cx, c.cy, c.dist[0], c.dist[1], c.dist[2], c.dist[3], c.dist[4]}};
  // Left camera: board pose = identity, so the corner is the point in the camera frame.
  const std::array<double, kBoardPoseSize> identity_pose = {{0, 0, 0, 1, 0, 0, 0}};
  // Right camera: right_from_left = (rotation vector, translation), OpenCV's rvec/tvec.
  const std::array<double, kExtrinsicsSize> extrinsics = {{0.02, -0.015, 0.01, -0.12, 0.004, 0.002}};
  std::vector<cv::Point3d> points;
  for (const cv::Point3d& n : gridOverImage(c)) points.push_back(n * 2.0);

  for (const bool right : {false, true}) {
    std::vector<cv::Point2d> reference;
    cv::Mat jacobian;
    const cv::Vec3d rvec = right ? cv::Vec3d(extrinsics[0], extrinsics[1], extrinsics[2]) : cv::Vec3d(0, 0, 0);
    const cv::Vec3d tvec = right ? cv::Vec3d(extrinsics[3], extrinsics[4], extrinsics[5]) : cv::Vec3d(0, 0, 0);
    cv::projectPoints(points, rvec, tvec, K(c), D(c), reference, jacobian);
    double worst_px = 0.0, worst_rel = 0.0;
    for (size_t i = 0; i < points.size(); ++i) {
      const Eigen::Vector3d corner(points[i].x, points[i].y, points[i].z);
      std::unique_ptr<ceres::CostFunction> cost(
          right ? RightCornerReprojectionCost::Create(corner, Eigen::Vector2d::Zero())
                : LeftCornerReprojectionCost::Create(corner, Eigen::Vector2d::Zero()));
      const double* blocks[3] = {intrinsics.data(), identity_pose.data(), extrinsics.data()};
      Eigen::Vector2d pixel;  // residual = predicted - observed, observed = 0
      Eigen::Matrix<double, 2, kIntrinsicsSize, Eigen::RowMajor> d_intrinsics;
      double* jacobians[3] = {d_intrinsics.data(), nullptr, nullptr};
      ASSERT_TRUE(cost->Evaluate(blocks, pixel.data(), jacobians));
      worst_px = std::max(worst_px, (pixel - Eigen::Vector2d(reference[i].x, reference[i].y)).norm());
      Eigen::Matrix<double, 2, kIntrinsicsSize> reference_d;
      for (int r = 0; r < 2; ++r)
        for (int k = 0; k < kIntrinsicsSize; ++k) reference_d(r, k) = jacobian.at<double>(2 * i + r, 6 + k);
      worst_rel = std::max(worst_rel, (d_intrinsics - reference_d).norm() / reference_d.norm());
    }
    EXPECT_LT(worst_px, 1e-9) << (right ? "right" : "left");
    EXPECT_LT(worst_rel, 1e-12) << (right ? "right" : "left");
  }
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
