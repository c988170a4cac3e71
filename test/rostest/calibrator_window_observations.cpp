// rostest: the OnlineCalibrator solving window observations (window_observations:=true,
// calibrator_window_observations.test). After a 5 % zoom, a whole light burst of per-frame
// observations is not solved; a window observation (one ground-truth frame of that burst, sent
// when its stamp is older than the stamp tolerance) is, as a window of one frame, and commits
// the zoom; the same window sent again is dropped with a warning; a later one is solved.
#include <gtest/gtest.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>

#include <cmath>
#include <functional>
#include <vector>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;
using test_support::waitUntil;
using sensor_msgs::CameraInfo;

namespace {


// The settled light-on frames of the first complete burst (a settled light-off frame after at
// least `min_lit` of them) whose frames are all stamped after `after`; empty while there is none.
std::vector<ros::Time> burstAfter(const std::vector<CalibrationMode::ConstPtr>& modes, const ros::Time& after,
                                  size_t min_lit) {
  std::vector<ros::Time> lit;
  for (const auto& m : modes) {
    if (m->header.stamp <= after || !m->settled) continue;
    if (m->light_on) {
      lit.push_back(m->header.stamp);
    } else if (lit.size() >= min_lit) {
      return lit;
    } else {
      lit.clear();
    }
  }
  return {};
}

// The ground-truth observation of the frame of `stamp` (null if none within 2 s).
StereoPatternObservation::ConstPtr observationAt(Collector<StereoPatternObservation>& truth, const ros::Time& stamp) {
  StereoPatternObservation::ConstPtr found;
  truth.waitFor(
      [&](const auto& m) {
        for (const auto& o : m)
          if (o->header.stamp == stamp) found = o;
        return found != nullptr;
      },
      2.0);
  return found;
}

// After `window` was solved (`solved`): the same window again, as it was and stamped as a newer
// one, and an older one, are dropped with a warning; a later one is solved.
void expectCopiesAndOlderDropped(ros::Publisher& window_pub, const StereoPatternObservation& window,
                                 const CalibrationStatus& solved, Collector<CalibrationMode>& modes,
                                 Collector<rosgraph_msgs::Log>& log, Collector<CalibrationStatus>& status) {
  // The same window again, as it was and stamped as a newer one: a copy, dropped with a warning.
  window_pub.publish(window);
  StereoPatternObservation copy = window;
  copy.header.stamp = modes.snapshot().back()->header.stamp;
  window_pub.publish(copy);
  EXPECT_TRUE(test_support::waitForLog(log, {"window observation dropped", "a copy of one seen before"}, 5.0));
  // Another window (two boards fewer per camera) stamped before the solved one: dropped too.
  StereoPatternObservation older = window;
  ASSERT_GE(older.left.size(), 5u);
  ASSERT_GE(older.right.size(), 5u);
  older.header.stamp = window.header.stamp - ros::Duration(0.5);
  for (int i = 0; i < 2; ++i) {
    older.left.pop_back();
    older.right.pop_back();
  }
  window_pub.publish(older);
  EXPECT_TRUE(test_support::waitForLog(log, {"window observation dropped", "not after the previous one"}, 5.0));
  // The control: a later window (a newer stamp, one board fewer per camera, so that its status
  // tells itself from the duplicate's by its corner count) is solved, and its status is the second
  // one (the duplicate made none: the calibrator solves in arrival order).
  StereoPatternObservation next = window;
  next.header.stamp = modes.snapshot().back()->header.stamp;
  ASSERT_GE(next.left.size(), 5u);
  ASSERT_GE(next.right.size(), 5u);
  next.left.pop_back();
  next.right.pop_back();
  window_pub.publish(next);
  ASSERT_TRUE(status.waitFor(
      [&](const auto& m) { return !m.empty() && m.back()->corners_used < solved.corners_used; }, 10.0))
      << "the later window observation was not solved";
  EXPECT_EQ(status.snapshot().size(), 2u) << "a copy or an older window was solved";
}

}  // namespace

TEST(CalibratorWindowObservations, SolvesEachWindowObservationAndNotThePerFrameWindows) {
  ros::NodeHandle nh;
  Collector<CalibrationMode> modes(nh, "calibration_mode", 1000);
  Collector<CameraInfo> left(nh, "left/camera_info", 1000);
  Collector<StereoPatternObservation> truth(nh, "ground_truth/observations", 1000);
  Collector<CalibrationStatus> status(nh, "calibration/status");
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 1000);
  ros::Publisher window_pub = nh.advertise<StereoPatternObservation>("calibration/window_observations", 10);
  ASSERT_TRUE(ros::service::waitForService("calibration/recalibrate", 20000));
  ASSERT_TRUE(waitUntil([&] { return window_pub.getNumSubscribers() > 0; }, 10.0))
      << "the calibrator does not subscribe to calibration/window_observations";
  ASSERT_TRUE(left.waitForCount(1, 20.0));
  const double fx_before = left.snapshot().back()->K[0];

  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.05;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  const ros::Time drift_time = ros::Time::now();

  // A whole burst after the zoom, with its per-frame observations: not solved (calibrator_auto
  // shows the same burst solved without window_observations). Its solve would follow the light-off
  // frame that ends it within a fraction of a second.
  std::vector<ros::Time> burst;
  ASSERT_TRUE(modes.waitFor([&](const auto& m) { return !(burst = burstAfter(m, drift_time, 8)).empty(); }, 10.0))
      << "no burst of 8 settled light-on frames after the zoom";
  EXPECT_FALSE(status.waitForCount(1, 1.5)) << "a window of per-frame observations was solved: "
                                            << status.snapshot().front()->reason;

  // A window observation: the ground truth of the burst's last frame, sent once frames more
  // than the stamp tolerance (2 s) newer exist (the stamp guard would drop it; a window
  // observation passes it).
  const StereoPatternObservation::ConstPtr window = observationAt(truth, burst.back());
  ASSERT_TRUE(window) << "no ground-truth observation of frame " << burst.back();
  ASSERT_TRUE(modes.waitFor(
      [&](const auto& m) { return !m.empty() && (m.back()->header.stamp - window->header.stamp).toSec() > 2.5; },
      5.0));
  window_pub.publish(*window);
  ASSERT_TRUE(status.waitForCount(1, 10.0)) << "the window observation was not solved";
  const CalibrationStatus solved = *status.snapshot().front();
  std::printf("window observation: accepted %d (%s), %u frames, %u corners, rms %.4f / %.4f px\n", solved.accepted,
              solved.reason.c_str(), solved.frames_used, solved.corners_used, solved.rms_left_px,
              solved.rms_right_px);
  EXPECT_TRUE(solved.accepted) << solved.reason;
  EXPECT_EQ(solved.frames_used, 1u) << "min_frames (8) does not apply to a window observation";
  ASSERT_TRUE(left.waitFor([&](const auto& m) { return std::abs(m.back()->K[0] / fx_before - 1.05) < 1e-3; }, 5.0))
      << "the zoom was not committed: fx " << left.snapshot().back()->K[0] << " was " << fx_before;

  expectCopiesAndOlderDropped(window_pub, *window, solved, modes, log, status);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibrator_window_observations_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
