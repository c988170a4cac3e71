// rostest: the whole graph on the simulated rig with the real tracker (full_graph.test).
// Records every frame's stamp (calibration_mode) and every disparity stamp from the start, zooms
// the rig by 5 % through sim/set_drift once the first calibration is in force, waits for the
// calibration of the next light window and compares the published CameraInfo and /tf_static
// with the simulator's truth; then forces a recalibration through the service.
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <stereo_msgs/DisparityImage.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_msgs/TFMessage.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <set>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::Recalibrate;
using test_support::Collector;
using sensor_msgs::CameraInfo;

namespace {

// The calibrator's bounds.
constexpr double kFocalRel = 0.0005, kPrincipalPx = 0.3, kK1 = 0.005, kBaselineRel = 0.001,
                 kRotationDeg = 0.01;

// The stamps of every disparity message (keeping the 1.4 MB messages would pile up).
class DisparityStamps {
 public:
  explicit DisparityStamps(ros::NodeHandle& nh)
      : sub_(nh.subscribe("disparity", 30, &DisparityStamps::add, this)) {}
  ~DisparityStamps() { sub_.shutdown(); }  // before mutex_ and stamps_ go (see Collector)
  std::set<ros::Time> snapshot() {
    std::lock_guard<std::mutex> lock(mutex_);
    return stamps_;
  }

