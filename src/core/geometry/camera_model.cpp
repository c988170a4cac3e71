#include "embedded_calibration_stereo/core/geometry/camera_model.h"

#include <Eigen/LU>
#include <cmath>

namespace ecs {

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

namespace {
// Radial factor and its derivative with respect to r^2.
inline void radial(const std::array<double, 5>& d, double r2, double* f, double* df_dr2) {
  *f = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
  *df_dr2 = d[0] + r2 * (2.0 * d[1] + 3.0 * r2 * d[4]);
}
}  // namespace

Eigen::Vector2d PinholeCamera::distort(const Eigen::Vector2d& xn) const {
  const double x = xn.x(), y = xn.y(), r2 = x * x + y * y;
  double f, df;
  radial(dist, r2, &f, &df);
  const double p1 = dist[2], p2 = dist[3];
  return {x * f + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
          y * f + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y};
}

Eigen::Vector2d PinholeCamera::undistortNormalized(const Eigen::Vector2d& xd) const {
  // Newton on distort(x) - xd = 0 with the analytic Jacobian; plumb_bob is well conditioned
  // inside the image, so a handful of steps reach machine precision.
  Eigen::Vector2d x = xd;
  const double p1 = dist[2], p2 = dist[3];
  for (int it = 0; it < 50; ++it) {
    const double r2 = x.squaredNorm();
    double f, df;
    radial(dist, r2, &f, &df);
    const Eigen::Vector2d residual = distort(x) - xd;
    if (residual.squaredNorm() < 1e-30) break;
    Eigen::Matrix2d J;
    J(0, 0) = f + 2.0 * x.x() * x.x() * df + 2.0 * p1 * x.y() + 6.0 * p2 * x.x();
    J(0, 1) = 2.0 * x.x() * x.y() * df + 2.0 * p1 * x.x() + 2.0 * p2 * x.y();
    J(1, 0) = 2.0 * x.x() * x.y() * df + 2.0 * p1 * x.x() + 2.0 * p2 * x.y();
    J(1, 1) = f + 2.0 * x.y() * x.y() * df + 6.0 * p1 * x.y() + 2.0 * p2 * x.x();
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

}  // namespace ecs
