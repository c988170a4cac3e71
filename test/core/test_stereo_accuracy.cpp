// Stereo accuracy in a depth user's terms (stereo_accuracy.h): vertical misalignment, disparity
// bias and depth error of true correspondences after rectifying with an estimated calibration.
// (a) Against an independent brute force written with OpenCV alone (cv::undistortPoints to a
//     tight tolerance, cv::projectPoints, cv::stereoRectify, cv::perspectiveTransform with Q)
//     for several perturbed rigs, and against the physics of simple errors (a rotation about
//     x is a misalignment of f' times the angle, a 1 % baseline error a 1 % depth error, a pan
//     a disparity bias of f' times the angle). (b) The prediction from a covariance against
//     Monte Carlo sampling of that covariance. (c) The calibrator's solve (device model, the
//     sim's head, 0.2 px corner noise) over 50 trials: the reported standard deviations cover
//     the true errors, and the predicted misalignment and bias are those the truth shows.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Core>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <random>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/test_support/solution_errors.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace embedded_calibration_stereo::core {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kDeg = M_PI / 180.0;

// The truth: the sim's head (tangential terms zeroed, as the calibrator's default model).
StereoRig simTruth() {
  cv::FileStorage fs = openYaml(ECS_SOURCE_DIR "/config/sim_rig.yaml");
  StereoRig truth = loadStereoRig(fs["rig"], "rig");
  for (PinholeCamera* c : {&truth.left, &truth.right}) c->dist[2] = c->dist[3] = 0.0;
  return truth;
}

// The right camera turned by `rotvec_rad` in its own optical frame.
StereoRig turnRight(StereoRig rig, const Eigen::Vector3d& rotvec_rad) {
  const Eigen::Isometry3d turn(Eigen::AngleAxisd(rotvec_rad.norm(), rotvec_rad.normalized()));
  rig.right_from_left = turn * rig.right_from_left;
  return rig;
}

// ---- The brute force: the definitions of stereo_accuracy.h written with OpenCV only. ----
struct Brute {
  // Per sample: depth index, misalignment, bias, depth error (%).
  std::vector<int> depth_index;
  std::vector<double> m, b, e;
  double f_rect = 0;  // f' of the estimate's rectification
};

cv::Matx33d K(const PinholeCamera& c) { return {c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1}; }
cv::Mat D(const PinholeCamera& c) { return cv::Mat(cv::Matx<double, 1, 5>(c.dist.data()), true); }
const cv::TermCriteria kTight(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-15);

cv::Point2d rectifyOne(const PinholeCamera& c, const cv::Mat& R, const cv::Mat& P, cv::Point2d raw) {
  std::vector<cv::Point2d> in{raw}, out;
  cv::undistortPoints(in, out, K(c), D(c), R, P, kTight);
  return out[0];
}

