// rostest: the OnlineCalibrator in the sim driver's manager. Its observations come from this
// test, which relays the driver's ground_truth/observations (noise-free corners) to
// test/observations unchanged, reduced to one board, corrupted, or not at all.
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_msgs/TFMessage.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>
#include <tuple>

#include "calibrator_test_utils.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::Recalibrate;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;
using sensor_msgs::CameraInfo;

namespace {

enum class Relay { kNone, kForward, kSingleBoard, kCorrupt };

// Republishes ground truth on the calibrator's input according to the current mode.
class ObservationRelay {
 public:
  explicit ObservationRelay(ros::NodeHandle& nh)
      : pub_(nh.advertise<StereoPatternObservation>("test/observations", 10)),
        sub_(nh.subscribe("ground_truth/observations", 10, &ObservationRelay::relay, this)) {}
  void set(Relay mode) { mode_ = mode; }

 private:
  void relay(const StereoPatternObservation::ConstPtr& msg) {
    const Relay mode = mode_;
    if (mode == Relay::kNone) return;
    StereoPatternObservation out = *msg;
    if (mode == Relay::kSingleBoard) {
      for (auto* side : {&out.left, &out.right})
        if (side->size() > 1) side->resize(1);
    } else if (mode == Relay::kCorrupt && out.left.size() >= 2) {
      out.left[0].u[0] = std::numeric_limits<float>::quiet_NaN();
      out.left[1].corner_ids[1] = out.left[1].corner_ids[0];
    }
    pub_.publish(out);
  }
  ros::Publisher pub_;
  ros::Subscriber sub_;
  std::atomic<Relay> mode_{Relay::kNone};
};

struct Fixture {
  ros::NodeHandle nh;
  ObservationRelay relay{nh};
  Collector<CalibrationMode> modes{nh, "calibration_mode"};
  Collector<CameraInfo> left{nh, "left/camera_info"}, right{nh, "right/camera_info"};
  Collector<CameraInfo> truth_left{nh, "ground_truth/left/camera_info"}, truth_right{nh, "ground_truth/right/camera_info"};
  Collector<CalibrationStatus> status{nh, "calibration/status"};
  Collector<tf2_msgs::TFMessage> tf_static{nh, "/tf_static"};
  Collector<rosgraph_msgs::Log> log{nh, "/rosout", 1000};
};

Fixture* fixture = nullptr;

uint32_t currentEpoch() { return fixture->modes.snapshot().back()->calibration_epoch; }

bool recalibrate(uint32_t frames, double timeout_s, bool dry_run, Recalibrate* srv, double* elapsed_s) {
  srv->request.frames = frames;
  srv->request.timeout_s = timeout_s;
  srv->request.dry_run = dry_run;
  const ros::WallTime start = ros::WallTime::now();
  const bool ok = ros::service::call("calibration/recalibrate", *srv);
  *elapsed_s = (ros::WallTime::now() - start).toSec();
  return ok;
}

std::string fileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Waits until `n` more calibration_mode messages arrived (a few frames later).
void waitFrames(size_t n) {
  ASSERT_TRUE(fixture->modes.waitForCount(fixture->modes.snapshot().size() + n, 10.0));
}

}  // namespace

TEST(CalibratorSim, Setup) {
  ASSERT_TRUE(ros::service::waitForService("calibration/recalibrate", 20000));
  ASSERT_TRUE(fixture->modes.waitForCount(2, 20.0)) << "no calibration_mode from the driver";
  ASSERT_TRUE(fixture->left.waitForCount(1, 5.0));
}

