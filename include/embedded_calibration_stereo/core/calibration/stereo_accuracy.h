#pragma once
// Accuracy of a stereo calibration in the terms a depth user feels: how far apart the two
// rectified images put a true correspondence vertically, how wrong its disparity is, and how
// wrong the depth computed from it is - for an estimated calibration against a reference (the
// truth of the simulator, or another calibration), and predicted from the covariance of a
// solve (bundle_adjuster.h: BundleAdjustmentSummary::rig_covariance).
//
// Definitions (docs/core.md, "Stereo accuracy"). Samples: a grid of raw pixels p over the
// REFERENCE left image, each at every depth Z of the options (metres along the reference left
// optical axis; infinity allowed): X = Z * (x, y, 1), (x, y) the reference left camera's
// normalised ray of p. The true correspondence is where the reference rig sees X: p in the
// left image, p_r = reference right camera's projection of X in the right one. Samples whose
// p_r falls outside the right image (or behind it) are skipped. Both raw pixels are then
// rectified with the ESTIMATED calibration as the product rectifies (its own
// computeRectificationGeometry, the given method and alpha): (uL, vL), (uR, vR). Per sample:
//   vertical misalignment  m = vL - vR                                      (px)
//   user's depth           Z_user = depth of (uL, vL, d = uL - uR) by the estimate's Q
//                          (Bouguet: f' B' / d), in the estimate's rectified left frame
//   true depth             Z_true = z of X in that same frame (R1_est X): the depth the user's
//                          depth image should have shown for this point
//   disparity bias         b = d - d_true, d_true the disparity the estimate's Q turns into
//                          Z_true (f' B' / Z_true; 0 at infinity)                  (px)
//   depth error            e = 100 (Z_user / Z_true - 1)                            (%)
// So the depth error is exactly the relative error of the depth the user reads for a true
// correspondence, and the bias is the disparity error that causes it (e ~ -100 b / d_true):
// a wrong baseline or focal length shows as a bias proportional to the disparity, a rotation
// about the vertical axis as a constant one. A matcher that finds the true correspondence
// despite the misalignment is assumed (the misalignment is reported on its own).
// Figures: RMS and max |.| over the samples, overall (misalignment and bias over every depth)
// and per depth; depth error per finite depth only.
//
// Prediction: the figures the true errors have in expectation when the estimate's error is
// distributed as its covariance says. The per-sample residuals (m, b, e) are linear in the
// rig's parameter error for errors of this size, so their Jacobian J_s with respect to the
// reference's parameters (central differences, one step of one standard deviation per
// parameter, the reference starting at the estimate and the samples held; the rectification of
// the right pixel, which such a step moves by a fraction of a pixel, linearised) gives each
// sample's variance J_s C J_s^T, and the expected RMS is sqrt(mean over samples of those).
// Deterministic and cheap (one rectification, 2 projections per sample and estimated
// parameter), unlike Monte Carlo sampling, which needs hundreds of rectifications for a few per
// cent and depends on a seed.
//
// Threading: free functions without shared state; safe from any thread.
#include <Eigen/Core>
#include <limits>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

struct StereoAccuracyOptions {
  // The product's rectification (the calibrator's: Bouguet, its rectification_alpha).
  RectificationOptions rectification;
  // Sample grid over the reference left image (cell centres).
  int grid_cols = 16, grid_rows = 10;
  // Depths of the samples in metres; infinity is allowed (no depth error there).
  std::vector<double> depths_m{1.0, 2.0, 5.0, 10.0, std::numeric_limits<double>::infinity()};
};

// Measured: rms and max |.| over the samples. Predicted: rms is the expected RMS, max the
// standard deviation of the worst sample.
struct AccuracyFigure {
  double rms = 0.0, max = 0.0;
};

struct DepthAccuracy {
  double depth_m = 0.0;
  int samples = 0;
  AccuracyFigure misalignment_px, disparity_bias_px;
  AccuracyFigure depth_error_pct;  // NaN at an infinite depth
};

struct StereoAccuracy {
  int samples = 0;  // all depths
  AccuracyFigure misalignment_px, disparity_bias_px;
  std::vector<DepthAccuracy> at_depth;  // in the order of options.depths_m
};

// The true figures of `estimate` against `reference` (the definitions above). Throws
// std::invalid_argument when either rig is invalid, the two differ in image size, or the
// estimate cannot be rectified (computeRectificationGeometry), or the options are unusable.
StereoAccuracy evaluateStereoAccuracy(const StereoRig& estimate, const StereoRig& reference,
                                      const StereoAccuracyOptions& options = {});

// The predicted figures of `estimate` whose parameter error has `covariance` (rigParameters()
// order; parameters of zero variance are held). Samples as evaluateStereoAccuracy() with the
// estimate as its own reference. Throws as evaluateStereoAccuracy(), and for a covariance
// with a negative or non-finite diagonal.
StereoAccuracy predictStereoAccuracy(const StereoRig& estimate, const RigCovariance& covariance,
                                     const StereoAccuracyOptions& options = {});

}  // namespace embedded_calibration_stereo::core