Brute bruteForce(const StereoRig& est, const StereoRig& ref, int cols, int rows,
                 const std::vector<double>& depths, double alpha = 0.0) {
  const cv::Size size(est.left.width, est.left.height);
  cv::Matx33d Re;
  cv::eigen2cv(Eigen::Matrix3d(est.right_from_left.linear()), Re);
  const Eigen::Vector3d te = est.right_from_left.translation();
  cv::Mat R1, R2, P1, P2, Q;
  cv::stereoRectify(K(est.left), D(est.left), K(est.right), D(est.right), size, Re, cv::Vec3d(te.x(), te.y(), te.z()),
                    R1, R2, P1, P2, Q, cv::CALIB_ZERO_DISPARITY, alpha, size);
  cv::Mat rvec_ref;
  cv::Matx33d Rr;
  cv::eigen2cv(Eigen::Matrix3d(ref.right_from_left.linear()), Rr);
  cv::Rodrigues(Rr, rvec_ref);
  const Eigen::Vector3d tr = ref.right_from_left.translation();
  Brute out;
  out.f_rect = P1.at<double>(0, 0);
  const double Tx = P2.at<double>(0, 3);  // -f' B'
  for (size_t d = 0; d < depths.size(); ++d)
    for (int j = 0; j < rows; ++j)
      for (int i = 0; i < cols; ++i) {
        const cv::Point2d pl((i + 0.5) * size.width / cols - 0.5, (j + 0.5) * size.height / rows - 0.5);
        std::vector<cv::Point2d> n;
        cv::undistortPoints(std::vector<cv::Point2d>{pl}, n, K(ref.left), D(ref.left), cv::noArray(), cv::noArray(),
                            kTight);
        const bool far = std::isinf(depths[d]);
        const double z = far ? 1.0 : depths[d];
        const cv::Point3d X(n[0].x * z, n[0].y * z, z);
        std::vector<cv::Point2d> pr;
        cv::projectPoints(std::vector<cv::Point3d>{X}, rvec_ref,
                          far ? cv::Vec3d(0, 0, 0) : cv::Vec3d(tr.x(), tr.y(), tr.z()), K(ref.right), D(ref.right), pr);
        if (pr[0].x < 0 || pr[0].y < 0 || pr[0].x > size.width - 1 || pr[0].y > size.height - 1) continue;
        const cv::Point2d l = rectifyOne(est.left, R1, P1, pl), r = rectifyOne(est.right, R2, P2, pr[0]);
        out.depth_index.push_back(static_cast<int>(d));
        out.m.push_back(l.y - r.y);
        const double disparity = l.x - r.x;
        if (far) {
          out.b.push_back(disparity);  // zero disparity at infinity (CALIB_ZERO_DISPARITY)
          out.e.push_back(0.0);
          continue;
        }
        const double true_depth = (cv::Matx33d(R1) * cv::Vec3d(X.x, X.y, X.z))[2];
        out.b.push_back(disparity - (-Tx / true_depth));  // textbook d = f' B' / Z
        std::vector<cv::Point3d> xyz;
        cv::perspectiveTransform(std::vector<cv::Point3d>{cv::Point3d(l.x, l.y, disparity)}, xyz, Q);
        out.e.push_back(100.0 * (xyz[0].z / true_depth - 1.0));
      }
  return out;
}

// RMS and max |.| of `v` over the samples at depth `d` (-1: all).
AccuracyFigure figureOf(const Brute& b, const std::vector<double>& v, int d) {
  double sum = 0, max = 0;
  int n = 0;
  for (size_t i = 0; i < v.size(); ++i)
    if (d < 0 || b.depth_index[i] == d) {
      sum += v[i] * v[i];
      max = std::max(max, std::abs(v[i]));
      ++n;
    }
  return {n ? std::sqrt(sum / n) : 0.0, max};
}

void expectFigure(const AccuracyFigure& got, const AccuracyFigure& want, double tol, const std::string& what) {
  EXPECT_NEAR(got.rms, want.rms, tol) << what << " rms";
  EXPECT_NEAR(got.max, want.max, tol) << what << " max";
}

void expectMatchesBruteForce(const StereoRig& est, const StereoRig& ref, const std::string& what) {
  SCOPED_TRACE(what);
  StereoAccuracyOptions o;
  const StereoAccuracy a = evaluateStereoAccuracy(est, ref, o);
  const Brute b = bruteForce(est, ref, o.grid_cols, o.grid_rows, o.depths_m);
  ASSERT_EQ(a.samples, static_cast<int>(b.m.size()));
  ASSERT_GT(a.samples, 600);  // most of the 16 x 10 x 5 samples are seen by both cameras
  expectFigure(a.misalignment_px, figureOf(b, b.m, -1), 1e-7, "misalignment");
  expectFigure(a.disparity_bias_px, figureOf(b, b.b, -1), 1e-7, "bias");
  ASSERT_EQ(a.at_depth.size(), o.depths_m.size());
  for (size_t d = 0; d < o.depths_m.size(); ++d) {
    const DepthAccuracy& at = a.at_depth[d];
    const std::string depth = " at " + std::to_string(o.depths_m[d]) + " m";
    EXPECT_EQ(at.depth_m, o.depths_m[d]);
    EXPECT_EQ(at.samples, std::count(b.depth_index.begin(), b.depth_index.end(), static_cast<int>(d)));
    expectFigure(at.misalignment_px, figureOf(b, b.m, d), 1e-7, "misalignment" + depth);
    expectFigure(at.disparity_bias_px, figureOf(b, b.b, d), 1e-7, "bias" + depth);
    if (std::isinf(o.depths_m[d]))
      EXPECT_TRUE(std::isnan(at.depth_error_pct.rms));
    else
      expectFigure(at.depth_error_pct, figureOf(b, b.e, d), 1e-7, "depth error" + depth);
  }
}

