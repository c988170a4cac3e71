#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "embedded_calibration_stereo/core/geometry/plumb_bob_distortion.h"

namespace embedded_calibration_stereo::core {

namespace {

// A raw left pixel of the reference at one depth (index into options.depths_m).
struct Sample {
  Eigen::Vector2d left_pixel;
  int depth_index = 0;
};

// The estimate's rectification, in the form the residuals need.
struct EstimatedRectification {
  StereoRig rig;
  Eigen::Matrix3d H1, H2;  // K'_i R_i: normalised undistorted ray -> homogeneous rectified pixel
  Eigen::Matrix3d R1;
  Eigen::Matrix4d Q;

  EstimatedRectification(const StereoRig& estimate, const RectificationOptions& options) : rig(estimate) {
    const RectificationGeometry g = computeRectificationGeometry(estimate, options);
    Eigen::Matrix3d R2, K1, K2;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        R1(r, c) = g.R1(r, c), R2(r, c) = g.R2(r, c);
        K1(r, c) = g.P1(r, c), K2(r, c) = g.P2(r, c);
      }
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) Q(r, c) = g.Q(r, c);
    H1 = K1 * R1;
    H2 = K2 * R2;
  }

  static Eigen::Vector2d rectify(const PinholeCamera& cam, const Eigen::Matrix3d& H, const Eigen::Vector2d& raw) {
    const Eigen::Vector3d h = H * cam.pixelToNormalized(raw).homogeneous();
    return h.hnormalized();
  }
  // Depth (rectified left frame) of a disparity, and its inverse, by Q.
  double depthOf(double disparity) const { return Q(2, 3) / (Q(3, 2) * disparity + Q(3, 3)); }
  double disparityOf(double depth) const {
    return std::isinf(depth) ? -Q(3, 3) / Q(3, 2) : (Q(2, 3) / depth - Q(3, 3)) / Q(3, 2);
  }
};

struct Residual {
  double misalignment_px = 0, bias_px = 0, depth_error_pct = 0;
};

// The residuals of a correspondence rectified to `l` and `r` by the estimate, of the point at
// `depth` along `ray` (the reference left camera's, z = 1).
Residual residualOf(const EstimatedRectification& est, const Eigen::Vector2d& l, const Eigen::Vector2d& r,
                    const Eigen::Vector3d& ray, double depth) {
  Residual out;
  const double disparity = l.x() - r.x();
  out.misalignment_px = l.y() - r.y();
  if (std::isinf(depth)) {
    out.bias_px = disparity - est.disparityOf(depth);
    out.depth_error_pct = std::numeric_limits<double>::quiet_NaN();
    return out;
  }
  const double true_depth = (est.R1 * (depth * ray)).z();
  out.bias_px = disparity - est.disparityOf(true_depth);
  out.depth_error_pct = 100.0 * (est.depthOf(disparity) / true_depth - 1.0);
  return out;
}

// Where the reference right camera sees the point at `depth` along `ray`; false behind it.
bool rightPixelOf(const StereoRig& reference, const Eigen::Vector3d& ray, double depth, Eigen::Vector2d* pixel) {
  // At infinity only the direction counts: the right camera sees the rotated ray.
  const Eigen::Vector3d in_right = std::isinf(depth) ? Eigen::Vector3d(reference.right_from_left.linear() * ray)
                                                     : Eigen::Vector3d(reference.right_from_left * (depth * ray));
  return reference.right.project(in_right, pixel);
}

Eigen::Vector3d leftRay(const StereoRig& reference, const Eigen::Vector2d& left_pixel) {
  const Eigen::Vector2d xn = reference.left.pixelToNormalized(left_pixel);
  return Eigen::Vector3d(xn.x(), xn.y(), 1.0);
}

// The residuals of one sample; false when the reference right camera does not see it.
bool sampleResidual(const EstimatedRectification& est, const StereoRig& reference, const Sample& s, double depth,
                    Residual* out) {
  const Eigen::Vector3d ray = leftRay(reference, s.left_pixel);
  Eigen::Vector2d right_pixel;
  if (!rightPixelOf(reference, ray, depth, &right_pixel) || !reference.right.inImage(right_pixel)) return false;
  *out = residualOf(est, EstimatedRectification::rectify(est.rig.left, est.H1, s.left_pixel),
                    EstimatedRectification::rectify(est.rig.right, est.H2, right_pixel), ray, depth);
  return true;
}

