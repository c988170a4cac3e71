// CalibrationMonitor on the drive_photo scenario (config/drive_photo.yaml: the head driving through
// a photographed corridor with a person crossing and a door swinging), rendered by the core
// simulator. The calibration in force is the simulator's nominal calibration and its true board
// poses; the simulator then drifts the right camera (SetRigDrift's model) and the monitor must
// notice. Depth-mode frames are light-off frames; each verification is one light-on frame whose
// corners come from the real PatternTracker (taught once, no background: the scene moves).
// Times are the simulator's; frames are rendered at a reduced rate to keep the test short (the
// monitor takes any frame rate).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>

#include "embedded_calibration_stereo/core/calibration/calibration_monitor.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"
#include "embedded_calibration_stereo/test_support/sim_prior.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"
#include "embedded_calibration_stereo/test_support/synthetic_window.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kConfigDir = std::string(ECS_SOURCE_DIR) + "/config/";

// The rotation of the right camera away from its nominal calibration (deg).
double rotationErrorDeg(const SimRig& sim, double t) {
  return rotationAngleDeg(sim.truthAt(t).right_from_left.linear(), sim.config().rig.right_from_left.linear());
}

// The same as a rotation vector (deg) in the monitor's convention (HealthReport::
// right_rotation_deg: the right frame turned by w, points mapped by its transpose), from the truth:
// R_true = R(w)^T R_nominal.
Eigen::Vector3d truthTurnDeg(const SimRig& sim, double t) {
  const Eigen::AngleAxisd a(Eigen::Matrix3d(sim.config().rig.right_from_left.linear() *
                                            sim.truthAt(t).right_from_left.linear().transpose()));
  return a.axis() * a.angle() * 180.0 / M_PI;
}

// The true accuracy figures of the calibration in force against the simulator's truth.
StereoAccuracy trueAccuracy(const SimRig& sim, double t) {
  StereoAccuracyOptions o;
  o.depths_m = {1.0, 2.0, 5.0, 10.0};
  return evaluateStereoAccuracy(sim.config().rig, sim.truthAt(t), o);
}

// The monitor's predicted depth error against the true one, at every depth.
void expectDepthErrorPredicted(const SimRig& sim, double t, const HealthReport& r) {
  const StereoAccuracy truth = trueAccuracy(sim, t);
  for (size_t i = 0; i < kHealthDepthsM.size(); ++i) {
    const double e = truth.at_depth[i].depth_error_pct.rms;
    std::printf("    depth error at %.0f m: predicted %.3f %%, true %.3f %%\n", kHealthDepthsM[i],
                r.predicted_depth_error_pct[i], e);
    EXPECT_NEAR(r.predicted_depth_error_pct[i], e, 0.05 + 0.2 * e) << "at " << kHealthDepthsM[i] << " m";
  }
}

// One head on drive_photo with its monitor. Frames are rendered at `depth_hz` (light off) with a
// verification (light on, tracked) every `verification_period_s`.
class Head {
 public:
  Head(double depth_hz, double verification_period_s = 2.0)
      : sim_(loadSimRigConfig(kConfigDir + "drive_photo.yaml")),
        depth_dt_(1.0 / depth_hz),
        period_(verification_period_s),
        monitor_(options(verification_period_s)),
        tracker_(teachSimPrior(sim_, 0.0), TrackerOptions()) {
    monitor_.setCalibration(sim_.config().rig, 1, sim_.virtualBoards(), true);
  }
  static CalibrationMonitorOptions options(double period) {
    CalibrationMonitorOptions o;
    o.verification_period_s = period;
    o.depth_frame_stride = 1;  // frames are rendered at the measuring rate
    return o;
  }