TEST(StereoAccuracy, MatchesAnOpenCvBruteForceForPerturbedRigs) {
  const StereoRig truth = simTruth();
  expectMatchesBruteForce(turnRight(truth, {0.05 * kDeg, 0, 0}), truth, "0.05 deg about x");
  expectMatchesBruteForce(turnRight(truth, {0, 0.05 * kDeg, 0}), truth, "0.05 deg about y");
  StereoRig longer = truth;
  longer.right_from_left.translation() *= 1.01;
  expectMatchesBruteForce(longer, truth, "baseline +1 %");
  StereoRig mixed = turnRight(truth, Eigen::Vector3d(0.02, -0.03, 0.04) * kDeg);
  mixed.left.fx *= 1.002;
  mixed.right.fy *= 0.998;
  mixed.left.cx += 0.5;
  mixed.right.cy -= 0.4;
  mixed.left.dist[0] += 0.002;
  mixed.right.dist[1] -= 0.003;
  mixed.right_from_left.translation() += Eigen::Vector3d(0.0003, -0.0002, 0.0005);
  expectMatchesBruteForce(mixed, truth, "mixed");
  // The reference may be any calibration, the truth the estimate.
  expectMatchesBruteForce(truth, mixed, "mixed as the reference");
}

TEST(StereoAccuracy, IdenticalRigsHaveNoError) {
  const StereoRig truth = simTruth();
  const StereoAccuracy a = evaluateStereoAccuracy(truth, truth);
  EXPECT_GT(a.samples, 600);
  // Zero up to the raw pixels' round trip through the distortion (Newton, 1e-12).
  EXPECT_LT(a.misalignment_px.max, 1e-9);
  EXPECT_LT(a.disparity_bias_px.max, 1e-9);
  for (const DepthAccuracy& d : a.at_depth)
    if (!std::isinf(d.depth_m)) {
      EXPECT_LT(d.depth_error_pct.max, 1e-9);
    }
}

// One sample at the image centre, every depth.
StereoAccuracy atCentre(const StereoRig& est, const StereoRig& truth) {
  StereoAccuracyOptions o;
  o.grid_cols = o.grid_rows = 1;
  return evaluateStereoAccuracy(est, truth, o);
}

double rectifiedFocal(const StereoRig& rig) {
  cv::Matx33d R;
  cv::eigen2cv(Eigen::Matrix3d(rig.right_from_left.linear()), R);
  const Eigen::Vector3d t = rig.right_from_left.translation();
  cv::Mat R1, R2, P1, P2, Q;
  const cv::Size size(rig.left.width, rig.left.height);
  cv::stereoRectify(K(rig.left), D(rig.left), K(rig.right), D(rig.right), size, R, cv::Vec3d(t.x(), t.y(), t.z()), R1,
                    R2, P1, P2, Q, cv::CALIB_ZERO_DISPARITY, 0.0, size);
  return P1.at<double>(0, 0);
}

TEST(StereoAccuracy, RotationAboutXIsAVerticalMisalignmentOfFocalTimesAngle) {
  const StereoRig truth = simTruth();
  const double angle = 0.05 * kDeg;
  const StereoRig est = turnRight(truth, {angle, 0, 0});
  const double expected = rectifiedFocal(est) * angle;  // ~0.57 px
  const StereoAccuracy c = atCentre(est, truth);
  for (const DepthAccuracy& d : c.at_depth) {  // a rotation: the same at every depth
    EXPECT_NEAR(d.misalignment_px.rms, expected, 0.03 * expected) << d.depth_m << " m";
    EXPECT_LT(d.disparity_bias_px.rms, 0.05 * expected) << d.depth_m << " m";
  }
  // Over the field of view the misalignment grows towards the edges, never below the centre's.
  const StereoAccuracy a = evaluateStereoAccuracy(est, truth);
  EXPECT_GE(a.misalignment_px.rms, 0.97 * expected);
  EXPECT_LT(a.misalignment_px.rms, 1.3 * expected);
}