// d(rectified right pixel) / d(raw right pixel) of the estimate, analytically: the inverse of
// the distortion's Jacobian, then the rectifying homography's.
Eigen::Matrix2d rightRectificationJacobian(const EstimatedRectification& est, const Eigen::Vector2d& raw) {
  const PinholeCamera& cam = est.rig.right;
  const Eigen::Vector2d xn = cam.pixelToNormalized(raw);
  Eigen::Vector2d distorted;
  Eigen::Matrix2d J;
  plumb_bob::distortWithJacobian(cam.dist.data(), xn.x(), xn.y(), &distorted.x(), &distorted.y(), &J);
  Eigen::Matrix2d pixel_to_distorted;
  pixel_to_distorted << 1.0 / cam.fx, -cam.skew / (cam.fx * cam.fy), 0.0, 1.0 / cam.fy;
  const Eigen::Matrix2d dxn_draw = J.inverse() * pixel_to_distorted;
  const Eigen::Vector3d h = est.H2 * xn.homogeneous();
  const Eigen::Vector2d uv = h.hnormalized();
  const Eigen::Matrix2d duv_dxn = (est.H2.topLeftCorner<2, 2>() - uv * est.H2.block<1, 2>(2, 0)) / h.z();
  return duv_dxn * dxn_draw;
}

void checkInputs(const StereoRig& estimate, const StereoRig& reference, const StereoAccuracyOptions& options) {
  if (options.grid_cols < 1 || options.grid_rows < 1)
    throw std::invalid_argument("stereo accuracy: grid_cols and grid_rows must be >= 1");
  if (options.depths_m.empty()) throw std::invalid_argument("stereo accuracy: no depth given");
  for (double z : options.depths_m)
    if (!(z > 0)) throw std::invalid_argument("stereo accuracy: depths must be > 0 (infinity allowed)");
  for (const StereoRig* rig : {&estimate, &reference}) {
    const std::string problem = rig->validate();
    if (!problem.empty()) throw std::invalid_argument("stereo accuracy: rig invalid: " + problem);
  }
  if (estimate.left.width != reference.left.width || estimate.left.height != reference.left.height ||
      estimate.right.width != reference.right.width || estimate.right.height != reference.right.height)
    throw std::invalid_argument("stereo accuracy: the two calibrations differ in image size");
}

// Grid over the reference left image, each cell centre at every depth, kept where the
// reference right camera sees it.
std::vector<Sample> visibleSamples(const EstimatedRectification& est, const StereoRig& reference,
                                   const StereoAccuracyOptions& options) {
  std::vector<Sample> samples;
  const double w = reference.left.width, h = reference.left.height;
  for (size_t d = 0; d < options.depths_m.size(); ++d)
    for (int j = 0; j < options.grid_rows; ++j)
      for (int i = 0; i < options.grid_cols; ++i) {
        Sample s;
        s.left_pixel = Eigen::Vector2d((i + 0.5) * w / options.grid_cols - 0.5, (j + 0.5) * h / options.grid_rows - 0.5);
        s.depth_index = static_cast<int>(d);
        Residual unused;
        if (sampleResidual(est, reference, s, options.depths_m[d], &unused)) samples.push_back(s);
      }
  return samples;
}

// Sums of squares and maxima, per depth and overall.
class FigureAccumulator {
 public:
  explicit FigureAccumulator(const StereoAccuracyOptions& options) : depths_(options.depths_m) {
    per_depth_.resize(depths_.size());
  }
  // `sq`: the squares (measured) or variances (predicted) of misalignment, bias, depth error.
  void add(int depth_index, const Eigen::Vector3d& sq) {
    for (Sums* s : {&overall_, &per_depth_[depth_index]}) {
      s->sum += sq;
      s->max = s->max.cwiseMax(sq);
      ++s->n;
    }
  }
  StereoAccuracy result() const {
    StereoAccuracy out;
    out.samples = overall_.n;
    out.misalignment_px = figure(overall_, 0);
    out.disparity_bias_px = figure(overall_, 1);
    for (size_t d = 0; d < depths_.size(); ++d) {
      DepthAccuracy a;
      a.depth_m = depths_[d];
      a.samples = per_depth_[d].n;
      a.misalignment_px = figure(per_depth_[d], 0);
      a.disparity_bias_px = figure(per_depth_[d], 1);
      if (std::isinf(depths_[d]))
        a.depth_error_pct.rms = a.depth_error_pct.max = std::numeric_limits<double>::quiet_NaN();
      else
        a.depth_error_pct = figure(per_depth_[d], 2);
      out.at_depth.push_back(a);
    }
    return out;
  }

 private:
  struct Sums {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero(), max = Eigen::Vector3d::Zero();
    int n = 0;
  };
  static AccuracyFigure figure(const Sums& s, int i) {
    if (s.n == 0) return {};
    return {std::sqrt(s.sum[i] / s.n), std::sqrt(s.max[i])};
  }
  std::vector<double> depths_;
  Sums overall_;
  std::vector<Sums> per_depth_;
};

Eigen::Vector3d asVector(const Residual& r, bool far) {
  return Eigen::Vector3d(r.misalignment_px, r.bias_px, far ? 0.0 : r.depth_error_pct);
}

}  // namespace