 private:
  void add(const stereo_msgs::DisparityImage::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(mutex_);
    stamps_.insert(msg->header.stamp);
  }
  ros::Subscriber sub_;
  std::mutex mutex_;
  std::set<ros::Time> stamps_;
};

struct Fixture {
  ros::NodeHandle nh;
  Collector<CalibrationMode> modes{nh, "calibration_mode"};
  DisparityStamps disparity{nh};
  Collector<CameraInfo> left{nh, "left/camera_info"}, right{nh, "right/camera_info"};
  Collector<CameraInfo> truth_left{nh, "ground_truth/left/camera_info"};
  Collector<CameraInfo> truth_right{nh, "ground_truth/right/camera_info"};
  Collector<CalibrationStatus> status{nh, "calibration/status"};
  Collector<tf2_msgs::TFMessage> tf_static{nh, "/tf_static"};
};

Fixture* fixture = nullptr;

template <class M>
typename M::ConstPtr byStamp(const std::vector<typename M::ConstPtr>& messages, const ros::Time& stamp) {
  for (auto it = messages.rbegin(); it != messages.rend(); ++it)
    if ((*it)->header.stamp == stamp) return *it;
  return nullptr;
}

core::StereoRig stereoRig(const CameraInfo& left, const CameraInfo& right) {
  core::StereoRig rig;
  std::string error;
  EXPECT_TRUE(embedded_calibration_stereo::fromStereoCameraInfo(left, right, &rig, &error)) << error;
  return rig;
}

// Compares a published calibration with the truth of the same frame; prints every error.
void expectWithinBounds(const core::StereoRig& published, const core::StereoRig& truth,
                        const Eigen::Isometry3d& tf_left_from_right, const char* what) {
  const auto relative = [](double a, double b) { return std::abs(a - b) / std::abs(b); };
  for (const auto& [est, ref, name] : {std::make_tuple(published.left, truth.left, "left"),
                                       std::make_tuple(published.right, truth.right, "right")}) {
    std::printf("%s %s: fx %.4f %% fy %.4f %% cx %+.3f px cy %+.3f px k1 %+.5f\n", what, name,
                100 * relative(est.fx, ref.fx), 100 * relative(est.fy, ref.fy), est.cx - ref.cx,
                est.cy - ref.cy, est.dist[0] - ref.dist[0]);
    EXPECT_LE(relative(est.fx, ref.fx), kFocalRel) << name;
    EXPECT_LE(relative(est.fy, ref.fy), kFocalRel) << name;
    EXPECT_LE(std::abs(est.cx - ref.cx), kPrincipalPx) << name;
    EXPECT_LE(std::abs(est.cy - ref.cy), kPrincipalPx) << name;
    EXPECT_LE(std::abs(est.dist[0] - ref.dist[0]), kK1) << name;
  }
  const double baseline = relative(published.baseline(), truth.baseline());
  const double rotation =
      core::rotationAngleDeg(published.right_from_left.linear(), truth.right_from_left.linear());
  const double tf_rotation =
      core::rotationAngleDeg(tf_left_from_right.linear(), truth.leftFromRight().linear());
  const double tf_baseline = relative(tf_left_from_right.translation().norm(), truth.baseline());
  std::printf("%s: baseline %.4f %% (tf %.4f %%), rotation %.4f deg (tf %.4f deg)\n", what,
              100 * baseline, 100 * tf_baseline, rotation, tf_rotation);
  EXPECT_LE(baseline, kBaselineRel);
  EXPECT_LE(tf_baseline, kBaselineRel);
  EXPECT_LE(rotation, kRotationDeg);
  EXPECT_LE(tf_rotation, kRotationDeg);
}

// The calibration the driver published with the first frame of `epoch`, the simulator's truth of
// that frame and the latest /tf_static.
struct Published {
  core::StereoRig rig, truth;
  Eigen::Isometry3d tf_left_from_right = Eigen::Isometry3d::Identity();
};

Published publishedAt(uint32_t epoch) {
  Fixture& f = *fixture;
  Published out;
  EXPECT_TRUE(f.modes.waitFor([&](const auto& m) { return !m.empty() && m.back()->calibration_epoch >= epoch; }, 5.0));
  // Three frames later the CameraInfo of the epoch's first frame has surely arrived.
  EXPECT_TRUE(f.modes.waitForCount(f.modes.snapshot().size() + 3, 5.0));
  CalibrationMode::ConstPtr frame;
  for (const auto& m : f.modes.snapshot())
    if (m->calibration_epoch == epoch && !frame) frame = m;
  if (!frame) {
    ADD_FAILURE() << "no frame of epoch " << epoch;
    return out;
  }
  const auto left = byStamp<CameraInfo>(f.left.snapshot(), frame->header.stamp);
  const auto right = byStamp<CameraInfo>(f.right.snapshot(), frame->header.stamp);
  const auto truth_left = byStamp<CameraInfo>(f.truth_left.snapshot(), frame->header.stamp);
  const auto truth_right = byStamp<CameraInfo>(f.truth_right.snapshot(), frame->header.stamp);
  if (!(left && right && truth_left && truth_right)) {
    ADD_FAILURE() << "CameraInfo of frame " << frame->header.stamp << " missing";
    return out;
  }
  EXPECT_TRUE(f.tf_static.waitFor([](const auto& m) { return !m.empty(); }, 2.0));
  const auto tf = f.tf_static.snapshot();
  if (!tf.empty() && tf.back()->transforms.size() == 1)
    out.tf_left_from_right = tf2::transformToEigen(tf.back()->transforms[0]);
  else
    ADD_FAILURE() << "no single left->right transform on /tf_static";
  out.rig = stereoRig(*left, *right);
  out.truth = stereoRig(*truth_left, *truth_right);
  return out;
}

// A forced recalibration after a knock of the right camera: a real change to commit (with
// nothing to correct the service would answer success = true, "calibration in force confirmed",
// and commit nothing).
void expectKnockRecalibratedOnRequest() {
  Fixture& f = *fixture;
  embedded_calibration_stereo::SetRigDrift knock;
  knock.request.focal_scale = 1.05;
  knock.request.knock_rotation_deg = {0.2, -0.3, 0.1};
  ASSERT_TRUE(ros::service::call("sim/set_drift", knock));
  ASSERT_TRUE(knock.response.success) << knock.response.message;
  ASSERT_TRUE(f.modes.waitForCount(f.modes.snapshot().size() + 3, 5.0));
  Recalibrate srv;
  srv.request.frames = 10;
  srv.request.timeout_s = 3.0;
  const ros::WallTime start = ros::WallTime::now();
  ASSERT_TRUE(ros::service::call("calibration/recalibrate", srv));
  const double elapsed = (ros::WallTime::now() - start).toSec();
  std::printf("recalibrate after a 0.37 deg knock: success %d in %.2f s (%s), epoch %u\n", srv.response.success,
              elapsed, srv.response.message.c_str(), srv.response.status.epoch);
  EXPECT_TRUE(srv.response.success) << srv.response.message;
  EXPECT_LT(elapsed, 3.0);
  if (srv.response.success) {
    const Published knocked = publishedAt(srv.response.status.epoch);
    expectWithinBounds(knocked.rig, knocked.truth, knocked.tf_left_from_right, "after the knock");
  }
}

// Disparity over the whole run: every frame from the first disparity on has one, except for runs
// of at most two frames; light-on frames included.
void expectDisparityNeverStopped() {
  Fixture& f = *fixture;
  ASSERT_TRUE(f.modes.waitForCount(f.modes.snapshot().size() + 5, 5.0));
  const auto modes = f.modes.snapshot();
  const std::set<ros::Time> with_disparity = f.disparity.snapshot();
  ASSERT_FALSE(with_disparity.empty()) << "no disparity at all";
  const ros::Time first = *with_disparity.begin(), last = *with_disparity.rbegin();
  int frames = 0, light_on = 0, light_on_with = 0, run = 0, longest_gap = 0;
  for (const auto& m : modes) {
    if (m->header.stamp < first || m->header.stamp > last) continue;
    ++frames;
    const bool has = with_disparity.count(m->header.stamp) > 0;
    if (m->light_on) {
      ++light_on;
      light_on_with += has;
    }
    run = has ? 0 : run + 1;
    longest_gap = std::max(longest_gap, run);
    if (!has)  // where the gaps are, for the log
      std::printf("  no disparity for frame %.3f (light %s%s, epoch %u)\n", m->header.stamp.toSec(),
                  m->light_on ? "on" : "off", m->settled ? "" : ", settling", m->calibration_epoch);
  }
  std::printf("disparity: %zu of %d frames (%d of %d light-on frames), longest gap %d frames\n",
              with_disparity.size(), frames, light_on_with, light_on, longest_gap);
  EXPECT_GT(light_on, 20) << "the run should contain several light windows";
  EXPECT_LE(longest_gap, 2);
}

}  // namespace