TEST(StereoAccuracy, OnePercentLongerBaselineIsOnePercentMoreDepth) {
  const StereoRig truth = simTruth();
  StereoRig est = truth;
  est.right_from_left.translation() *= 1.01;
  const StereoAccuracy a = evaluateStereoAccuracy(est, truth);
  EXPECT_LT(a.misalignment_px.max, 1e-6);  // same directions: the same rectified rows
  for (const DepthAccuracy& d : a.at_depth) {
    SCOPED_TRACE(std::to_string(d.depth_m) + " m");
    if (std::isinf(d.depth_m)) {
      EXPECT_LT(d.disparity_bias_px.max, 1e-6);  // no parallax at infinity
      continue;
    }
    EXPECT_NEAR(d.depth_error_pct.rms, 1.0, 1e-6);  // Z_user = f' 1.01 B / d exactly
    EXPECT_NEAR(d.depth_error_pct.max, 1.0, 1e-6);
    // Bias -1/1.01 of the true disparity f' B / Z.
    const double disparity = rectifiedFocal(est) * truth.baseline() / d.depth_m;
    EXPECT_NEAR(d.disparity_bias_px.rms, disparity * (1.0 - 1.0 / 1.01), 0.03 * disparity * 0.01);
  }
}

TEST(StereoAccuracy, PanAboutYIsADisparityBiasOfFocalTimesAngle) {
  const StereoRig truth = simTruth();
  const double angle = 0.05 * kDeg;
  const StereoRig est = turnRight(truth, {0, angle, 0});
  const double expected = rectifiedFocal(est) * angle;
  const StereoAccuracy c = atCentre(est, truth);
  for (const DepthAccuracy& d : c.at_depth) {
    SCOPED_TRACE(std::to_string(d.depth_m) + " m");
    EXPECT_NEAR(d.disparity_bias_px.rms, expected, 0.03 * expected);
    EXPECT_LT(d.misalignment_px.rms, 0.02 * expected);
    if (std::isinf(d.depth_m)) continue;
    // The bias shortens or lengthens the depth by b / (d + b) of the true disparity d.
    const double disparity = rectifiedFocal(est) * truth.baseline() / d.depth_m;
    const double relative = expected / disparity;
    EXPECT_NEAR(d.depth_error_pct.rms / 100.0, relative / (1.0 + relative), 0.05 * relative) << d.depth_m;
  }
}

TEST(StereoAccuracy, RefusesUnusableInputs) {
  const StereoRig truth = simTruth();
  StereoRig smaller = truth;
  smaller.left.width = smaller.right.width = 640;
  EXPECT_THROW(evaluateStereoAccuracy(smaller, truth), std::invalid_argument);
  StereoAccuracyOptions o;
  o.depths_m = {1.0, -2.0};
  EXPECT_THROW(evaluateStereoAccuracy(truth, truth, o), std::invalid_argument);
  RigCovariance c = RigCovariance::Zero();
  c(3, 3) = -1.0;
  EXPECT_THROW(predictStereoAccuracy(truth, c), std::invalid_argument);
}

// A covariance like a solve's: sd 0.05 % on the focal lengths, 0.3 px on the principal points,
// 0.002 / 0.005 on k1 / k2, 0.01 deg on the rotation and 0.1 mm on the translation, with
// correlations drawn at random (a random correlation matrix).
RigCovariance solveLikeCovariance(const StereoRig& rig) {
  RigParameters sd = RigParameters::Zero();
  for (int c = 0; c < 2; ++c) {
    const PinholeCamera& cam = c == 0 ? rig.left : rig.right;
    sd.segment<6>(9 * c) << 5e-4 * cam.fx, 5e-4 * cam.fy, 0.3, 0.3, 0.002, 0.005;
  }
  sd.segment<3>(18).setConstant(0.01 * kDeg);
  sd.segment<3>(21).setConstant(1e-4);
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g;
  Eigen::MatrixXd A(kRigParameterCount, kRigParameterCount + 6);
  for (int i = 0; i < A.size(); ++i) A.data()[i] = g(rng);
  Eigen::MatrixXd corr = A * A.transpose();
  const Eigen::VectorXd s = corr.diagonal().cwiseSqrt().cwiseInverse();
  corr = s.asDiagonal() * corr * s.asDiagonal();
  RigCovariance c = sd.asDiagonal() * corr * sd.asDiagonal();
  return c;
}