StereoAccuracy evaluateStereoAccuracy(const StereoRig& estimate, const StereoRig& reference,
                                      const StereoAccuracyOptions& options) {
  checkInputs(estimate, reference, options);
  const EstimatedRectification est(estimate, options.rectification);
  FigureAccumulator acc(options);
  for (const Sample& s : visibleSamples(est, reference, options)) {
    const double depth = options.depths_m[s.depth_index];
    Residual r;
    sampleResidual(est, reference, s, depth, &r);
    acc.add(s.depth_index, asVector(r, std::isinf(depth)).cwiseAbs2());
  }
  return acc.result();
}

StereoAccuracy predictStereoAccuracy(const StereoRig& estimate, const RigCovariance& covariance,
                                     const StereoAccuracyOptions& options) {
  checkInputs(estimate, estimate, options);
  for (int k = 0; k < kRigParameterCount; ++k)
    if (!std::isfinite(covariance(k, k)) || covariance(k, k) < 0)
      throw std::invalid_argument("stereo accuracy: covariance diagonal " + std::to_string(k) +
                                  " negative or not finite");
  const EstimatedRectification est(estimate, options.rectification);
  const std::vector<Sample> samples = visibleSamples(est, estimate, options);
  std::vector<int> free;  // parameters with a variance
  for (int k = 0; k < kRigParameterCount; ++k)
    if (covariance(k, k) > 0) free.push_back(k);
  const int n = static_cast<int>(samples.size()), m = static_cast<int>(free.size());
  // Per sample at the estimate: the left rectified pixel (the reference moves only the right
  // one), the ray, the right raw pixel and the derivative of its rectification. A moved
  // reference moves the right raw pixel by a small fraction of a pixel: its rectification is
  // linear there, which spares a Newton undistortion per sample and parameter.
  struct Base {
    Eigen::Vector2d left_rect, right_raw, right_rect;
    Eigen::Vector3d ray;
    Eigen::Matrix2d right_jacobian;
  };
  std::vector<Base> base(n);
  for (int s = 0; s < n; ++s) {
    Base& b = base[s];
    b.left_rect = EstimatedRectification::rectify(estimate.left, est.H1, samples[s].left_pixel);
    b.ray = leftRay(estimate, samples[s].left_pixel);
    rightPixelOf(estimate, b.ray, options.depths_m[samples[s].depth_index], &b.right_raw);
    b.right_rect = EstimatedRectification::rectify(estimate.right, est.H2, b.right_raw);
    b.right_jacobian = rightRectificationJacobian(est, b.right_raw);
  }
  // Jacobians of (misalignment, bias, depth error) of every sample over the free parameters.
  Eigen::MatrixXd J[3];
  for (Eigen::MatrixXd& j : J) j = Eigen::MatrixXd::Zero(n, m);
  const RigParameters parameters = rigParameters(estimate);
  for (int c = 0; c < m; ++c) {
    const int k = free[c];
    const double step = std::sqrt(covariance(k, k));
    const bool moves_left_ray = k < 9;  // the reference left camera's intrinsics
    for (int side = 0; side < 2; ++side) {
      RigParameters moved = parameters;
      moved[k] += side == 0 ? step : -step;
      const StereoRig reference = rigFromParameters(moved, estimate);
      for (int s = 0; s < n; ++s) {
        const Base& b = base[s];
        const double depth = options.depths_m[samples[s].depth_index];
        const Eigen::Vector3d ray = moves_left_ray ? leftRay(reference, samples[s].left_pixel) : b.ray;
        Eigen::Vector2d right_raw;
        rightPixelOf(reference, ray, depth, &right_raw);
        const Eigen::Vector2d right_rect = b.right_rect + b.right_jacobian * (right_raw - b.right_raw);
        const Residual r = residualOf(est, b.left_rect, right_rect, ray, depth);
        const Eigen::Vector3d v = asVector(r, std::isinf(depth));
        if (side == 0) {
          for (int q = 0; q < 3; ++q) J[q](s, c) = v[q];
        } else {
          for (int q = 0; q < 3; ++q) J[q](s, c) = (J[q](s, c) - v[q]) / (2.0 * step);
        }
      }
    }
  }
  Eigen::MatrixXd C(m, m);
  for (int a = 0; a < m; ++a)
    for (int b = 0; b < m; ++b) C(a, b) = covariance(free[a], free[b]);
  FigureAccumulator acc(options);
  Eigen::Vector3d variance;
  for (int s = 0; s < n; ++s) {
    for (int q = 0; q < 3; ++q) variance[q] = std::max(0.0, J[q].row(s).dot(C * J[q].row(s).transpose()));
    acc.add(samples[s].depth_index, variance);
  }
  return acc.result();
}

}  // namespace embedded_calibration_stereo::core