TEST(CalibratorSim, TimesOutWithoutBoardsAndSwitchesTheLightOff) {
  fixture->relay.set(Relay::kNone);
  fixture->modes.clear();
  Recalibrate srv;
  double elapsed = 0;
  ASSERT_TRUE(recalibrate(10, 1.5, false, &srv, &elapsed));
  EXPECT_FALSE(srv.response.success);
  EXPECT_NE(srv.response.message.find("no boards seen"), std::string::npos) << srv.response.message;
  EXPECT_FALSE(srv.response.status.accepted);
  EXPECT_LT(elapsed, 1.5 + 1.0) << "timeout 1.5 s + 1 s margin";
  // The light was on during the wait and is off again a frame or two later.
  const auto during = fixture->modes.snapshot();
  EXPECT_TRUE(std::any_of(during.begin(), during.end(), [](const auto& m) { return m->light_on && m->settled; }));
  EXPECT_TRUE(fixture->modes.waitFor([](const auto& m) { return !m.empty() && !m.back()->light_on; }, 3.0));
}

TEST(CalibratorSim, DropsBadObservationsWithAnErrorNamingTheTopic) {
  fixture->relay.set(Relay::kCorrupt);
  std::string found;
  EXPECT_TRUE(test_support::waitForLog(fixture->log, {"test/observations", "non-finite", "duplicate"}, 10.0, &found));
  std::printf("logged: %s\n", found.c_str());
  fixture->relay.set(Relay::kNone);
  // Still alive: the service answers.
  Recalibrate srv;
  double elapsed = 0;
  EXPECT_TRUE(recalibrate(1, 0.5, true, &srv, &elapsed));
}

TEST(CalibratorSim, RejectedSolveChangesNothing) {
  // Store the calibration in force in its files first, so that there are bytes to compare.
  std::string left_path, right_path;
  ASSERT_TRUE(ros::param::get("~left_calibration_file", left_path));
  ASSERT_TRUE(ros::param::get("~right_calibration_file", right_path));
  for (const std::string side : {"left", "right"}) {
    sensor_msgs::SetCameraInfo set;
    set.request.camera_info = *(side == "left" ? fixture->left : fixture->right).snapshot().back();
    ASSERT_TRUE(ros::service::call(side + "/set_camera_info", set));
    ASSERT_TRUE(set.response.success) << set.response.status_message;
  }
  waitFrames(2);
  const uint32_t epoch = currentEpoch();
  const std::string left_bytes = fileBytes(left_path), right_bytes = fileBytes(right_path);
  ASSERT_FALSE(left_bytes.empty()) << left_path;
  ASSERT_FALSE(right_bytes.empty()) << right_path;
  const size_t tf_before = fixture->tf_static.snapshot().size();
  fixture->status.clear();

  fixture->relay.set(Relay::kSingleBoard);
  Recalibrate srv;
  double elapsed = 0;
  ASSERT_TRUE(recalibrate(10, 5.0, false, &srv, &elapsed));
  fixture->relay.set(Relay::kNone);
  EXPECT_FALSE(srv.response.success);
  EXPECT_FALSE(srv.response.status.accepted);
  EXPECT_FALSE(srv.response.status.reason.empty());
  std::printf("rejected: %s\n", srv.response.status.reason.c_str());
  ASSERT_TRUE(fixture->status.waitForCount(1, 2.0)) << "no calibration/status";
  EXPECT_FALSE(fixture->status.snapshot().back()->accepted);
  EXPECT_EQ(fixture->status.snapshot().back()->reason, srv.response.status.reason);
  waitFrames(3);
  EXPECT_EQ(currentEpoch(), epoch);
  EXPECT_EQ(fileBytes(left_path), left_bytes);
  EXPECT_EQ(fileBytes(right_path), right_bytes);
  EXPECT_EQ(fixture->tf_static.snapshot().size(), tf_before);
}