// (b) The linearised prediction against Monte Carlo: draw estimates from the covariance around
// the truth, measure each against the truth, and take the RMS of the figures over the draws.
TEST(StereoAccuracy, PredictionIsTheMonteCarloExpectationOfTheCovariance) {
  const StereoRig truth = simTruth();
  const RigCovariance cov = solveLikeCovariance(truth);
  const auto start = std::chrono::steady_clock::now();
  const StereoAccuracy p = predictStereoAccuracy(truth, cov);
  std::printf("[ figures  ] predictStereoAccuracy: %.1f ms (%d samples)\n",
              std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count(), p.samples);
  // A square root of the (singular: p1, p2, k3 held) covariance.
  const Eigen::SelfAdjointEigenSolver<RigCovariance> eig(cov);
  ASSERT_GT(eig.eigenvalues().minCoeff(), -1e-12 * eig.eigenvalues().maxCoeff());
  const RigCovariance root = eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal();
  std::mt19937_64 rng(11);
  std::normal_distribution<double> g;
  const int kDraws = 300;
  double m2 = 0, b2 = 0;
  std::vector<double> e2(p.at_depth.size(), 0.0);
  for (int k = 0; k < kDraws; ++k) {
    RigParameters z;
    for (int i = 0; i < kRigParameterCount; ++i) z[i] = g(rng);
    const StereoRig est = rigFromParameters(rigParameters(truth) + RigParameters(root * z), truth);
    const StereoAccuracy a = evaluateStereoAccuracy(est, truth);
    m2 += a.misalignment_px.rms * a.misalignment_px.rms;
    b2 += a.disparity_bias_px.rms * a.disparity_bias_px.rms;
    for (size_t d = 0; d < e2.size(); ++d) e2[d] += std::pow(a.at_depth[d].depth_error_pct.rms, 2);
  }
  const double m = std::sqrt(m2 / kDraws), b = std::sqrt(b2 / kDraws);
  std::printf("[ figures  ] Monte Carlo / predicted: misalignment %.4f / %.4f px, bias %.4f / %.4f px\n", m,
              p.misalignment_px.rms, b, p.disparity_bias_px.rms);
  // 300 draws: the RMS over them is good to a few per cent.
  EXPECT_NEAR(p.misalignment_px.rms / m, 1.0, 0.08);
  EXPECT_NEAR(p.disparity_bias_px.rms / b, 1.0, 0.08);
  for (size_t d = 0; d < e2.size(); ++d) {
    if (std::isinf(p.at_depth[d].depth_m)) continue;
    const double mc = std::sqrt(e2[d] / kDraws);
    std::printf("[ figures  ] depth error at %.0f m: Monte Carlo %.4f %%, predicted %.4f %%\n", p.at_depth[d].depth_m,
                mc, p.at_depth[d].depth_error_pct.rms);
    EXPECT_NEAR(p.at_depth[d].depth_error_pct.rms / mc, 1.0, 0.08) << p.at_depth[d].depth_m << " m";
  }
  // The worst sample's sd is at least the RMS.
  EXPECT_GE(p.misalignment_px.max, p.misalignment_px.rms);
}