  // Runs from the current time to `until` (s); `each_frame(t)` runs before every frame (drift).
  // Stops early when `stop(report)` is true after a frame. Returns the last report.
  template <typename Before, typename Stop>
  HealthReport runUntil(double until, Before each_frame, Stop stop) {
    HealthReport r = monitor_.report();
    while ((k_ + 1) * depth_dt_ <= until + 1e-6) {
      t_ = ++k_ * depth_dt_;  // by frame index: no drift of the clock
      each_frame(t_);
      if (t_ >= next_verification_ - 1e-6) {
        const SimFrame on = sim_.render(t_, 1.0, seed_++);
        const StereoObservation obs = tracker_.trackStereo(on.left, on.right, t_);
        EXPECT_TRUE(monitor_.addVerification(t_, obs)) << "t " << t_ << ": " << monitor_.report().reason;
        next_verification_ += period_;
        ++verifications_;
      } else {
        const SimFrame off = sim_.render(t_, 0.0, seed_++);
        monitor_.addDepthFrame(t_, off.left, off.right);
        ++depth_frames_;
      }
      r = monitor_.report();
      if (stop(r)) break;
    }
    return r;
  }
  HealthReport runUntil(double until) {
    return runUntil(until, [](double) {}, [](const HealthReport&) { return false; });
  }

  SimRig& sim() { return sim_; }
  CalibrationMonitor& monitor() { return monitor_; }
  double time() const { return t_; }
  int verifications() const { return verifications_; }
  int depthFrames() const { return depth_frames_; }
  // The next verification comes at least `gap` after t (so a change can be placed between two).
  double nextVerification() const { return next_verification_; }

 private:
  SimRig sim_;
  double depth_dt_, period_;
  CalibrationMonitor monitor_;
  PatternTracker tracker_;
  double t_ = 0.0;
  int k_ = 0;
  double next_verification_ = 0.0;
  uint64_t seed_ = 100;
  int verifications_ = 0, depth_frames_ = 0;
};

bool leftGood(const HealthReport& r) {
  return r.state == CalibrationHealth::kDegraded || r.state == CalibrationHealth::kBad;
}

void print(const char* what, const HealthReport& r, double t) {
  std::printf("  %s: t %.2f s %s, misalignment %.3f +- %.3f px (%d matches), boards L %.3f R %.3f stereo %.3f "
              "residual %.3f px, bias %.3f px, right turn (%.4f, %.4f, %.4f) deg, focal x%.4f/x%.4f, depth error "
              "%.2f/%.2f/%.2f/%.2f %%\n    %s\n",
              what, t, toString(r.state), r.misalignment_px, r.misalignment_sd_px, r.matches, r.board_rms_left_px,
              r.board_rms_right_px, r.stereo_consistency_px, r.board_residual_px, r.disparity_bias_px,
              r.right_rotation_deg.x(), r.right_rotation_deg.y(), r.right_rotation_deg.z(), r.left_focal_scale,
              r.right_focal_scale, r.predicted_depth_error_pct[0], r.predicted_depth_error_pct[1],
              r.predicted_depth_error_pct[2], r.predicted_depth_error_pct[3], r.reason.c_str());
}

// The figures of an undrifted head stay GOOD while it drives past the movers (20 s: a door swing,
// the person crossing twice, turns both ways); the worst of each figure after the first second is
// held to half its threshold.
TEST(CalibrationMonitor, NoDriftStaysGood) {
  Head head(5.0);
  double worst_misalignment = 0, worst_bias = 0, worst_residual = 0;
  int good = 0, reports = 0;
  const HealthReport last = head.runUntil(
      20.0, [](double) {},
      [&](const HealthReport& r) {
        ++reports;
        good += r.state == CalibrationHealth::kGood;
        // The depth mode's first smoothing time constant is its settling (it does not count).
        if (head.time() < 1.0) return false;
        worst_misalignment = std::max(worst_misalignment, r.misalignment_px);
        worst_bias = std::max(worst_bias, r.disparity_bias_px);
        worst_residual = std::max(worst_residual, r.board_residual_px);
        return false;
      });
  print("no drift", last, head.time());
  std::printf("  worst over %d frames (%d verifications): misalignment %.3f px, bias %.3f px, residual %.3f px\n",
              reports, head.verifications(), worst_misalignment, worst_bias, worst_residual);
  EXPECT_EQ(good, reports);
  EXPECT_GE(last.matches, 100);
  EXPECT_LT(worst_misalignment, 0.5 * CalibrationMonitorOptions().misalignment_degraded_px);
  EXPECT_LT(worst_bias, 0.5 * CalibrationMonitorOptions().disparity_bias_degraded_px);
  EXPECT_LT(worst_residual, 0.5 * CalibrationMonitorOptions().board_residual_degraded_px);
}

