#pragma once
// Decides whether a new calibration replaces the one in force. A candidate is accepted only
// when it converged, fits its observations (RMS, epipolar RMS, outliers), is well determined
// (standard deviations), saw enough boards in both cameras, and explains the observations
// better than the calibration in force - or the calibration in force no longer fits them - and,
// when asked (min_change_in_predicted), differs from the calibration in force by more than its
// own predicted error, in the terms a depth user feels (stereo_accuracy.h). Otherwise it is
// rejected with a human-readable reason and nothing changes.
//
// Threading: immutable after construction; evaluate() is a pure function.
#include <optional>
#include <string>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"

namespace embedded_calibration_stereo::core {

struct GateOptions {
  double max_rms_px = 1.0;  // per camera, RMS of the corner reprojection error norm
  double max_epipolar_rms_px = 1.0;
  double max_outlier_fraction = 0.02;  // corners with error above the adjuster's threshold
  int min_boards_per_camera = 4;       // distinct virtual boards with corners, in each camera
  // Standard deviation limits. Defaults: what 10 frames of a six-board device like the sim's
  // reach at 0.2 px corner noise with FREE board poses, with margin; one frame does not pass.
  // Kept for the rigid device model (the default when the device is given), whose standard
  // deviations are lower (one frame passes or fails on the rotation limit): the limits must
  // also accept the free-pose solves of a head configured without its device model, and a
  // 1-frame device solve is as well determined as a 10-frame free-pose one. (bench_calibrator
  // prints the standard deviations; docs/figures.md.)
  double max_focal_stddev_rel = 0.01;          // stddev(fx)/fx and stddev(fy)/fy
  double max_principal_point_stddev_px = 5.0;  // cx, cy
  double max_distortion_stddev = 0.02;         // each estimated distortion term
  double max_baseline_stddev_rel = 0.01;       // stddev(baseline)/baseline
  double max_rotation_stddev_deg = 0.1;
  // The candidate must lower the RMS of the calibration in force (refit on the same
  // observations, board poses only) by this fraction ...
  double min_rms_improvement_rel = 0.05;
  // ... unless the calibration in force no longer fits them at all.
  double in_force_max_rms_px = 1.0;
  // The change from the calibration in force, hypot(vertical misalignment RMS, disparity bias
  // RMS) of one rectified with the other over the field of view (stereo_accuracy.h), must exceed
  // this many times the same figure predicted from the candidate's covariance; 0 = not checked.
  // A change within the candidate's own uncertainty is no evidence against the calibration in
  // force: committing it would trade a calibration for one no better known. On a moving scene
  // the tracker's corners share errors a slightly wrong calibration fits better than the true
  // one, so a better RMS alone can be a worse calibration.
  double min_change_in_predicted = 0.0;
  // A candidate kept out only because it confirms the calibration in force (fits no better, or
  // changes too little) replaces it when its predicted accuracy for depth, hypot(misalignment,
  // disparity bias) RMS predicted from its covariance, is below this times the calibration in
  // force's (evaluate()'s in_force_predicted_px): as well fitted and better known, e.g. solved with
  // what the windows since the calibration in force taught (calibration_filter.h). 0: never.
  double refine_ratio = 0.0;
  // A candidate whose corners fit no better than the calibration in force's (and not clearly
  // worse) replaces it when the window's scene matches say the calibration in force is wrong: the
  // likelihood ratio of scene_comparison.h above the chi-square quantile of this upper tail (with
  // kSceneComparisonDof). The boards cannot tell a small turn of a camera from a small shift; the
  // scene can. 0: the scene is not consulted.
  double scene_test_probability = 0.0;

  std::string validate() const;  // empty when usable
};

// What the gate decided, as a value to branch on (the reason is for people only).
enum class GateOutcome {
  kRejected,           // the candidate does not replace the calibration in force
  kAccepted,           // it replaces the calibration in force (or is the first calibration)
  kRefinement,         // accepted as a refinement of the calibration in force (GateOptions::refine_ratio)
  kInForceConfirmed,   // rejected only because it fits no better (and not clearly worse) than the
                       // calibration in force: these observations confirm the calibration in force
  kChangeTooSmall,     // rejected because the change from the calibration in force lies within the
                       // new solve's own uncertainty (GateOptions::min_change_in_predicted): also
                       // a confirmation of the calibration in force
};

struct GateDecision {
  // The flags are set by setOutcome(), from `outcome` (they stay first, for the brace-initialised
  // decisions of callers): accepted for kAccepted and kRefinement, in_force_confirmed for
  // kInForceConfirmed and kChangeTooSmall, change_too_small and refinement for their own value.
  bool accepted = false;
  std::string reason;  // why, in words, for CalibrationStatus.reason: "accepted: " or "rejected: " + detail
  std::string detail;  // the reason without its verdict
  bool change_too_small = false;
  bool in_force_confirmed = false;
  bool refinement = false;
  // The candidate's predicted hypot(misalignment, disparity bias) RMS (px) when the gate computed
  // it (min_change_in_predicted, refine_ratio), 0 otherwise.
  double predicted_px = 0.0;
  GateOutcome outcome = GateOutcome::kRejected;

  // Sets `outcome` and the flags derived from it.
  void setOutcome(GateOutcome value);
};

class QualityGate {
 public:
  explicit QualityGate(GateOptions options) : options_(options) {}
  // `in_force_fit`: evaluateFixedCalibration() of the calibration in force on the same
  // observations as the candidate; nullptr when no calibration is in force yet.
  // `in_force_predicted_px`: the calibration in force's own predicted hypot(misalignment,
  // disparity bias) RMS (the decision's predicted_px when it was accepted), for refine_ratio.
  GateDecision evaluate(const BundleAdjustmentSummary& candidate, const BundleAdjustmentSummary* in_force_fit,
                        std::optional<double> in_force_predicted_px = std::nullopt) const;
  // The candidate's predicted hypot(misalignment, disparity bias) RMS (px); 0 without covariance.
  static double predictedPx(const BundleAdjustmentSummary& candidate);
  const GateOptions& options() const { return options_; }

 private:
  GateOptions options_;
};

// RMS over both cameras (corner-count weighted).
double combinedRms(const BundleAdjustmentSummary& s);

}  // namespace embedded_calibration_stereo::core