// (c) The calibrator's solve: the rigid device model on the sim's head, the nominal device off
// by manufacturing tolerances (1 mm, 0.5 deg), 0.2 px corner noise, 5 frames (the calibrator's
// default window minimum) per trial, 50 trials: the ratio of an RMS over trials to its
// prediction scatters by about 1/sqrt(2 n) for each parameter that dominates it, and the bias
// and the far depth errors are dominated by few (over 20 trials one seed set gave 1.51).
TEST(StereoAccuracyCalibrator, TrueErrorsMatchTheReportedCovarianceOverFiftyTrials) {
  const auto start = std::chrono::steady_clock::now();
  const StereoRig truth = simTruth();
  cv::FileStorage fs = openYaml(ECS_SOURCE_DIR "/config/sim_rig.yaml");
  const CalibrationDevice device = loadDevice(fs["device"], "device");
  // ECS_ACCURACY_TRIALS: more trials for the figures in docs/figures.md (the test's bounds are
  // for 20).
  const char* trials_env = std::getenv("ECS_ACCURACY_TRIALS");
  const int kTrials = trials_env ? std::max(1, std::atoi(trials_env)) : 50;
  int inside = 0, total = 0;
  double true_m2 = 0, true_b2 = 0, pred_m2 = 0, pred_b2 = 0, mahalanobis = 0;
  int free_parameters = 0;
  std::vector<double> true_e2(4, 0.0), pred_e2(4, 0.0);
  for (int trial = 0; trial < kTrials; ++trial) {
    SyntheticObservationOptions o;
    o.frames = 5;
    o.noise_sigma_px = 0.2;
    o.seed = 300 + trial;
    const std::vector<StereoObservation> frames = generateSyntheticObservations(truth, device.virtualBoards(), o);
    const CalibrationDevice nominal = perturbDevice(device, 0.001, 0.5, 400 + trial);
    CalibrationInput input;
    input.frames = &frames;
    input.device = &nominal;
    input.image_width = truth.left.width;
    input.image_height = truth.left.height;
    input.in_force = truth;
    const BundleAdjustmentSummary r = BundleAdjuster({}, {}).Solve(input);
    ASSERT_TRUE(r.success && r.covariance_ok) << r.message;
    ASSERT_EQ(r.board_poses, "device model");
    for (double z : errorsInReportedStddevs(r, truth)) {
      ++total;
      if (z <= 3.0) ++inside;
    }
    // The full covariance: its diagonal is the reported sd, and the error's Mahalanobis
    // distance over its free parameters is chi-square with that many degrees of freedom.
    const RigCovariance& C = r.rig_covariance;
    EXPECT_NEAR(std::sqrt(C(0, 0)), r.left_stddev.fx, 1e-9 * r.left_stddev.fx);
    EXPECT_NEAR(std::sqrt(C(13, 13)), r.right_stddev.dist[0], 1e-9 * r.right_stddev.dist[0]);
    EXPECT_EQ(C(6, 6), 0.0);  // p1: held
    std::vector<int> free;
    for (int k = 0; k < kRigParameterCount; ++k)
      if (C(k, k) > 0) free.push_back(k);
    const RigParameters err = rigParameters(r.rig) - rigParameters(truth);
    Eigen::MatrixXd Cf(free.size(), free.size());
    Eigen::VectorXd ef(free.size());
    for (size_t a = 0; a < free.size(); ++a) {
      ef[a] = err[free[a]];
      for (size_t b = 0; b < free.size(); ++b) Cf(a, b) = C(free[a], free[b]);
    }
    mahalanobis += ef.dot(Cf.ldlt().solve(ef));
    free_parameters = static_cast<int>(free.size());

    const StereoAccuracy t = evaluateStereoAccuracy(r.rig, truth);
    const StereoAccuracy p = predictStereoAccuracy(r.rig, C);
    true_m2 += std::pow(t.misalignment_px.rms, 2);
    true_b2 += std::pow(t.disparity_bias_px.rms, 2);
    pred_m2 += std::pow(p.misalignment_px.rms, 2);
    pred_b2 += std::pow(p.disparity_bias_px.rms, 2);
    for (int d = 0; d < 4; ++d) {
      true_e2[d] += std::pow(t.at_depth[d].depth_error_pct.rms, 2);
      pred_e2[d] += std::pow(p.at_depth[d].depth_error_pct.rms, 2);
    }
  }
  const double true_m = std::sqrt(true_m2 / kTrials), pred_m = std::sqrt(pred_m2 / kTrials);
  const double true_b = std::sqrt(true_b2 / kTrials), pred_b = std::sqrt(pred_b2 / kTrials);
  std::printf("[ figures  ] %d trials: within 3 reported sd %d of %d; mean Mahalanobis distance^2 %.2f (%d free "
              "parameters)\n",
              kTrials, inside, total, mahalanobis / kTrials, free_parameters);
  std::printf("[ figures  ] RMS over trials, true / predicted: misalignment %.4f / %.4f px, bias %.4f / %.4f px\n",
              true_m, pred_m, true_b, pred_b);
  for (int d = 0; d < 4; ++d)
    std::printf("[ figures  ] depth error at %.0f m: true %.4f %%, predicted %.4f %%\n",
                StereoAccuracyOptions().depths_m[d], std::sqrt(true_e2[d] / kTrials), std::sqrt(pred_e2[d] / kTrials));
  EXPECT_GE(static_cast<double>(inside) / total, 0.95) << inside << " of " << total;
  // Chi-square with 50 x free degrees of freedom: its mean within 1 +- 0.35 with margin to spare.
  EXPECT_NEAR(mahalanobis / kTrials / free_parameters, 1.0, 0.35);
  EXPECT_LE(std::max(true_m / pred_m, pred_m / true_m), 1.5);
  EXPECT_LE(std::max(true_b / pred_b, pred_b / true_b), 1.5);
  for (int d = 0; d < 4; ++d) {
    const double t = std::sqrt(true_e2[d] / kTrials), p = std::sqrt(pred_e2[d] / kTrials);
    EXPECT_LE(std::max(t / p, p / t), 1.5) << "depth error at " << StereoAccuracyOptions().depths_m[d] << " m";
  }
  std::printf("[ figures  ] %d trials took %.1f s\n", kTrials,
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