// A knock of the right camera at t = 1 s; returns the delay to the first DEGRADED (or -1), the
// report at the end of the window and the true turn.
double knockDelay(const Eigen::Vector3d& knock_deg, double depth_hz, double period, double window_s,
                  HealthReport* out, Eigen::Vector3d* truth) {
  Head head(depth_hz, period);
  const HealthReport before = head.runUntil(1.0);
  EXPECT_EQ(before.state, CalibrationHealth::kGood) << before.reason;
  DriftRequest knock;
  knock.knock_rotation_deg = knock_deg;
  EXPECT_TRUE(head.sim().setDrift(knock, head.time()).empty());
  const double t0 = head.time();
  double first = -1.0;
  *out = head.runUntil(
      t0 + window_s, [](double) {},
      [&](const HealthReport& r) {
        if (first < 0 && leftGood(r)) first = head.time() - t0;
        return false;
      });
  *truth = truthTurnDeg(head.sim(), head.time());
  return first;
}

// Tilt and roll (about x and z) move rows: the depth mode sees them within 2 s of frames (here
// 15 frames a second and no verification inside the window).
void expectRowKnockDegradedWithinTwoSeconds(int axis, const char* name) {
  Eigen::Vector3d knock = Eigen::Vector3d::Zero();
  knock[axis] = 0.05;
  HealthReport r;
  Eigen::Vector3d truth;
  const double delay = knockDelay(knock, 10.0, 100.0, 2.0, &r, &truth);
  print(name, r, delay);
  std::printf("    first DEGRADED %.2f s after the knock; turn fitted %.4f deg, true %.4f deg\n", delay,
              r.right_rotation_deg[axis], truth[axis]);
  EXPECT_GE(delay, 0.0) << r.reason;
  EXPECT_EQ(r.state, CalibrationHealth::kDegraded) << r.reason;
  EXPECT_NEAR(r.right_rotation_deg[axis], truth[axis], 0.01);
}

TEST(CalibrationMonitor, TiltKnockDegradedWithinTwoSeconds) {
  expectRowKnockDegradedWithinTwoSeconds(0, "knock 0.05 deg about x");
}

TEST(CalibrationMonitor, RollKnockDegradedWithinTwoSeconds) {
  expectRowKnockDegradedWithinTwoSeconds(2, "knock 0.05 deg about z");
}

// A change between two verifications must be DEGRADED at the next one; the depth mode alone (in
// between) must not see it.
void expectCaughtByNextVerification(const char* what, const DriftRequest& drift, HealthReport* at,
                                    Eigen::Vector3d* truth) {
  Head head(5.0, 2.0);
  const HealthReport before = head.runUntil(2.5);  // verifications at 0 and 2 s
  ASSERT_EQ(before.state, CalibrationHealth::kGood) << before.reason;
  EXPECT_TRUE(head.sim().setDrift(drift, head.time()).empty());
  const int verifications = head.verifications();
  const HealthReport between = head.runUntil(head.nextVerification() - 0.1);
  EXPECT_EQ(between.state, CalibrationHealth::kGood) << what << ": the depth mode saw it: " << between.reason;
  *at = head.runUntil(head.nextVerification());
  EXPECT_EQ(head.verifications(), verifications + 1);
  print(what, *at, head.time());
  EXPECT_EQ(at->state, CalibrationHealth::kDegraded) << at->reason;
  *truth = truthTurnDeg(head.sim(), head.time());
  expectDepthErrorPredicted(head.sim(), head.time(), *at);
}

