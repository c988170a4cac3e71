#pragma once
// Ceres functor of the bundle adjuster's scene constraints (bundle_adjuster.h,
// StereoObservation::scene): a scene point seen by both cameras at the same instant lies
// on the epipolar line of the rig, whatever its depth. The residual is the Sampson distance of
// the pair of undistorted rays under E = [t]x R (right_from_left), the first-order distance of
// the two observations to the nearest pair that satisfies the constraint, in pixels (times a
// focal length) and times a weight that whitens it against the board corners' noise. It does
// not depend on the length of the translation: the scene gives the direction of the baseline,
// the boards its length.
//
// Parameter blocks: intrinsics[9] of the left and of the right camera, extrinsics[6]
// (reprojection_cost.h).
//
// Threading: immutable after construction except the weight, which the owner changes only
// between solves; Ceres may evaluate the functor from several threads at once.
#include <ceres/autodiff_cost_function.h>
#include <ceres/jet.h>
#include <ceres/rotation.h>

#include <Eigen/Core>

#include "embedded_calibration_stereo/core/calibration/reprojection_cost.h"
#include "embedded_calibration_stereo/core/geometry/camera_model.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"

namespace embedded_calibration_stereo::core {

inline double scalarPart(double v) { return v; }
template <typename T, int N>
double scalarPart(const ceres::Jet<T, N>& v) {
  return v.a;
}

// Raw pixel -> normalised undistorted (*x, *y), differentiable in the intrinsics: the root is
// found in doubles (PinholeCamera's Newton), then one Newton step in T from it, which leaves the
// value and carries the derivative of the implicit function.
template <typename T>
void undistortRawPixel(const T* intrinsics, const Eigen::Vector2d& pixel, T* x, T* y) {
  const T xd = (T(pixel.x()) - intrinsics[kCx]) / intrinsics[kFx];
  const T yd = (T(pixel.y()) - intrinsics[kCy]) / intrinsics[kFy];
  PinholeCamera c;
  for (int k = 0; k < plumb_bob::kCoefficientCount; ++k) c.dist[k] = scalarPart(intrinsics[kK1 + k]);
  const Eigen::Vector2d x0 = c.undistortNormalized(Eigen::Vector2d(scalarPart(xd), scalarPart(yd)));
  double dx0, dy0;
  Eigen::Matrix2d J;
  plumb_bob::distortWithJacobian(c.dist.data(), x0.x(), x0.y(), &dx0, &dy0, &J);
  const Eigen::Matrix2d Ji = J.inverse();
  T dx, dy;
  plumb_bob::distort(intrinsics + kK1, T(x0.x()), T(x0.y()), &dx, &dy);
  const T rx = dx - xd, ry = dy - yd;
  *x = T(x0.x()) - (Ji(0, 0) * rx + Ji(0, 1) * ry);
  *y = T(x0.y()) - (Ji(1, 0) * rx + Ji(1, 1) * ry);
}

class SceneEpipolarCost {
 public:
  // focal_px: converts normalised distances to pixels (the right camera's focal length in
  // force); *weight: whitening factor, read at every evaluation.
  SceneEpipolarCost(const SceneMatch& match, double focal_px, const double* weight)
      : left_(match.left_u, match.left_v), right_(match.right_u, match.right_v), focal_(focal_px), weight_(weight) {}

  template <typename T>
  bool operator()(const T* left, const T* right, const T* extrinsics, T* residual) const {
    Eigen::Matrix<T, 3, 1> a, b;
    undistortRawPixel(left, left_, &a[0], &a[1]);
    undistortRawPixel(right, right_, &b[0], &b[1]);
    a[2] = T(1.0);
    b[2] = T(1.0);
    Eigen::Matrix<T, 3, 3> R;
    ceres::AngleAxisToRotationMatrix(extrinsics, ceres::ColumnMajorAdapter3x3(R.data()));
    Eigen::Matrix<T, 3, 3> tx;
    tx << T(0.0), -extrinsics[5], extrinsics[4], extrinsics[5], T(0.0), -extrinsics[3], -extrinsics[4],
        extrinsics[3], T(0.0);
    const Eigen::Matrix<T, 3, 3> E = tx * R;
    const Eigen::Matrix<T, 3, 1> Ea = E * a, Etb = E.transpose() * b;
    const T denominator = Ea[0] * Ea[0] + Ea[1] * Ea[1] + Etb[0] * Etb[0] + Etb[1] * Etb[1];
    if (!(denominator > T(0.0))) return false;
    residual[0] = T(*weight_ * focal_) * b.dot(Ea) / sqrt(denominator);
    return true;
  }

  static ceres::CostFunction* Create(const SceneMatch& match, double focal_px, const double* weight) {
    return new ceres::AutoDiffCostFunction<SceneEpipolarCost, 1, kIntrinsicsSize, kIntrinsicsSize,
                                           kExtrinsicsSize>(
        new SceneEpipolarCost(match, focal_px, weight));
  }

 private:
  Eigen::Vector2d left_, right_;
  double focal_;
  const double* weight_;
};

}  // namespace embedded_calibration_stereo::core
