#include "embedded_calibration_stereo/core/geometry/camera_model.h"

#include <Eigen/LU>
#include <cmath>

#include "embedded_calibration_stereo/core/geometry/plumb_bob_distortion.h"

namespace embedded_calibration_stereo::core {

std::string PinholeCamera::validate() const {
  if (width <= 0) return "width must be > 0";
  if (height <= 0) return "height must be > 0";
  if (!(fx > 0) || !std::isfinite(fx)) return "fx must be > 0";
  if (!(fy > 0) || !std::isfinite(fy)) return "fy must be > 0";
  if (!std::isfinite(cx) || !std::isfinite(cy)) return "cx and cy must be finite";
  for (double d : dist)
    if (!std::isfinite(d)) return "distortion coefficients must be finite";
  return "";
}

Eigen::Vector2d PinholeCamera::distort(const Eigen::Vector2d& xn) const {
  Eigen::Vector2d xd;
  plumb_bob::distort(dist.data(), xn.x(), xn.y(), &xd.x(), &xd.y());
  return xd;
}

Eigen::Vector2d PinholeCamera::undistortNormalized(const Eigen::Vector2d& xd) const {
  // Newton on distort(x) - xd = 0 with the analytic Jacobian; plumb_bob is well conditioned
  // inside the image, so a handful of steps reach machine precision.
  Eigen::Vector2d x = xd;
  for (int it = 0; it < 50; ++it) {
    Eigen::Vector2d distorted;
    Eigen::Matrix2d J;
    plumb_bob::distortWithJacobian(dist.data(), x.x(), x.y(), &distorted.x(), &distorted.y(), &J);
    const Eigen::Vector2d residual = distorted - xd;
    if (residual.squaredNorm() < 1e-30) break;
    const Eigen::Vector2d step = J.partialPivLu().solve(residual);
    x -= step;
    if (step.squaredNorm() < 1e-30) break;
  }
  return x;
}

Eigen::Vector2d PinholeCamera::normalizedToPixel(const Eigen::Vector2d& xn) const {
  const Eigen::Vector2d d = distort(xn);
  return {fx * d.x() + skew * d.y() + cx, fy * d.y() + cy};
}

bool PinholeCamera::project(const Eigen::Vector3d& p, Eigen::Vector2d* pixel) const {
  if (!(p.z() > 0)) return false;
  *pixel = normalizedToPixel(Eigen::Vector2d(p.x() / p.z(), p.y() / p.z()));
  return true;
}

Eigen::Vector2d PinholeCamera::pixelToNormalized(const Eigen::Vector2d& pixel) const {
  const double yd = (pixel.y() - cy) / fy;
  const double xd = (pixel.x() - cx - skew * yd) / fx;
  return undistortNormalized(Eigen::Vector2d(xd, yd));
}

Eigen::Vector2d PinholeCamera::undistortPixel(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d xn = pixelToNormalized(pixel);
  return {fx * xn.x() + skew * xn.y() + cx, fy * xn.y() + cy};
}

Eigen::Matrix3d PinholeCamera::K() const {
  Eigen::Matrix3d k;
  k << fx, skew, cx, 0, fy, cy, 0, 0, 1;
  return k;
}

PinholeCamera PinholeCamera::withFocalScale(double scale) const {
  PinholeCamera c = *this;
  c.fx *= scale;
  c.fy *= scale;
  return c;
}

}  // namespace embedded_calibration_stereo::core
