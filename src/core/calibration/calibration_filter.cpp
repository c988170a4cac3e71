#include "embedded_calibration_stereo/core/calibration/calibration_filter.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace embedded_calibration_stereo::core {

namespace {

// The groups' parameters (rigParameters() order).
struct Group {
  const char* name;
  std::vector<int> index;
};

const std::vector<Group>& groups() {
  static const std::vector<Group> g = {
      {"left focal length", {0, 1}},  {"left principal point", {2, 3}},   {"left distortion", {4, 5, 6, 7, 8}},
      {"right focal length", {9, 10}}, {"right principal point", {11, 12}}, {"right distortion", {13, 14, 15, 16, 17}},
      {"stereo rotation", {18, 19, 20}}, {"stereo translation", {21, 22, 23}},
  };
  return g;
}

// P(X > x) for X chi-square with k degrees of freedom (closed forms for integer k).
double chiSquareSurvival(double x, int k) {
  if (x <= 0.0) return 1.0;
  if (k % 2 == 0) {
    double term = 1.0, sum = 1.0;
    for (int i = 1; i < k / 2; ++i) sum += (term *= 0.5 * x / i);
    return std::exp(-0.5 * x) * sum;
  }
  double term = std::sqrt(2.0 * x / M_PI) * std::exp(-0.5 * x), sum = 0.0;
  for (int i = 1; i <= (k - 1) / 2; ++i) {
    sum += term;
    term *= x / (2 * i + 1);
  }
  return std::erfc(std::sqrt(0.5 * x)) + sum;
}

// R_window R_state^T: what turns the state's right camera into the window's.
Eigen::Matrix3d windowFromStateRotation(const Eigen::Vector3d& window_rotation, const RigParameters& state) {
  return rotationFromVector(window_rotation) * rotationFromVector(state.segment<3>(18)).transpose();
}

// The state's stereo translation at the window's stereo rotation: t = -R C with the state's right
// camera centre C = -R_state^T t_state. Heat and knocks turn the right camera about its own centre,
// which leaves C where it was and turns t with R; comparing t as it was would take every such turn
// for a move of the camera.
Eigen::Vector3d translationAt(const Eigen::Vector3d& window_rotation, const RigParameters& state) {
  return windowFromStateRotation(window_rotation, state) * state.segment<3>(21);
}

// d translationAt / d rotation (of the window's when `of_window`, else of the state's), by central
// differences (the function is smooth, and a step of 1e-6 rad is far below any rotation it sees).
Eigen::Matrix3d translationAtRotationJacobian(const Eigen::Vector3d& window_rotation, const RigParameters& state,
                                              bool of_window) {
  constexpr double kStep = 1e-6;
  Eigen::Matrix3d J;
  for (int k = 0; k < 3; ++k) {
    Eigen::Vector3d w_plus = window_rotation, w_minus = window_rotation;
    RigParameters s_plus = state, s_minus = state;
    if (of_window) {
      w_plus[k] += kStep, w_minus[k] -= kStep;
    } else {
      s_plus[18 + k] += kStep, s_minus[18 + k] -= kStep;
    }
    J.col(k) = (translationAt(w_plus, s_plus) - translationAt(w_minus, s_minus)) / (2 * kStep);
  }
  return J;
}

// The random walk's variance per parameter and second.
RigParameters walkVariance(const StereoRig& rig, const CalibrationFilterOptions& options) {
  RigParameters walk = RigParameters::Zero();
  for (int c = 0; c < 2; ++c) {
    const PinholeCamera& camera = c ? rig.right : rig.left;
    const int o = 9 * c;
    walk[o + 0] = std::pow(options.focal_walk_rel * camera.fx, 2);
    walk[o + 1] = std::pow(options.focal_walk_rel * camera.fy, 2);
    walk[o + 2] = walk[o + 3] = std::pow(options.principal_point_walk_px, 2);
    for (int k = 4; k < 9; ++k) walk[o + k] = std::pow(options.distortion_walk, 2);
  }
  for (int k = 18; k < 21; ++k) walk[k] = std::pow(options.rotation_walk_deg * M_PI / 180.0, 2);
  for (int k = 21; k < 24; ++k) walk[k] = std::pow(options.translation_walk_m, 2);
  return walk;
}

// The state with its translation carried to the window's rotation (translationAt), the linear map
// of that carriage (for the state's covariance), and the window's: d(window - carried state) /
// d(window) (the carried translation depends on the window's rotation).
struct Carried {
  RigParameters state;
  RigCovariance jacobian = RigCovariance::Identity(), window_jacobian = RigCovariance::Identity();
};

Carried carriedToWindowRotation(const RigParameters& state, const Eigen::Vector3d& window_rotation) {
  Carried out;
  out.state = state;
  out.state.segment<3>(21) = translationAt(window_rotation, state);
  out.jacobian.block<3, 3>(21, 18) = translationAtRotationJacobian(window_rotation, state, false);
  out.jacobian.block<3, 3>(21, 21) = windowFromStateRotation(window_rotation, state);
  out.window_jacobian.block<3, 3>(21, 18) = -translationAtRotationJacobian(window_rotation, state, true);
  return out;
}

}  // namespace

