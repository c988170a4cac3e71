#include "camera_rays.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/plumb_bob_distortion.h"

namespace embedded_calibration_stereo::core {
namespace sim {

void CameraRays::jacobian(double x, double y, double J[4]) const {
  // (u, v) = A * distort(x, y) + c with A = [fx skew; 0 fy], so d(x,y)/d(u,v) = (A * Jd)^-1.
  double xd, yd;
  Eigen::Matrix2d Jd;
  plumb_bob::distortWithJacobian(camera.dist.data(), x, y, &xd, &yd, &Jd);
  Eigen::Matrix2d A;
  A << camera.fx, camera.skew, 0.0, camera.fy;
  const Eigen::Matrix2d inv = (A * Jd).inverse();
  J[0] = inv(0, 0), J[1] = inv(0, 1), J[2] = inv(1, 0), J[3] = inv(1, 1);
}

bool sameIntrinsics(const PinholeCamera& a, const PinholeCamera& b) {
  return a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy &&
         a.cx == b.cx && a.cy == b.cy && a.skew == b.skew && a.dist == b.dist;
}

CameraRays computeCameraRays(const PinholeCamera& camera) {
  CameraRays rays;
  rays.camera = camera;
  rays.x.create(camera.height, camera.width, CV_32F);
  rays.y.create(camera.height, camera.width, CV_32F);
  // Pixel -> distorted normalised is affine: (u, v) = A * (xd, yd) + c.
  Eigen::Matrix2d A;
  A << camera.fx, camera.skew, 0.0, camera.fy;
  const Eigen::Matrix2d A_inv = A.inverse();
  std::vector<double> row_max_radius(camera.height, 0.0);

  cv::parallel_for_(cv::Range(0, camera.height), [&](const cv::Range& range) {
    for (int v = range.start; v < range.end; ++v) {
      float* out_x = rays.x.ptr<float>(v);
      float* out_y = rays.y.ptr<float>(v);
      double max_r = 0.0, x = 0.0, y = 0.0;
      Eigen::Vector2d previous_target;
      for (int u = 0; u < camera.width; ++u) {
        const Eigen::Vector2d target = A_inv * Eigen::Vector2d(u - camera.cx, v - camera.cy);
        // Newton on distort(x) = target, warm-started from the left neighbour's solution (the
        // row's first pixel starts at the target; plumb_bob is mild inside the image); stop at
        // machine precision so the rendered corners are exact.
        if (u == 0) {
          x = target.x(), y = target.y();
        } else {
          x += target.x() - previous_target.x(), y += target.y() - previous_target.y();
        }
        previous_target = target;
        Eigen::Matrix2d J;
        for (int it = 0; it < 30; ++it) {
          double xd, yd;
          plumb_bob::distortWithJacobian(camera.dist.data(), x, y, &xd, &yd, &J);
          const Eigen::Vector2d step = J.inverse() * Eigen::Vector2d(xd - target.x(), yd - target.y());
          x -= step.x();
          y -= step.y();
          if (step.squaredNorm() < 1e-28) break;
        }
        out_x[u] = static_cast<float>(x);
        out_y[u] = static_cast<float>(y);
        max_r = std::max(max_r, std::hypot(x, y));
      }
      row_max_radius[v] = max_r;
    }
  });
  rays.max_radius = *std::max_element(row_max_radius.begin(), row_max_radius.end());
  cv::minMaxLoc(rays.x, &rays.x_min, &rays.x_max);
  cv::minMaxLoc(rays.y, &rays.y_min, &rays.y_max);
  return rays;
}

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
