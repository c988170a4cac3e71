#include "embedded_calibration_stereo/core/calibration/quality_gate.h"

#include <cmath>
#include <iomanip>
#include <optional>
#include <sstream>

#include "embedded_calibration_stereo/core/calibration/calibration_filter.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"

namespace embedded_calibration_stereo::core {

namespace {

std::string fmt(double value, int precision = 3) {
  std::ostringstream s;
  s << std::setprecision(precision) << value;
  return s.str();
}

// First stddev over its limit, as "left fx stddev 1.2 px > 0.9 px"; empty when all pass.
std::string cameraStddevProblem(const char* side, const PinholeCamera& c, const CameraStddev& sd,
                                const GateOptions& o) {
  const std::string name = side;
  if (!(sd.fx <= o.max_focal_stddev_rel * c.fx))
    return name + " fx stddev " + fmt(sd.fx) + " px > " + fmt(o.max_focal_stddev_rel * c.fx) +
           " px";
  if (!(sd.fy <= o.max_focal_stddev_rel * c.fy))
    return name + " fy stddev " + fmt(sd.fy) + " px > " + fmt(o.max_focal_stddev_rel * c.fy) +
           " px";
  if (!(sd.cx <= o.max_principal_point_stddev_px) || !(sd.cy <= o.max_principal_point_stddev_px))
    return name + " principal point stddev (" + fmt(sd.cx) + ", " + fmt(sd.cy) + ") px > " +
           fmt(o.max_principal_point_stddev_px) + " px";
  static const char* const kNames[5] = {"k1", "k2", "p1", "p2", "k3"};
  for (int i = 0; i < 5; ++i)
    if (!(sd.dist[i] <= o.max_distortion_stddev))
      return name + " " + kNames[i] + " stddev " + fmt(sd.dist[i]) + " > " +
             fmt(o.max_distortion_stddev);
  return "";
}

}  // namespace

std::string GateOptions::validate() const {
  if (!(max_rms_px > 0) || !(max_epipolar_rms_px > 0)) return "RMS limits must be > 0";
  if (!(max_outlier_fraction >= 0 && max_outlier_fraction <= 1))
    return "max_outlier_fraction must be in [0, 1]";
  if (min_boards_per_camera < 1) return "min_boards_per_camera must be >= 1";
  if (!(max_focal_stddev_rel > 0) || !(max_principal_point_stddev_px > 0) ||
      !(max_distortion_stddev > 0) || !(max_baseline_stddev_rel > 0) ||
      !(max_rotation_stddev_deg > 0))
    return "standard deviation limits must be > 0";
  if (!(min_rms_improvement_rel >= 0)) return "min_rms_improvement_rel must be >= 0";
  if (!(in_force_max_rms_px > 0)) return "in_force_max_rms_px must be > 0";
  if (!(min_change_in_predicted >= 0)) return "min_change_in_predicted must be >= 0";
  if (!(refine_ratio >= 0 && refine_ratio < 1)) return "refine_ratio must be in [0, 1)";
  if (!(scene_test_probability >= 0 && scene_test_probability < 1)) return "scene_test_probability must be in [0, 1)";
  return "";
}

void GateDecision::setOutcome(GateOutcome value) {
  outcome = value;
  accepted = value == GateOutcome::kAccepted || value == GateOutcome::kRefinement;
  refinement = value == GateOutcome::kRefinement;
  change_too_small = value == GateOutcome::kChangeTooSmall;
  in_force_confirmed = value == GateOutcome::kInForceConfirmed || value == GateOutcome::kChangeTooSmall;
}

double combinedRms(const BundleAdjustmentSummary& s) {
  const int n = s.corners_left + s.corners_right;
  if (n == 0) return 0.0;
  return std::sqrt((s.rms_left_px * s.rms_left_px * s.corners_left +
                    s.rms_right_px * s.rms_right_px * s.corners_right) /
                   n);
}

double QualityGate::predictedPx(const BundleAdjustmentSummary& c) {
  if (!c.success || !c.covariance_ok) return 0.0;
  try {
    const StereoAccuracy p = predictStereoAccuracy(c.rig, c.rig_covariance);
    return std::hypot(p.misalignment_px.rms, p.disparity_bias_px.rms);
  } catch (const std::exception&) {
    return 0.0;
  }
}

namespace {

GateDecision verdict(GateOutcome outcome, const std::string& why) {
  GateDecision d;
  d.setOutcome(outcome);
  d.reason = (d.accepted ? "accepted: " : "rejected: ") + why;
  d.detail = why;
  return d;
}

GateDecision rejected(const std::string& why) { return verdict(GateOutcome::kRejected, why); }
GateDecision accepted(const std::string& why) { return verdict(GateOutcome::kAccepted, why); }

// Why the candidate cannot be accepted whatever is in force (its solve, its fit, how well its
// parameters are known); empty when it passes.
std::string candidateProblem(const BundleAdjustmentSummary& c, const GateOptions& o) {
  if (!c.success) return "no solution (" + c.message + ")";
  if (c.boards_left < o.min_boards_per_camera || c.boards_right < o.min_boards_per_camera)
    return "boards seen: " + std::to_string(c.boards_left) + " left, " + std::to_string(c.boards_right) +
           " right; at least " + std::to_string(o.min_boards_per_camera) + " needed in each camera";
  if (!c.converged) return "solver did not converge (" + c.message + ")";
  if (!(c.rms_left_px <= o.max_rms_px) || !(c.rms_right_px <= o.max_rms_px))
    return "RMS " + fmt(c.rms_left_px) + " / " + fmt(c.rms_right_px) + " px > " + fmt(o.max_rms_px) + " px";
  if (!(c.epipolar_rms_px <= o.max_epipolar_rms_px))
    return "epipolar RMS " + fmt(c.epipolar_rms_px) + " px > " + fmt(o.max_epipolar_rms_px) + " px";
  if (c.corners_used == 0 || c.outliers > o.max_outlier_fraction * static_cast<double>(c.corners_used))
    return std::to_string(c.outliers) + " outlier corners of " + std::to_string(c.corners_used) +
           " (max fraction " + fmt(o.max_outlier_fraction) + ")";
  return "";
}

// The candidate's standard deviations over their limits; empty when all pass.
std::string uncertaintyProblem(const BundleAdjustmentSummary& c, const GateOptions& o) {
  if (!c.covariance_ok) return "covariance unavailable (parameters not determined)";
  std::string stddev = cameraStddevProblem("left", c.rig.left, c.left_stddev, o);
  if (stddev.empty()) stddev = cameraStddevProblem("right", c.rig.right, c.right_stddev, o);
  if (!stddev.empty()) return stddev;
  if (!(c.baseline_stddev_m <= o.max_baseline_stddev_rel * c.rig.baseline()))
    return "baseline stddev " + fmt(c.baseline_stddev_m * 1000) + " mm > " +
           fmt(o.max_baseline_stddev_rel * c.rig.baseline() * 1000) + " mm";
  if (!(c.rotation_stddev_deg <= o.max_rotation_stddev_deg))
    return "rotation stddev " + fmt(c.rotation_stddev_deg) + " deg > " + fmt(o.max_rotation_stddev_deg) + " deg";
  return "";
}

// A candidate that only confirms the calibration in force replaces it when clearly better
// known (refine_ratio); otherwise `kept` stands.
GateDecision refineOr(GateDecision kept, const BundleAdjustmentSummary& c, const GateOptions& o,
                      std::optional<double> in_force_predicted_px) {
  if (!kept.in_force_confirmed || !(o.refine_ratio > 0) || !in_force_predicted_px || !(*in_force_predicted_px > 0))
    return kept;
  const double p = QualityGate::predictedPx(c);
  if (!(p > 0 && p < o.refine_ratio * *in_force_predicted_px)) return kept;
  GateDecision refined = verdict(GateOutcome::kRefinement, "refinement of the calibration in force, predicted error " +
                                                                fmt(p) + " px against " + fmt(*in_force_predicted_px) +
                                                                " px");
  refined.predicted_px = p;
  return refined;
}

// The significance of the change, when asked.
struct Significance {
  std::string rejection;  // "" when significant (or not asked)
  bool within_uncertainty = false;  // the change lies within the new solve's uncertainty (not an
                                    // evaluation that failed)
  std::string note;  // describes the change for the acceptance
};

Significance significance(const BundleAdjustmentSummary& c, const BundleAdjustmentSummary& in_force,
                          const GateOptions& o) {
  Significance s;
  if (!(o.min_change_in_predicted > 0)) return s;
  try {
    const StereoAccuracy change = evaluateStereoAccuracy(in_force.rig, c.rig);
    const StereoAccuracy predicted = predictStereoAccuracy(c.rig, c.rig_covariance);
    const double d = std::hypot(change.misalignment_px.rms, change.disparity_bias_px.rms);
    const double p = std::hypot(predicted.misalignment_px.rms, predicted.disparity_bias_px.rms);
    s.note = "; change for depth " + fmt(d) + " px, predicted error " + fmt(p) + " px";
    if (d > o.min_change_in_predicted * p) return s;
    s.within_uncertainty = true;
    s.rejection = "change from the calibration in force within the new solve's uncertainty: " + fmt(d) +
                  " px (misalignment and disparity bias) vs " + fmt(o.min_change_in_predicted) + " x " + fmt(p) +
                  " px predicted";
  } catch (const std::exception& e) {
    s.rejection = std::string("accuracy for depth not evaluated: ") + e.what();
  }
  return s;
}

// The scene's verdict on a candidate the corners do not prefer (scene_test_probability): an
// acceptance when its matches fit the candidate significantly better, nothing otherwise.
std::optional<GateDecision> sceneVerdict(const BundleAdjustmentSummary& c, const BundleAdjustmentSummary& in_force,
                                         const GateOptions& o) {
  const SceneComparison& scene = c.scene_vs_in_force;
  if (!(o.scene_test_probability > 0) || scene.matches == 0) return std::nullopt;
  const double limit = chiSquareQuantile(o.scene_test_probability, kSceneComparisonDof);
  if (!(scene.statistic > limit)) return std::nullopt;
  const Significance s = significance(c, in_force, o);
  if (!s.rejection.empty()) return std::nullopt;
  return accepted("the scene fits it better: " + std::to_string(scene.matches) + " scene matches at RMS " +
                  fmt(scene.candidate_rms_px) + " px vs " + fmt(scene.in_force_rms_px) +
                  " px for the calibration in force (test " + fmt(scene.statistic) + " > " + fmt(limit) +
                  "); corner RMS " + fmt(combinedRms(c)) + " px vs " + fmt(combinedRms(in_force)) + " px" + s.note);
}

// The decision for a candidate that passed on its own, against the calibration in force's fit of
// the same observations.
GateDecision againstInForce(const BundleAdjustmentSummary& c, const BundleAdjustmentSummary& in_force,
                            const GateOptions& o, std::optional<double> in_force_predicted_px) {
  const double candidate_rms = combinedRms(c);
  const double in_force_rms = combinedRms(in_force);
  if (in_force_rms > o.in_force_max_rms_px) {
    const Significance s = significance(c, in_force, o);
    if (!s.rejection.empty()) return rejected(s.rejection);
    return accepted("calibration in force no longer fits (RMS " + fmt(in_force_rms) + " px > " +
                  fmt(o.in_force_max_rms_px) + " px), new RMS " + fmt(candidate_rms) + " px" + s.note);
  }
  if (candidate_rms * (1.0 + o.min_rms_improvement_rel) <= in_force_rms) {
    const Significance s = significance(c, in_force, o);
    if (!s.rejection.empty()) {
      // The observations do not tell the two apart: the calibration in force stands.
      const GateDecision kept =
          verdict(s.within_uncertainty ? GateOutcome::kChangeTooSmall : GateOutcome::kRejected, s.rejection);
      return refineOr(kept, c, o, in_force_predicted_px);
    }
    return accepted("RMS " + fmt(candidate_rms) + " px vs " + fmt(in_force_rms) + " px for the calibration in force" +
                  s.note);
  }
  // A fresh solve clearly worse than the calibration in force confirms nothing: something failed.
  const bool confirms = candidate_rms <= in_force_rms * (1.0 + o.min_rms_improvement_rel);
  if (confirms)
    if (std::optional<GateDecision> by_scene = sceneVerdict(c, in_force, o)) return *by_scene;
  const GateDecision kept = verdict(confirms ? GateOutcome::kInForceConfirmed : GateOutcome::kRejected,
                                    "no significant improvement: RMS " + fmt(candidate_rms) + " px vs " +
                                        fmt(in_force_rms) + " px for the calibration in force (needs " +
                                        fmt(100 * o.min_rms_improvement_rel) + "% lower)");
  return refineOr(kept, c, o, in_force_predicted_px);
}

}  // namespace

GateDecision QualityGate::evaluate(const BundleAdjustmentSummary& c, const BundleAdjustmentSummary* in_force_fit,
                                   std::optional<double> in_force_predicted_px) const {
  const GateOptions& o = options_;
  const std::string options_problem = o.validate();
  if (!options_problem.empty()) return rejected("invalid gate options: " + options_problem);
  std::string problem = candidateProblem(c, o);
  if (problem.empty()) problem = uncertaintyProblem(c, o);
  if (!problem.empty()) return rejected(problem);
  if (!in_force_fit) return accepted("first calibration, RMS " + fmt(combinedRms(c)) + " px");
  if (!in_force_fit->success)
    return accepted("calibration in force cannot explain the observations (" + in_force_fit->message + ")");
  return againstInForce(c, *in_force_fit, o, in_force_predicted_px);
}

}  // namespace embedded_calibration_stereo::core