const std::vector<std::string>& turnAndZoomGroups() {
  static const std::vector<std::string> names = {groups()[0].name, groups()[3].name, groups()[6].name};
  return names;
}

double chiSquareQuantile(double upper_tail, int dof) {
  if (!(upper_tail > 0.0 && upper_tail < 1.0) || dof < 1)
    throw std::invalid_argument("chiSquareQuantile: upper_tail in (0, 1) and dof >= 1");
  // Bisection: the survival function falls monotonically.
  double low = 0.0, high = 1.0;
  while (chiSquareSurvival(high, dof) > upper_tail) high *= 2.0;
  for (int i = 0; i < 100; ++i) {
    const double mid = 0.5 * (low + high);
    (chiSquareSurvival(mid, dof) > upper_tail ? low : high) = mid;
  }
  return 0.5 * (low + high);
}

const std::vector<std::string>& calibrationGroupNames() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> n;
    for (const Group& g : groups()) n.push_back(g.name);
    return n;
  }();
  return names;
}

std::string CalibrationFilterOptions::validate() const {
  if (!(change_probability > 0.0 && change_probability < 0.5)) return "change_probability must be in (0, 0.5)";
  if (!(covariance_scale >= 1.0)) return "covariance_scale must be >= 1";
  for (double walk : {focal_walk_rel, principal_point_walk_px, distortion_walk, rotation_walk_deg, translation_walk_m})
    if (!(walk >= 0.0 && std::isfinite(walk))) return "the walks must be finite and >= 0";
  return "";
}

CalibrationFilter::CalibrationFilter(CalibrationFilterOptions options) : options_(options) {
  const std::string problem = options_.validate();
  if (!problem.empty()) throw std::invalid_argument("calibration filter: " + problem);
}

void CalibrationFilter::setState(const StereoRig& rig, const RigCovariance& covariance, double time_s) {
  state_ = State{rig, covariance, time_s};
}

std::optional<RigPrior> CalibrationFilter::priorFor(const BundleAdjustmentSummary& window, double time_s,
                                                    std::vector<std::string>* changed,
                                                    const std::vector<std::string>& known_changed) const {
  if (changed) changed->clear();
  if (!state_ || !window.success || !window.covariance_ok) return std::nullopt;
  const RigParameters measured = rigParameters(window.rig);
  const Carried carried = carriedToWindowRotation(rigParameters(state_->rig), measured.segment<3>(18));
  const RigParameters& state = carried.state;
  // The window's covariance as its translation is compared with the carried state's.
  const RigCovariance window_covariance =
      carried.window_jacobian * window.rig_covariance * carried.window_jacobian.transpose();
  // The state's, carried, and the walk's variance over the time since the state.
  const double dt = std::max(0.0, time_s - state_->time_s);
  const RigCovariance prior_covariance =
      carried.jacobian * (options_.covariance_scale * state_->covariance) * carried.jacobian.transpose() +
      RigCovariance(walkVariance(state_->rig, options_).asDiagonal()) * dt;

  RigPrior prior;
  prior.mean = state;
  prior.covariance = prior_covariance;
  for (const Group& g : groups()) {
    if (std::find(known_changed.begin(), known_changed.end(), g.name) != known_changed.end()) {
      if (changed) changed->push_back(g.name);
      continue;
    }
    // The group's parameters both solves estimated (a held term has no variance).
    std::vector<int> index;
    for (int i : g.index)
      if (window.rig_covariance(i, i) > 0.0 && state_->covariance(i, i) > 0.0) index.push_back(i);
    if (index.empty()) continue;
    const int n = static_cast<int>(index.size());
    Eigen::VectorXd delta(n);
    Eigen::MatrixXd C(n, n);
    for (int a = 0; a < n; ++a) {
      delta[a] = measured[index[a]] - state[index[a]];
      for (int b = 0; b < n; ++b)
        C(a, b) = options_.covariance_scale * window_covariance(index[a], index[b]) +
                  prior_covariance(index[a], index[b]);
    }
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(C);
    const double d2 = delta.dot(ldlt.solve(delta));
    const double limit = chiSquareQuantile(options_.change_probability, n);
    if (!(ldlt.info() == Eigen::Success && std::isfinite(d2) && d2 <= limit)) {
      if (changed) changed->push_back(g.name);
      continue;
    }
    for (int i : index) prior.active[i] = true;
  }
  if (prior.activeCount() == 0) return std::nullopt;
  return prior;
}

}  // namespace embedded_calibration_stereo::core
