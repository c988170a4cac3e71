#include "embedded_calibration_stereo/core/calibration/scene_comparison.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/calibration/scene_epipolar_cost.h"

namespace embedded_calibration_stereo::core {

std::vector<double> sceneEpipolarResiduals(const std::vector<SceneMatch>& matches, const StereoRig& rig,
                                           double focal_px) {
  // rigParameters(): left intrinsics, right intrinsics, then the extrinsics, as the cost reads them.
  const RigParameters p = rigParameters(rig);
  const double unit = 1.0;
  std::vector<double> distances;
  distances.reserve(matches.size());
  for (const SceneMatch& m : matches) {
    double r = std::numeric_limits<double>::infinity();
    SceneEpipolarCost(m, focal_px, &unit)(p.data(), p.data() + 9, p.data() + 18, &r);
    distances.push_back(r);
  }
  return distances;
}

std::vector<double> sceneEpipolarDistances(const std::vector<SceneMatch>& matches, const StereoRig& rig,
                                           double focal_px) {
  std::vector<double> d = sceneEpipolarResiduals(matches, rig, focal_px);
  for (double& v : d) v = std::abs(v);
  return d;
}

SceneComparison compareOnScene(const std::vector<SceneMatch>& matches, const StereoRig& candidate,
                               const StereoRig& in_force, double sigma_px, double clip_sigmas) {
  if (!(sigma_px > 0) || !(clip_sigmas > 0)) throw std::invalid_argument("compareOnScene: sigma and clip must be > 0");
  SceneComparison c;
  if (matches.empty()) return c;
  // One focal length for both, so that the two sums are in the same pixels.
  const double focal = in_force.right.fy;
  const std::vector<double> a = sceneEpipolarDistances(matches, candidate, focal);
  const std::vector<double> b = sceneEpipolarDistances(matches, in_force, focal);
  const double clip = clip_sigmas * sigma_px;
  double sum_a = 0.0, sum_b = 0.0;
  for (size_t i = 0; i < matches.size(); ++i) {
    sum_a += std::pow(std::min(a[i], clip), 2);
    sum_b += std::pow(std::min(b[i], clip), 2);
  }
  c.matches = static_cast<int>(matches.size());
  c.candidate_rms_px = std::sqrt(sum_a / c.matches);
  c.in_force_rms_px = std::sqrt(sum_b / c.matches);
  // The likelihood ratio with the matches' variance unknown (estimated from each sum): heavy
  // tails, which the robust spread underrates, raise both sums alike.
  c.statistic = sum_a > 0.0 ? c.matches * std::log(sum_b / sum_a) : 0.0;
  return c;
}

}  // namespace embedded_calibration_stereo::core