TEST(FullGraph, ZoomAndKnockAreRecalibratedAndDisparityNeverStops) {
  Fixture& f = *fixture;
  ASSERT_TRUE(f.modes.waitForCount(5, 30.0)) << "no frames from the driver";
  // The tracker teaches itself at the first burst; the first auto-calibration follows. The rig
  // starts calibrated (the driver's calibration is the sim's nominal one), so the gate may keep
  // it: any status shows that tracking and solving run.
  ASSERT_TRUE(f.status.waitForCount(1, 30.0)) << "no calibration/status within 30 s";
  const CalibrationStatus first_status = *f.status.snapshot().back();
  std::printf("first calibration window: accepted %d (%s), %u frames, rms %.4f / %.4f px\n", first_status.accepted,
              first_status.reason.c_str(), first_status.frames_used, first_status.rms_left_px,
              first_status.rms_right_px);

  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.05;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  const ros::Time drift_time = ros::Time::now();
  std::printf("zoom 5 %% at %.2f\n", drift_time.toSec());

  // The next accepted calibration solved on frames taken after the zoom.
  ASSERT_TRUE(f.status.waitFor(
      [&](const auto& m) { return !m.empty() && m.back()->accepted && m.back()->header.stamp > drift_time; }, 20.0))
      << "no accepted calibration after the zoom";
  const CalibrationStatus after = *f.status.snapshot().back();
  std::printf("calibration after the zoom: epoch %u, %u frames, %u corners, rms %.4f / %.4f px, epipolar %.4f px, "
              "solve %.0f ms\n",
              after.epoch, after.frames_used, after.corners_used, after.rms_left_px, after.rms_right_px,
              after.epipolar_rms_px, after.solve_ms);
  const core::StereoRig before_zoom = stereoRig(*f.left.snapshot().front(), *f.right.snapshot().front());
  const Published zoomed = publishedAt(after.epoch);
  // The zoom really was a change: the calibration before it was 5 % off.
  EXPECT_NEAR(zoomed.truth.left.fx / before_zoom.left.fx, 1.05, 0.01);
  expectWithinBounds(zoomed.rig, zoomed.truth, zoomed.tf_left_from_right, "after the zoom");

  expectKnockRecalibratedOnRequest();
  if (HasFatalFailure()) return;
  expectDisparityNeverStopped();
}

int main(int argc, char** argv) {
  return test_support::runTestsWithFixture(argc, argv, "full_graph_test", 2, &fixture);
}