TEST(CalibrationMonitor, PanKnockDegradedAtNextVerification) {
  DriftRequest knock;
  knock.knock_rotation_deg = Eigen::Vector3d(0, 0.05, 0);
  HealthReport r;
  Eigen::Vector3d truth;
  expectCaughtByNextVerification("knock 0.05 deg about y", knock, &r, &truth);
  EXPECT_NEAR(r.right_rotation_deg.y(), truth.y(), 0.005);
}

TEST(CalibrationMonitor, ZoomDegradedAtNextVerification) {
  DriftRequest zoom;
  zoom.focal_scale = 1.01;
  HealthReport r;
  Eigen::Vector3d truth;
  expectCaughtByNextVerification("zoom 1 %", zoom, &r, &truth);
  EXPECT_NEAR(r.left_focal_scale, 1.01, 0.001);
  EXPECT_NEAR(r.right_focal_scale, 1.01, 0.001);
}

// Thermal ramps at 0.01 deg/s must be caught before the right camera has turned 0.03 deg. About
// y (the simulator's thermal drift) only the boards see it; about x and z (applied here as a
// right_rotation_deg updated every frame) the depth mode does.
double rampCaughtAtDeg(int axis, double depth_hz) {
  Head head(depth_hz, 2.0);
  const HealthReport before = head.runUntil(1.3);
  EXPECT_EQ(before.state, CalibrationHealth::kGood) << before.reason;
  const double t0 = head.time(), rate = 0.01;
  if (axis == 1) {
    DriftRequest thermal;
    thermal.thermal_rate_deg_per_s = rate;
    EXPECT_TRUE(head.sim().setDrift(thermal, t0).empty());
  }
  const HealthReport r = head.runUntil(
      t0 + 6.0,
      [&](double t) {
        if (axis == 1) return;
        DriftRequest turn;
        turn.right_rotation_deg[axis] = rate * (t - t0);
        EXPECT_TRUE(head.sim().setDrift(turn, t).empty());
      },
      leftGood);
  const double caught = rotationErrorDeg(head.sim(), head.time());
  char what[64];
  std::snprintf(what, sizeof(what), "thermal 0.01 deg/s about %c", "xyz"[axis]);
  print(what, r, head.time());
  std::printf("  caught at %.4f deg (%.2f s after the start)\n", caught, head.time() - t0);
  EXPECT_TRUE(leftGood(r)) << r.reason;
  return caught;
}

