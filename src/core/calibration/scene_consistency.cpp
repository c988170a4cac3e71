#include "embedded_calibration_stereo/core/calibration/scene_consistency.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "embedded_calibration_stereo/core/calibration/scene_comparison.h"

namespace embedded_calibration_stereo::core {

std::string SceneConsistencyOptions::validate() const {
  if (!(max_change_px >= 0) || !(significance_sigmas >= 0)) return "max_change_px and significance_sigmas must be >= 0";
  if (min_matches < 7) return "min_matches must be >= 7 (six terms are fitted)";
  return "";
}

namespace {

constexpr int kTerms = 6;  // 1, x, y, x^2, x y, y^2
using Terms = Eigen::Matrix<double, kTerms, 1>;

// Image position scaled to [-0.5, 0.5] about the centre, so that the terms are alike in size.
Terms terms(double u, double v, const PinholeCamera& camera) {
  const double x = u / camera.width - 0.5, y = v / camera.height - 0.5;
  Terms t;
  t << 1.0, x, y, x * x, x * y, y * y;
  return t;
}

struct SurfaceFit {
  Terms coefficients = Terms::Zero();
  Eigen::Matrix<double, kTerms, kTerms> covariance = Eigen::Matrix<double, kTerms, kTerms>::Zero();
  bool ok = false;
};

// Least squares, then again without the residuals beyond 3 robust spreads (wrong matches), with
// the covariance at the kept residuals' variance.
SurfaceFit fitSurface(const std::vector<SceneMatch>& matches, const StereoRig& guide) {
  const std::vector<double> r = sceneEpipolarResiduals(matches, guide, guide.right.fy);
  std::vector<bool> keep(matches.size(), true);
  SurfaceFit fit;
  for (int pass = 0; pass < 2; ++pass) {
    Eigen::Matrix<double, kTerms, kTerms> normal = Eigen::Matrix<double, kTerms, kTerms>::Zero();
    Terms rhs = Terms::Zero();
    int n = 0;
    for (size_t i = 0; i < matches.size(); ++i) {
      if (!keep[i] || !std::isfinite(r[i])) continue;
      const Terms t = terms(matches[i].left_u, matches[i].left_v, guide.left);
      normal += t * t.transpose();
      rhs += t * r[i];
      ++n;
    }
    if (n <= kTerms) return fit;
    const Eigen::LDLT<Eigen::Matrix<double, kTerms, kTerms>> solver(normal);
    if (solver.info() != Eigen::Success) return fit;
    fit.coefficients = solver.solve(rhs);
    std::vector<double> residuals;
    for (size_t i = 0; i < matches.size(); ++i)
      if (keep[i] && std::isfinite(r[i]))
        residuals.push_back(r[i] - terms(matches[i].left_u, matches[i].left_v, guide.left).dot(fit.coefficients));
    double sum_sq = 0.0;
    for (double e : residuals) sum_sq += e * e;
    const double variance = sum_sq / (n - kTerms);
    fit.covariance = variance * solver.solve(Eigen::Matrix<double, kTerms, kTerms>::Identity());
    fit.ok = true;
    if (pass == 1) break;
    std::vector<double> magnitude;
    for (double e : residuals) magnitude.push_back(std::abs(e));
    std::nth_element(magnitude.begin(), magnitude.begin() + magnitude.size() / 2, magnitude.end());
    const double limit = 3.0 * 1.4826 * magnitude[magnitude.size() / 2];
    for (size_t i = 0; i < matches.size(); ++i)
      if (!std::isfinite(r[i]) ||
          std::abs(r[i] - terms(matches[i].left_u, matches[i].left_v, guide.left).dot(fit.coefficients)) > limit)
        keep[i] = false;
  }
  return fit;
}

}  // namespace

SceneConsistency compareSceneSides(const std::vector<SceneMatch>& before, const std::vector<SceneMatch>& after,
                                   const StereoRig& guide, const SceneConsistencyOptions& options) {
  if (const std::string problem = options.validate(); !problem.empty())
    throw std::invalid_argument("compareSceneSides: " + problem);
  SceneConsistency c;
  const int least = static_cast<int>(std::min(before.size(), after.size()));
  if (least < options.min_matches) return c;
  const SurfaceFit a = fitSurface(before, guide), b = fitSurface(after, guide);
  if (!a.ok || !b.ok) return c;
  c.compared = true;
  // The difference where the matches are (both sides'): a surface says nothing far from its data.
  const Terms delta = b.coefficients - a.coefficients;
  const Eigen::Matrix<double, kTerms, kTerms> covariance = a.covariance + b.covariance;
  double sum_sq = 0.0, sum_var = 0.0;
  int n = 0;
  for (const std::vector<SceneMatch>* side : {&before, &after})
    for (const SceneMatch& m : *side) {
      const Terms t = terms(m.left_u, m.left_v, guide.left);
      sum_sq += std::pow(t.dot(delta), 2);
      sum_var += t.dot(covariance * t);
      ++n;
    }
  c.change_px = std::sqrt(sum_sq / n);
  c.change_stddev_px = std::sqrt(sum_var / n);
  c.consistent = !(c.change_px > options.max_change_px && c.change_px > options.significance_sigmas * c.change_stddev_px);
  return c;
}

}  // namespace embedded_calibration_stereo::core
