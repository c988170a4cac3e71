// The calibrator's ROS-side helpers that need no master: which observation messages are
// dropped and why, the CalibrationStatus filled from a solve, and whether a published
// camera_info carries a committed calibration.
#include <gtest/gtest.h>
#include <ros/time.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>

#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/ros/calibration_file.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/rectified_pair.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace core = embedded_calibration_stereo::core;

namespace ecsr = embedded_calibration_stereo;

namespace {

std::vector<core::VirtualBoard> simBoards() {
  cv::FileStorage fs = core::openYaml(std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml");
  return core::loadDevice(fs["device"], "device").virtualBoards();
}

// Ten corners of the first row of board `id`, on both sides.
core::StereoObservation observation(int id) {
  core::BoardCorners b;
  b.board_id = id;
  for (int i = 0; i < 10; ++i) {
    b.corner_ids.push_back(i);
    b.u.push_back(100.0f + 10 * i);
    b.v.push_back(200.0f);
  }
  core::StereoObservation o;
  o.left = {b};
  o.right = {b};
  return o;
}

bool anyContains(const std::vector<std::string>& lines, const std::string& needle) {
  for (const auto& l : lines)
    if (l.find(needle) != std::string::npos) return true;
  return false;
}

}  // namespace

TEST(ObservationDefects, CleanObservationHasNone) {
  const auto boards = simBoards();
  ASSERT_GE(boards.size(), 2u);
  EXPECT_TRUE(ecsr::observationDefects(observation(boards[1].virtual_id), boards).empty());
  // A board with only a few corners is usable data, not a defect of the message.
  core::StereoObservation few = observation(boards[0].virtual_id);
  few.left[0].corner_ids.resize(2);
  few.left[0].u.resize(2);
  few.left[0].v.resize(2);
  EXPECT_TRUE(ecsr::observationDefects(few, boards).empty());
}

TEST(ObservationDefects, NamesEachDefect) {
  const auto boards = simBoards();
  const int id = boards[0].virtual_id;

  core::StereoObservation nan = observation(id);
  nan.right[0].v[3] = std::numeric_limits<float>::quiet_NaN();
  auto defects = ecsr::observationDefects(nan, boards);
  ASSERT_EQ(defects.size(), 1u);
  EXPECT_NE(defects[0].find("right"), std::string::npos) << defects[0];
  EXPECT_NE(defects[0].find("non-finite"), std::string::npos) << defects[0];
  EXPECT_EQ(defects[0].find("frame 0"), std::string::npos) << "single message: no frame index";

  core::StereoObservation duplicate = observation(id);
  duplicate.left[0].corner_ids[4] = duplicate.left[0].corner_ids[5];
  EXPECT_TRUE(anyContains(ecsr::observationDefects(duplicate, boards), "duplicate"));

  core::StereoObservation outside = observation(id);
  outside.left[0].corner_ids[0] = boards[0].cornerCount();  // one past the last corner
  EXPECT_TRUE(anyContains(ecsr::observationDefects(outside, boards), "outside the board"));

  EXPECT_TRUE(anyContains(ecsr::observationDefects(observation(1000), boards), "unknown board"));

  core::StereoObservation lengths = observation(id);
  lengths.left[0].u.pop_back();
  EXPECT_TRUE(anyContains(ecsr::observationDefects(lengths, boards), "differ in length"));
}

TEST(MakeStatus, FillsEveryFieldInCameraInfoOrder) {
  ros::Time::init();
  core::BundleAdjustmentSummary s;
  s.rig.left.fx = 650;
  s.rig.left.fy = 651;
  s.rig.left.cx = 370;
  s.rig.left.cy = 240;
  s.rig.left.dist = {-0.28, 0.07, 0.001, -0.002, 0.0};
  s.rig.right = s.rig.left;
  s.rig.right.fx = 640;
  s.rig.right_from_left.translation() << -0.12, 0.0, 0.0;
  s.left_stddev.fx = 0.5;
  s.left_stddev.dist[1] = 0.01;
  s.right_stddev.cy = 0.3;
  s.frames_used = 10;
  s.corners_used = 1234;
  s.rms_left_px = 0.2;
  s.rms_right_px = 0.25;
  s.epipolar_rms_px = 0.1;
  s.baseline_stddev_m = 1e-4;
  s.rotation_stddev_deg = 0.02;
  s.solve_ms = 80;
  core::GateDecision rejected{false, "rejected: too few boards"};
  const auto status = ecsr::makeStatus(s, rejected);
  EXPECT_FALSE(status.accepted);
  EXPECT_EQ(status.reason, rejected.reason);
  EXPECT_EQ(status.frames_used, 10u);
  EXPECT_EQ(status.corners_used, 1234u);
  EXPECT_EQ(status.rms_left_px, 0.2);
  EXPECT_EQ(status.rms_right_px, 0.25);
  EXPECT_EQ(status.epipolar_rms_px, 0.1);
  const std::vector<double> left = {650, 651, 370, 240, -0.28, 0.07, 0.001, -0.002, 0.0};
  EXPECT_EQ(status.left_intrinsics, left);
  EXPECT_EQ(status.right_intrinsics[0], 640);
  EXPECT_EQ(status.left_intrinsics_stddev, (std::vector<double>{0.5, 0, 0, 0, 0, 0.01, 0, 0, 0}));
  EXPECT_EQ(status.right_intrinsics_stddev, (std::vector<double>{0, 0, 0, 0.3, 0, 0, 0, 0, 0}));
  EXPECT_NEAR(status.baseline_m, 0.12, 1e-12);
  EXPECT_EQ(status.baseline_stddev_m, 1e-4);
  EXPECT_EQ(status.rotation_stddev_deg, 0.02);
  EXPECT_EQ(status.solve_ms, 80);
  EXPECT_TRUE(ecsr::makeStatus(s, core::GateDecision{true, "ignored"}).reason.empty());
}

// The predicted depth accuracy comes from the solve's covariance: an uncertain rotation of the
// right camera about x is a vertical misalignment of about f' times its sd, an uncertain
// baseline a depth error of its relative sd at every depth; no covariance, no prediction.
TEST(MakeStatus, CarriesThePredictedDepthAccuracyOfTheCovariance) {
  ros::Time::init();
  core::BundleAdjustmentSummary s;
  s.success = true;
  s.rig = core::makeSimLikeStereoRig();
  const core::GateDecision accepted{true, ""};
  const std::vector<double> depths = {1, 2, 5, 10};
  auto status = ecsr::makeStatus(s, accepted);
  EXPECT_EQ(std::vector<double>(status.predicted_depths_m.begin(), status.predicted_depths_m.end()), depths);
  EXPECT_EQ(status.predicted_misalignment_rms_px, 0.0);  // no covariance
  EXPECT_EQ(status.predicted_depth_error_pct[0], 0.0);

  s.covariance_ok = true;
  const double angle_sd = 0.05 * M_PI / 180.0;
  s.rig_covariance(18, 18) = angle_sd * angle_sd;  // rotation vector x
  status = ecsr::makeStatus(s, accepted);
  const double f = s.rig.left.fx;
  EXPECT_GT(status.predicted_misalignment_rms_px, 0.95 * f * angle_sd);
  EXPECT_LT(status.predicted_misalignment_rms_px, 1.3 * f * angle_sd);
  EXPECT_LT(status.predicted_disparity_bias_rms_px, 0.2 * status.predicted_misalignment_rms_px);

  s.rig_covariance.setZero();
  const double baseline_sd = 0.01 * s.rig.baseline();
  s.rig_covariance(21, 21) = baseline_sd * baseline_sd;  // translation x: the baseline
  status = ecsr::makeStatus(s, accepted);
  EXPECT_LT(status.predicted_misalignment_rms_px, 0.01);
  for (size_t d = 0; d < depths.size(); ++d) EXPECT_NEAR(status.predicted_depth_error_pct[d], 1.0, 0.05) << depths[d];
}

TEST(CarriesCalibration, TellsTheCommittedCalibrationFromAnother) {
  const core::StereoRig rig = embedded_calibration_stereo::test_support::headRig();
  const auto [left, right] = ecsr::toStereoCameraInfo(rig);
  EXPECT_TRUE(ecsr::carriesCalibration(left, left));
  EXPECT_TRUE(ecsr::carriesCalibration(right, right));
  EXPECT_FALSE(ecsr::carriesCalibration(right, left));

  // A driver storing the calibration as a camera_calibration_parsers file and reading it back
  // still publishes the committed calibration.
  char dir[] = "/tmp/ecs_carries_calibration_XXXXXX";
  ASSERT_NE(mkdtemp(dir), nullptr);
  std::string error;
  sensor_msgs::CameraInfo reread;
  ASSERT_TRUE(ecsr::writeCalibrationFileAtomic(std::string(dir) + "/left.yaml", "left", left, &error)) << error;
  ASSERT_TRUE(ecsr::readCalibrationFile(std::string(dir) + "/left.yaml", nullptr, &reread, &error)) << error;
  std::filesystem::remove_all(dir);
  EXPECT_TRUE(ecsr::carriesCalibration(reread, left));

  // Another calibration: each field that a commit changes, changed a little.
  const auto changed = [&](auto edit) {
    sensor_msgs::CameraInfo other = left;
    edit(&other);
    return ecsr::carriesCalibration(other, left);
  };
  EXPECT_FALSE(changed([](auto* i) { i->K[0] *= 1.0 + 1e-5; }));
  EXPECT_FALSE(changed([](auto* i) { i->K[5] += 1e-3; }));
  EXPECT_FALSE(changed([](auto* i) { i->D[2] += 1e-5; }));
  EXPECT_FALSE(changed([](auto* i) { i->D.push_back(0.0); }));
  EXPECT_FALSE(changed([](auto* i) { i->R[1] += 1e-5; }));
  EXPECT_FALSE(changed([](auto* i) { i->P[3] -= 1e-3; }));
  EXPECT_FALSE(changed([](auto* i) { i->width = 640; }));
  EXPECT_FALSE(changed([](auto* i) { i->distortion_model = "equidistant"; }));
  // The header is not part of the calibration.
  EXPECT_TRUE(changed([](auto* i) { i->header.frame_id = "elsewhere"; }));
}

TEST(BoundRecalibrateRequest, LimitsFramesAndTimeoutAndRefusesNonFiniteTimeouts) {
  ecsr::CalibratorParams params;
  params.min_frames = 5;
  params.max_frames = 30;
  params.max_request_timeout_s = 60.0;
  // Within the limits: unchanged, no note.
  ecsr::BoundedRequest r = ecsr::boundRecalibrateRequest(10, 3.0, params);
  EXPECT_EQ(r.refusal, "");
  EXPECT_EQ(r.frames, 10u);
  EXPECT_EQ(r.timeout_s, 3.0);
  EXPECT_EQ(r.note, "");
  // Defaults: 0 frames -> min_frames, timeout <= 0 -> 10 s.
  r = ecsr::boundRecalibrateRequest(0, 0.0, params);
  EXPECT_EQ(r.frames, 5u);
  EXPECT_EQ(r.timeout_s, 10.0);
  r = ecsr::boundRecalibrateRequest(0, -4.0, params);
  EXPECT_EQ(r.timeout_s, 10.0);
  // With window observations: a whole burst (max_frames) by default.
  ecsr::CalibratorParams windows = params;
  windows.window_observations = true;
  EXPECT_EQ(ecsr::boundRecalibrateRequest(0, 0.0, windows).frames, 30u);
  EXPECT_EQ(ecsr::boundRecalibrateRequest(12, 0.0, windows).frames, 12u);
  // The request: 4e9 frames, 1e9 s.
  r = ecsr::boundRecalibrateRequest(4000000000u, 1e9, params);
  EXPECT_EQ(r.refusal, "");
  EXPECT_EQ(r.frames, 30u);
  EXPECT_EQ(r.timeout_s, 60.0);
  EXPECT_NE(r.note.find("max_frames"), std::string::npos) << r.note;
  EXPECT_NE(r.note.find("max_request_timeout_s"), std::string::npos) << r.note;
  // Non-finite: refused, saying why.
  for (double bad : {std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                     std::numeric_limits<double>::quiet_NaN()}) {
    r = ecsr::boundRecalibrateRequest(10, bad, params);
    EXPECT_NE(r.refusal.find("timeout_s must be a finite number"), std::string::npos) << r.refusal;
  }
  // A default above a small limit is limited too.
  params.max_request_timeout_s = 4.0;
  r = ecsr::boundRecalibrateRequest(10, 0.0, params);
  EXPECT_EQ(r.timeout_s, 4.0);
}

// CalibrationStatus.outcome: set with the flags that follow from it, in every status the
// calibrator builds without a solve, and from the gate's decision in a solve's.
TEST(CalibrationOutcome, TheStatusFlagsFollowTheOutcome) {
  ros::Time::init();
  using S = ecsr::CalibrationStatus;
  ecsr::CalibrationStatus status;
  for (const auto o : {core::CalibrationOutcome::kCommitted, core::CalibrationOutcome::kAcceptedNotCommitted,
                       core::CalibrationOutcome::kDryRunAcceptable}) {
    ecsr::setOutcome(&status, o);
    EXPECT_EQ(status.outcome, static_cast<uint8_t>(o));
    EXPECT_TRUE(status.accepted) << int(status.outcome);
    EXPECT_FALSE(status.in_force_confirmed) << int(status.outcome);
  }
  ecsr::setOutcome(&status, core::CalibrationOutcome::kInForceConfirmed);
  EXPECT_EQ(status.outcome, S::OUTCOME_IN_FORCE_CONFIRMED);
  EXPECT_FALSE(status.accepted);
  EXPECT_TRUE(status.in_force_confirmed);
  ecsr::setOutcome(&status, core::CalibrationOutcome::kCommitFailed);  // an accepted solve the driver did not store
  EXPECT_EQ(status.outcome, S::OUTCOME_COMMIT_FAILED);
  EXPECT_FALSE(status.accepted);
  EXPECT_FALSE(status.in_force_confirmed);

  const ecsr::CalibrationStatus busy = ecsr::statusWithoutSolve("busy: ...", 4);
  EXPECT_EQ(busy.outcome, S::OUTCOME_NOT_SOLVED);
  EXPECT_EQ(busy.epoch, 4u);
  EXPECT_EQ(busy.reason, "busy: ...");
  EXPECT_FALSE(busy.accepted);
  EXPECT_EQ(ecsr::statusWithoutSolve("no camera_info", 1, core::CalibrationOutcome::kMissingInputs).outcome,
            S::OUTCOME_MISSING_INPUTS);

  core::BundleAdjustmentSummary s;
  s.success = true;
  core::GateDecision decision;
  decision.setOutcome(core::GateOutcome::kRefinement);
  EXPECT_EQ(ecsr::makeStatus(s, decision).outcome, S::OUTCOME_COMMITTED);  // to be committed
  decision.setOutcome(core::GateOutcome::kChangeTooSmall);
  const ecsr::CalibrationStatus confirmed = ecsr::makeStatus(s, decision);
  EXPECT_EQ(confirmed.outcome, S::OUTCOME_IN_FORCE_CONFIRMED);
  EXPECT_TRUE(confirmed.in_force_confirmed);
  decision.setOutcome(core::GateOutcome::kRejected);
  EXPECT_EQ(ecsr::makeStatus(s, decision).outcome, S::OUTCOME_REJECTED);
}

TEST(CalibrationOutcome, TheRecalibrateMessageSaysCommittedOnlyForACommit) {
  ecsr::CalibrationStatus status;
  ecsr::setOutcome(&status, core::CalibrationOutcome::kCommitted);
  EXPECT_EQ(ecsr::recalibrateMessage(status), "committed");
  status.reason = "committed, but no frame with it on /stereo/calibration_mode within 2.0 s: ...";
  EXPECT_EQ(ecsr::recalibrateMessage(status), status.reason);
  core::CalibrationOutcome others[] = {core::CalibrationOutcome::kAcceptedNotCommitted,
                                      core::CalibrationOutcome::kDryRunAcceptable,
                                      core::CalibrationOutcome::kRejected};
  for (const auto o : others) {
    ecsr::setOutcome(&status, o);
    status.reason = "";
    EXPECT_EQ(ecsr::recalibrateMessage(status), "") << int(status.outcome);
  }
}
