#pragma once
// The plumb_bob distortion of ROS CameraInfo and OpenCV (Brown-Conrady: radial k1, k2, k3,
// tangential p1, p2), written once for every user: PinholeCamera (projection and its Newton
// undistortion), the simulator's ray maps and the Ceres reprojection costs. Coefficients are in
// CameraInfo.D order, d = {k1, k2, p1, p2, k3}.
//
// distort() is templated on the scalar so that Ceres differentiates it automatically (Jets);
// distortWithJacobian() is the double-precision value with its analytic 2x2 Jacobian, which
// the Newton undistortions and the simulator's anti-aliasing footprints need. Both evaluate the
// same expressions in the same order, so a double evaluation gives the same bits everywhere.
//
// Threading: pure functions.
#include <Eigen/Core>

namespace embedded_calibration_stereo::core {
namespace plumb_bob {

constexpr int kCoefficientCount = 5;  // k1, k2, p1, p2, k3

// 1 + k1 r^2 + k2 r^4 + k3 r^6, in Horner form.
template <typename T>
inline T radialFactor(const T* d, const T& r2) {
  return T(1.0) + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
}

// Normalised undistorted (x, y) = (X/Z, Y/Z) -> normalised distorted (*xd, *yd).
template <typename T>
inline void distort(const T* d, const T& x, const T& y, T* xd, T* yd) {
  const T& p1 = d[2];
  const T& p2 = d[3];
  const T r2 = x * x + y * y;
  const T radial = radialFactor(d, r2);
  *xd = x * radial + T(2.0) * p1 * x * y + p2 * (r2 + T(2.0) * x * x);
  *yd = y * radial + p1 * (r2 + T(2.0) * y * y) + T(2.0) * p2 * x * y;
}

// distort() and J = d(xd, yd)/d(x, y).
inline void distortWithJacobian(const double* d, double x, double y, double* xd, double* yd,
                                Eigen::Matrix2d* J) {
  distort(d, x, y, xd, yd);
  const double p1 = d[2], p2 = d[3];
  const double r2 = x * x + y * y;
  const double f = radialFactor(d, r2);
  const double df_dr2 = d[0] + r2 * (2.0 * d[1] + 3.0 * r2 * d[4]);
  (*J)(0, 0) = f + 2.0 * x * x * df_dr2 + 2.0 * p1 * y + 6.0 * p2 * x;
  (*J)(0, 1) = 2.0 * x * y * df_dr2 + 2.0 * p1 * x + 2.0 * p2 * y;
  (*J)(1, 0) = (*J)(0, 1);
  (*J)(1, 1) = f + 2.0 * y * y * df_dr2 + 6.0 * p1 * y + 2.0 * p2 * x;
}

}  // namespace plumb_bob
}  // namespace embedded_calibration_stereo::core