// The published rig against the truth. The corners are the sim's noise-free ground truth and
// device_config is the sim's own device, so the solve should return the truth up to the solver's
// tolerances (printed). The bounds leave a wide margin on that and are still several times
// tighter than what 10 frames reach at 0.2 px noise (docs/figures.md): fx, fy 0.01 %, cx, cy
// 0.05 px, baseline 0.01 %, rotation 0.005 deg.
void expectRigIsTheTruth(const core::StereoRig& published, const core::StereoRig& truth) {
  const auto relative = [](double a, double b) { return std::abs(a - b) / std::abs(b); };
  for (const auto& [est, ref, name] : {std::make_tuple(published.left, truth.left, "left"),
                                       std::make_tuple(published.right, truth.right, "right")}) {
    std::printf("%s fx %.6f %% fy %.6f %% cx %.4f px cy %.4f px\n", name, 100 * relative(est.fx, ref.fx),
                100 * relative(est.fy, ref.fy), est.cx - ref.cx, est.cy - ref.cy);
    EXPECT_LT(relative(est.fx, ref.fx), 1e-4) << name;
    EXPECT_LT(relative(est.fy, ref.fy), 1e-4) << name;
    EXPECT_LT(std::abs(est.cx - ref.cx), 0.05) << name;
    EXPECT_LT(std::abs(est.cy - ref.cy), 0.05) << name;
  }
  const double rotation_deg = core::rotationAngleDeg(published.right_from_left.linear(), truth.right_from_left.linear());
  std::printf("baseline %.6f %%, rotation %.5f deg\n", 100 * relative(published.baseline(), truth.baseline()),
              rotation_deg);
  EXPECT_LT(relative(published.baseline(), truth.baseline()), 1e-4);
  EXPECT_LT(rotation_deg, 0.005);
  // The right P carries Tx = -fx' * baseline.
  const CameraInfo& right = *fixture->right.snapshot().back();
  EXPECT_NEAR(right.P[3], -right.P[0] * published.baseline(), 1e-6 * right.P[0]);
}

// The commit on /tf_static: one transform, left to right, the truth's.
void expectTfStaticIsTheTruth(size_t tf_before, const core::StereoRig& truth) {
  ASSERT_TRUE(fixture->tf_static.waitForCount(tf_before + 1, 2.0)) << "no /tf_static update";
  const auto& transforms = fixture->tf_static.snapshot().back()->transforms;
  ASSERT_EQ(transforms.size(), 1u);
  EXPECT_EQ(transforms[0].header.frame_id, "stereo_left_optical_frame");
  EXPECT_EQ(transforms[0].child_frame_id, "stereo_right_optical_frame");
  const Eigen::Isometry3d left_from_right = tf2::transformToEigen(transforms[0]);
  const Eigen::Isometry3d truth_left_from_right = truth.leftFromRight();
  EXPECT_LT((left_from_right.translation() - truth_left_from_right.translation()).norm(), 1e-4 * truth.baseline());
  EXPECT_LT(core::rotationAngleDeg(left_from_right.linear(), truth_left_from_right.linear()), 0.005);
  ASSERT_TRUE(fixture->status.waitFor([](const auto& m) { return !m.empty() && m.back()->accepted; }, 2.0));
}