TEST(CalibrationMonitor, ThermalRampAboutYCaughtBeforeThreeHundredthsOfADegree) {
  EXPECT_LT(rampCaughtAtDeg(1, 5.0), 0.03);
}
TEST(CalibrationMonitor, ThermalRampAboutXCaughtBeforeThreeHundredthsOfADegree) {
  EXPECT_LT(rampCaughtAtDeg(0, 10.0), 0.03);
}
TEST(CalibrationMonitor, ThermalRampAboutZCaughtBeforeThreeHundredthsOfADegree) {
  EXPECT_LT(rampCaughtAtDeg(2, 10.0), 0.03);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core

namespace embedded_calibration_stereo::core {
namespace {

// A wrong calibration put in force (the right camera's focal length 0.5 % too long, as a bad
// commit would) is caught by the first verification, with and without the boards' poses; the
// fitted change names it.
TEST(CalibrationMonitor, WrongCalibrationCaughtByFirstVerification) {
  SimRig sim(loadSimRigConfig(kConfigDir + "drive_photo.yaml"));
  PatternTracker tracker(teachSimPrior(sim, 0.0), TrackerOptions());
  const SimFrame on = sim.render(0.5, 1.0, 11);
  const StereoObservation obs = tracker.trackStereo(on.left, on.right, 0.5);
  StereoRig wrong = sim.config().rig;
  wrong.right.fx *= 1.005;
  wrong.right.fy *= 1.005;
  for (bool posed : {true, false}) {
    CalibrationMonitor monitor{CalibrationMonitorOptions()};
    monitor.setCalibration(sim.config().rig, 1, sim.virtualBoards(), posed);
    ASSERT_TRUE(monitor.addVerification(0.5, obs));
    const HealthReport right = monitor.report();
    EXPECT_EQ(right.state, CalibrationHealth::kGood) << right.reason;  // the control
    monitor.setCalibration(wrong, 2, sim.virtualBoards(), posed);
    EXPECT_EQ(monitor.report().state, CalibrationHealth::kUnknown);
    ASSERT_TRUE(monitor.addVerification(0.5, obs));
    const HealthReport r = monitor.report();
    print(posed ? "right focal length 0.5 % long, boards posed" : "right focal length 0.5 % long, no board poses",
          r, 0.5);
    EXPECT_EQ(r.epoch, 2);
    EXPECT_TRUE(leftGood(r)) << r.reason;
    EXPECT_NEAR(r.right_focal_scale, 1.0 / 1.005, 0.001);
  }
}

// Unusable options and inputs are refused with a message naming the problem; a refused
// calibration leaves the one in force.
TEST(CalibrationMonitor, RefusesBadOptionsAndInputs) {
  CalibrationMonitorOptions o;
  o.misalignment_bad_px = o.misalignment_degraded_px;
  EXPECT_NE(o.validate().find("misalignment_bad_px"), std::string::npos) << o.validate();
  EXPECT_THROW(CalibrationMonitor{o}, std::invalid_argument);
  o = CalibrationMonitorOptions();
  o.matching.lk_window_px = 12;
  EXPECT_NE(o.validate().find("lk_window_px"), std::string::npos) << o.validate();
  EXPECT_EQ(CalibrationMonitorOptions().validate(), "");

  const SimRigConfig config = loadSimRigConfig(kConfigDir + "drive_photo.yaml");
  CalibrationMonitor monitor{Head::options(2.0)};  // measures on every depth frame
  EXPECT_EQ(monitor.report().state, CalibrationHealth::kUnknown);
  EXPECT_THROW(monitor.addDepthFrame(0.0, cv::Mat(480, 752, CV_8UC1), cv::Mat(480, 752, CV_8UC1)), std::logic_error);
  monitor.setCalibration(config.rig, 3, {}, false);
  StereoRig broken = config.rig;
  broken.right.fx = -1.0;
  EXPECT_THROW(monitor.setCalibration(broken, 4, {}, false), std::invalid_argument);
  EXPECT_EQ(monitor.report().epoch, 3);
  EXPECT_THROW(monitor.addDepthFrame(0.0, cv::Mat(240, 376, CV_8UC1), cv::Mat(240, 376, CV_8UC1)),
               std::invalid_argument);
  EXPECT_THROW(monitor.addDepthFrame(0.0, cv::Mat(480, 752, CV_16UC1), cv::Mat(480, 752, CV_16UC1)),
               std::invalid_argument);
  // A black pair has no features: no measurement, and the report says why.
  EXPECT_FALSE(monitor.addDepthFrame(0.0, cv::Mat::zeros(480, 752, CV_8UC1), cv::Mat::zeros(480, 752, CV_8UC1)));
  const HealthReport r = monitor.report();
  EXPECT_EQ(r.state, CalibrationHealth::kUnknown);
  EXPECT_NE(r.reason.find("too few scene features"), std::string::npos) << r.reason;
}

}  // namespace
}  // namespace embedded_calibration_stereo::core

namespace embedded_calibration_stereo::core {
namespace {

// A knock far beyond the band (0.5 deg about x: rows 5.7 px apart, the band is +-3 px) is still
// measured (the fit restarts from the median offset) and goes BAD within 2 s.
TEST(CalibrationMonitor, LargeTiltKnockBadWithinTwoSeconds) {
  HealthReport r;
  Eigen::Vector3d truth;
  const double delay = knockDelay(Eigen::Vector3d(0.5, 0, 0), 10.0, 100.0, 2.0, &r, &truth);
  print("knock 0.5 deg about x", r, delay);
  EXPECT_GE(delay, 0.0) << r.reason;
  EXPECT_EQ(r.state, CalibrationHealth::kBad) << r.reason;
  EXPECT_NEAR(r.right_rotation_deg.x(), truth.x(), 0.05);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core

namespace embedded_calibration_stereo::core {
namespace {

// A verification judges a calibration against board poses. A solve estimates the cameras and the
// board poses together: a window's solve (the drive_photo head, the window tracker's corner noise
// and scene correspondences, synthetic with known truth) checked with the true corners against
// its own solve's board poses shows no change, against the device's true (nominal) poses a
// change several times what its errors do to depth. So the health nodelet verifies a
// calibration against its solve's boards (health_solve_boards.test).
TEST(CalibrationMonitor, ASolvesCalibrationIsVerifiedAgainstItsSolvesBoards) {
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  const StereoRig& truth = head.truth;
  const CalibrationDevice& device = head.device;
  double true_sum = 0.0, nominal_sum = 0.0, solve_worst = 0.0;
  const int windows = 8;
  for (int seed = 0; seed < windows; ++seed) {
    SyntheticWindow w;
    w.corner_noise_px = 0.023 / M_SQRT2;
    w.corner_seed = 3000 + seed;
    w.scene_matches = 600;
    w.scene_seed = 4000 + seed;
    w.device_error_m = w.device_error_deg = 0.0;
    const BundleAdjustmentSummary solve = solveSyntheticWindow(head, truth, w);
    ASSERT_TRUE(solve.success) << solve.message;
    SyntheticObservationOptions v;
    v.noise_sigma_px = 0.02;
    v.seed = 9000 + seed;
    const StereoObservation verification = generateSyntheticObservations(truth, device.virtualBoards(), v)[0];
    std::vector<VirtualBoard> solved = device.virtualBoards();
    for (VirtualBoard& b : solved) b.rig_from_board = solve.rig_from_board.at(b.virtual_id);
    double reported[2];
    for (int k = 0; k < 2; ++k) {
      CalibrationMonitor monitor(CalibrationMonitorOptions{});
      monitor.setCalibration(solve.rig, 1, k == 0 ? device.virtualBoards() : solved, true);
      ASSERT_TRUE(monitor.addVerification(1.0, verification));
      reported[k] = monitor.report().disparity_bias_px;
    }
    const double true_bias = evaluateStereoAccuracy(solve.rig, truth).disparity_bias_px.rms;
    std::printf("[ figures  ] window %d: true disparity bias %.4f px; verification against the true board poses %.4f "
                "px, against its solve's %.4f px\n",
                seed, true_bias, reported[0], reported[1]);
    true_sum += true_bias;
    nominal_sum += reported[0];
    solve_worst = std::max(solve_worst, reported[1]);
  }
  EXPECT_LT(solve_worst, 0.02);                     // noise only: 0.02 px corners on one frame
  EXPECT_GT(nominal_sum, 2.0 * true_sum);           // what the nominal poses would have reported
}

// Options refused by parameter name, nested ones with their path; the sentence is the same as
// validate() gives.
TEST(CalibrationMonitor, OptionProblemsNameTheParameter) {
  CalibrationMonitorOptions o;
  EXPECT_TRUE(o.problem().ok());
  o.misalignment_bad_px = o.misalignment_degraded_px / 2;
  EXPECT_EQ(o.problem().parameter, "misalignment_degraded_px");
  EXPECT_EQ(o.validate(), o.problem().text());
  o = CalibrationMonitorOptions();
  o.matching.grid_rows = 0;
  EXPECT_EQ(o.problem().parameter, "matching.grid_rows");
  EXPECT_EQ(o.problem().problem, "must be >= 1");
  o = CalibrationMonitorOptions();
  o.max_verification_age_s = 0;
  EXPECT_EQ(o.problem().parameter, "max_verification_age_s");
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