TEST(CalibratorSim, RecoversADriftedRigAndCommitsIt) {
  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.05;
  drift.request.right_rotation_deg = {0.0, 0.3, 0.0};
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  fixture->truth_left.clear();
  fixture->truth_right.clear();
  waitFrames(2);
  ASSERT_TRUE(fixture->truth_right.waitForCount(1, 5.0));
  const CameraInfo truth_left = *fixture->truth_left.snapshot().back();
  const CameraInfo truth_right = *fixture->truth_right.snapshot().back();
  core::StereoRig truth;
  std::string error;
  ASSERT_TRUE(embedded_calibration_stereo::fromStereoCameraInfo(truth_left, truth_right, &truth, &error)) << error;
  fixture->relay.set(Relay::kForward);

  // Dry run: an acceptable result, nothing committed.
  const uint32_t epoch = currentEpoch();
  const size_t tf_before = fixture->tf_static.snapshot().size();
  Recalibrate srv;
  double elapsed = 0;
  ASSERT_TRUE(recalibrate(10, 3.0, true, &srv, &elapsed));
  EXPECT_TRUE(srv.response.success) << srv.response.message;
  waitFrames(3);
  EXPECT_EQ(currentEpoch(), epoch);
  EXPECT_EQ(fixture->tf_static.snapshot().size(), tf_before);

  // The real one: committed, published by the driver and on /tf_static.
  ASSERT_TRUE(recalibrate(10, 3.0, false, &srv, &elapsed));
  fixture->relay.set(Relay::kNone);
  ASSERT_TRUE(srv.response.success) << srv.response.message;
  EXPECT_LT(elapsed, 3.0);
  std::printf("recalibrate: %.2f s, solve %.0f ms, rms %.4f / %.4f px\n", elapsed, srv.response.status.solve_ms,
              srv.response.status.rms_left_px, srv.response.status.rms_right_px);
  // The epoch reported is the one the driver stamps on its first frame carrying the commit.
  const std::optional<uint32_t> published_epoch =
      test_support::epochPublishedWith(srv.response.status, fixture->modes, fixture->left, fixture->right);
  ASSERT_TRUE(published_epoch) << "the driver never published the committed calibration";
  EXPECT_NE(*published_epoch, epoch);
  EXPECT_EQ(srv.response.status.epoch, *published_epoch);
  waitFrames(2);
  core::StereoRig published;
  ASSERT_TRUE(embedded_calibration_stereo::fromStereoCameraInfo(*fixture->left.snapshot().back(),
                                                                *fixture->right.snapshot().back(), &published, &error))
      << error;
  expectRigIsTheTruth(published, truth);
  expectTfStaticIsTheTruth(tf_before, truth);
}

// A pair set from outside the calibrator (the health monitor's rollback, a rosservice call)
// becomes the calibration in force: /tf_static must follow it, not keep the last commit's.
TEST(CalibratorSim, PutsACalibrationSetFromOutsideOnTfStatic) {
  ASSERT_TRUE(fixture->left.waitForCount(1, 5.0) && fixture->right.waitForCount(1, 5.0));
  core::StereoRig rig;
  std::string error;
  ASSERT_TRUE(embedded_calibration_stereo::fromStereoCameraInfo(*fixture->left.snapshot().back(),
                                                                *fixture->right.snapshot().back(), &rig, &error))
      << error;
  // Another rig: the right camera turned 0.2 deg about y and the baseline 1 % longer.
  rig.right_from_left.linear() = Eigen::AngleAxisd(0.2 * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix() *
                                 rig.right_from_left.linear();
  rig.right_from_left.translation() *= 1.01;
  auto pair = embedded_calibration_stereo::toStereoCameraInfo(rig);
  pair.first.header.frame_id = fixture->left.snapshot().back()->header.frame_id;
  pair.second.header.frame_id = fixture->right.snapshot().back()->header.frame_id;
  const size_t tf_before = fixture->tf_static.snapshot().size();
  for (const std::string side : {"left", "right"}) {
    sensor_msgs::SetCameraInfo set;
    set.request.camera_info = side == "left" ? pair.first : pair.second;
    ASSERT_TRUE(ros::service::call(side + "/set_camera_info", set));
    ASSERT_TRUE(set.response.success) << set.response.status_message;
  }
  ASSERT_TRUE(fixture->tf_static.waitFor(
      [&](const auto& all) {
        if (all.size() <= tf_before || all.back()->transforms.size() != 1) return false;
        const Eigen::Isometry3d left_from_right = tf2::transformToEigen(all.back()->transforms[0]);
        return core::rotationAngleDeg(left_from_right.linear(), rig.leftFromRight().linear()) < 1e-3 &&
               (left_from_right.translation() - rig.leftFromRight().translation()).norm() < 1e-6;
      },
      5.0))
      << "/tf_static does not carry the calibration set through set_camera_info";
}

int main(int argc, char** argv) {
  return test_support::runTestsWithFixture(argc, argv, "calibrator_sim_test", 2, &fixture);
}
