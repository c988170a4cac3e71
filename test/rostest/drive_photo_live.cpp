// rostest: live calibration on the moving drive_photo scenario (drive_photo_live.test).
// Records every frame's calibration_mode and camera_info (published and the simulator's truth)
// from the start. Once a first window has been solved: a 5 % zoom and a thermal rotation of the
// right camera start (sim/set_drift); after the next solved window the rotation stops where it
// got to and the right camera is knocked. The tracker tracks each light burst as a whole
// (window_tracking) and publishes its observation seconds after the burst, so "the next window"
// is the first window observation whose burst, from the light-off frame before it, was taken
// after the drift was set, and its solve the status that follows it. After that window (which
// commits, or confirms a correction that a burst lit wholly after the knock committed before it)
// the calibration in force is judged against the truth of a frame it is in force for: the
// accuracy targets for depth (core/calibration/stereo_accuracy.h: vertical misalignment and
// disparity bias RMS over the field of view, depth error at 10 m) and fx, baseline, printed, and
// the test's bounds below. Every commit of the
// run (each change of calibration epoch) is compared with the calibration it replaced against
// the same truth: none may be worse.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>

#include <cmath>
#include <cstdio>
#include <set>
#include <string>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/test_support/corner_score.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::kInForceConfirmedReason;
using embedded_calibration_stereo::SetRigDrift;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;
using sensor_msgs::CameraInfo;

namespace {

// The accuracy targets for depth after the drift (px RMS over the field of view, %, relative):
// printed, met or not. The window after the knock is one window observation of a 30-frame burst
// with its scene correspondences and what the earlier windows taught; its own predicted bias is
// about 0.04 px, and the runs measured met every target (docs/figures.md). The test holds the
// calibration to the target for misalignment and to about twice the others: a run is a sample
// of one window, and its bias a draw from that prediction (on a slower 2-core machine, 1 run in
// 6 drew the right camera's fx 0.054 % off, against the 0.05 % target).
constexpr double kTargetMisalignmentPx = 0.05, kTargetBiasPx = 0.05, kTargetDepthError10mPct = 0.7,
                 kTargetFocalRel = 0.0005, kTargetBaselineRel = 0.001;
constexpr double kMisalignmentPx = 0.05, kBiasPx = 0.12, kDepthError10mPct = 1.8, kFocalRel = 0.001,
                 kBaselineRel = 0.0025;
// A commit is worse than the calibration it replaced when its combined error against the same
// truth, hypot(misalignment RMS, bias RMS), is larger by more than this (px).
constexpr double kWorsePx = 0.01;
double combined(const core::StereoAccuracy& a) { return std::hypot(a.misalignment_px.rms, a.disparity_bias_px.rms); }
constexpr double kThermalDegPerS = 0.03;
constexpr double kFps = 30.0;  // the driver's fps (drive_photo_live.test)
// A burst starts within a period of the drift, may be dropped while the tracker's worker is busy
// with the one before, and is published once tracked.
constexpr double kWindowTimeoutS = 25.0;

struct Fixture {
  ros::NodeHandle nh;
  Collector<CalibrationMode> modes{nh, "calibration_mode", 1000};
  Collector<CameraInfo> left{nh, "left/camera_info", 1000}, right{nh, "right/camera_info", 1000};
  Collector<CameraInfo> truth_left{nh, "ground_truth/left/camera_info", 1000};
  Collector<CameraInfo> truth_right{nh, "ground_truth/right/camera_info", 1000};
  Collector<CalibrationStatus> status{nh, "calibration/status"};
  Collector<StereoPatternObservation> windows{nh, "calibration/window_observations", 1000};
  // The simulator's true corners of every frame: each window observation against its last frame's.
  Collector<StereoPatternObservation> truth_corners{nh, "ground_truth/observations", 1000};
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics{nh, "/diagnostics", 1000};
};

Fixture* fixture = nullptr;

CameraInfo::ConstPtr byStamp(const std::vector<CameraInfo::ConstPtr>& messages, const ros::Time& stamp) {
  for (auto it = messages.rbegin(); it != messages.rend(); ++it)
    if ((*it)->header.stamp == stamp) return *it;
  return nullptr;
}

// The published calibration and the truth of one frame.
struct Frame {
  bool ok = false;
  core::StereoRig published, truth;
};

Frame frameAt(const ros::Time& stamp) {
  Fixture& f = *fixture;
  Frame out;
  const auto l = byStamp(f.left.snapshot(), stamp), r = byStamp(f.right.snapshot(), stamp);
  const auto tl = byStamp(f.truth_left.snapshot(), stamp), tr = byStamp(f.truth_right.snapshot(), stamp);
  if (!(l && r && tl && tr)) return out;
  std::string error;
  out.ok = embedded_calibration_stereo::fromStereoCameraInfo(*l, *r, &out.published, &error) &&
           embedded_calibration_stereo::fromStereoCameraInfo(*tl, *tr, &out.truth, &error);
  EXPECT_TRUE(out.ok) << error;
  return out;
}

core::StereoAccuracy accuracy(const core::StereoRig& estimate, const core::StereoRig& truth) {
  return core::evaluateStereoAccuracy(estimate, truth);  // the calibrator's rectification (alpha 0)
}

void print(const char* what, const core::StereoAccuracy& a) {
  std::printf("%s: misalignment %.4f px RMS (max %.4f), disparity bias %.4f px RMS (max %.4f), depth error "
              "%.3f / %.3f / %.3f / %.3f %% at 1 / 2 / 5 / 10 m\n",
              what, a.misalignment_px.rms, a.misalignment_px.max, a.disparity_bias_px.rms, a.disparity_bias_px.max,
              a.at_depth[0].depth_error_pct.rms, a.at_depth[1].depth_error_pct.rms,
              a.at_depth[2].depth_error_pct.rms, a.at_depth[3].depth_error_pct.rms);
}

// Waits for the first status stamped after `after`; null on timeout.
CalibrationStatus::ConstPtr nextStatus(const ros::Time& after, double timeout_s) {
  Fixture& f = *fixture;
  CalibrationStatus::ConstPtr found;
  f.status.waitFor(
      [&](const auto& m) {
        for (const auto& s : m)
          if (s->header.stamp > after) {
            found = s;
            return true;
          }
        return false;
      },
      timeout_s);
  return found;
}

// The stamp of the last settled light-off frame before the burst whose last light-on frame is
// `last_light_on` (the frame the window tracker starts from); zero when not recorded.
ros::Time lightOffBefore(const ros::Time& last_light_on) {
  const auto modes = fixture->modes.snapshot();
  bool in_burst = false;
  for (auto it = modes.rbegin(); it != modes.rend(); ++it) {
    if ((*it)->header.stamp == last_light_on) in_burst = true;
    if (in_burst && !(*it)->light_on && (*it)->settled) return (*it)->header.stamp;
  }
  return ros::Time();
}

// Waits for the first window observation whose whole burst was taken after `after`; returns
// when it arrived (zero on timeout). The status of its solve is the next one after that.
ros::Time windowAfter(const ros::Time& after, double timeout_s) {
  ros::Time arrived;
  fixture->windows.waitFor(
      [&](const auto& m) {
        for (const auto& w : m)
          if (lightOffBefore(w->header.stamp) > after) {
            arrived = ros::Time::now();
            return true;
          }
        return false;
      },
      timeout_s);
  return arrived;
}

bool setDrift(const SetRigDrift::Request& request) {
  SetRigDrift srv;
  srv.request = request;
  if (!ros::service::call("sim/set_drift", srv)) return false;
  EXPECT_TRUE(srv.response.success) << srv.response.message;
  return srv.response.success;
}

// The stamp of the frame whose calibration is judged: the first of `epoch` (when `confirmed`, the
// newest of it: the epoch has been in force since an earlier commit).
ros::Time committedStamp(const std::vector<CalibrationMode::ConstPtr>& seen, uint32_t epoch, bool confirmed) {
  if (confirmed) {
    for (auto it = seen.rbegin() + 3; it < seen.rend(); ++it)  // the newest frames' camera_info may be on the way
      if ((*it)->calibration_epoch == epoch) return (*it)->header.stamp;
    return ros::Time();
  }
  for (const auto& m : seen)
    if (m->calibration_epoch == epoch) return m->header.stamp;
  return ros::Time();
}

// Where the error of `committed` sits: principal points, the stereo rotation, the translation's
// direction.
void printErrorParts(const Frame& committed) {
  const Eigen::AngleAxisd turn(committed.published.right_from_left.linear() *
                               committed.truth.right_from_left.linear().transpose());
  const Eigen::Vector3d turn_deg = turn.angle() * turn.axis() * 180.0 / M_PI;
  const Eigen::Vector3d t_est = committed.published.right_from_left.translation().normalized(),
                        t_true = committed.truth.right_from_left.translation().normalized();
  std::printf("cx %+.3f / %+.3f px, cy %+.3f / %+.3f px, rotation error (%+.4f, %+.4f, %+.4f) deg, translation "
              "direction %.4f deg\n",
              committed.published.left.cx - committed.truth.left.cx,
              committed.published.right.cx - committed.truth.right.cx,
              committed.published.left.cy - committed.truth.left.cy,
              committed.published.right.cy - committed.truth.right.cy, turn_deg.x(), turn_deg.y(), turn_deg.z(),
              std::acos(std::min(1.0, t_est.dot(t_true))) * 180.0 / M_PI);
}

// The calibration in force after the drift against the truth of its frame.
void expectCommittedAccurate(const Frame& committed) {
  Fixture& f = *fixture;
  // The drift really happened: the calibration before it is far off.
  EXPECT_NEAR(committed.truth.left.fx / f.truth_left.snapshot().front()->K[0], 1.05, 0.01);
  const core::StereoAccuracy a = accuracy(committed.published, committed.truth);
  print("after zoom, thermal rotation and knock", a);
  const double fx_left = std::abs(committed.published.left.fx / committed.truth.left.fx - 1);
  const double fx_right = std::abs(committed.published.right.fx / committed.truth.right.fx - 1);
  const double baseline = std::abs(committed.published.baseline() / committed.truth.baseline() - 1);
  std::printf("fx %.4f / %.4f %%, baseline %.4f %%\n", 100 * fx_left, 100 * fx_right, 100 * baseline);
  printErrorParts(committed);
  const bool targets_met = a.misalignment_px.rms <= kTargetMisalignmentPx && a.disparity_bias_px.rms <= kTargetBiasPx &&
                           a.at_depth[3].depth_error_pct.rms <= kTargetDepthError10mPct &&
                           std::max(fx_left, fx_right) <= kTargetFocalRel && baseline <= kTargetBaselineRel;
  std::printf("accuracy targets for depth (misalignment and bias %.2f px, depth error at 10 m %.1f %%, fx %.2f %%, "
              "baseline %.1f %%): %s\n",
              kTargetBiasPx, kTargetDepthError10mPct, 100 * kTargetFocalRel, 100 * kTargetBaselineRel,
              targets_met ? "met" : "NOT met");
  EXPECT_LE(a.misalignment_px.rms, kMisalignmentPx);
  EXPECT_LE(a.disparity_bias_px.rms, kBiasPx);
  EXPECT_LE(a.at_depth[3].depth_error_pct.rms, kDepthError10mPct);
  EXPECT_LE(fx_left, kFocalRel);
  EXPECT_LE(fx_right, kFocalRel);
  EXPECT_LE(baseline, kBaselineRel);
}

// Every commit against the calibration it replaced, on the truth of the first frame of the new
// epoch (the replaced one is the camera_info of the frame before it).
void expectNoCommitWorse(const std::vector<CalibrationMode::ConstPtr>& modes) {
  int commits = 0;
  for (size_t i = 1; i < modes.size(); ++i) {
    if (modes[i]->calibration_epoch == modes[i - 1]->calibration_epoch) continue;
    const Frame now = frameAt(modes[i]->header.stamp), before = frameAt(modes[i - 1]->header.stamp);
    if (!now.ok || !before.ok) continue;  // the last frames' camera_info may still be on the way
    ++commits;
    const core::StereoAccuracy new_a = accuracy(now.published, now.truth);
    const core::StereoAccuracy old_a = accuracy(before.published, now.truth);
    std::printf("commit at %.3f (epoch %u -> %u):\n", modes[i]->header.stamp.toSec(), modes[i - 1]->calibration_epoch,
                modes[i]->calibration_epoch);
    print("  replaced", old_a);
    print("  new     ", new_a);
    EXPECT_LE(combined(new_a), combined(old_a) + kWorsePx) << "commit at " << modes[i]->header.stamp;
  }
  EXPECT_GE(commits, 2) << "the zoom and the knock should each have been committed";
}

// How many bursts the window tracker kept up with (the others were dropped, its worker busy), and
// its windows against the truth.
void printTracking(const std::vector<CalibrationMode::ConstPtr>& modes) {
  Fixture& f = *fixture;
  int bursts = 0, lit = 0;
  for (const auto& m : modes) {
    if (m->light_on && m->settled) ++lit;
    if (!m->light_on && m->settled) {
      bursts += lit >= 3;
      lit = 0;
    }
  }
  const auto windows = f.windows.snapshot();
  std::printf("window observations: %zu for %d bursts of >= 3 settled light-on frames\n", windows.size(), bursts);
  const auto truths = f.truth_corners.snapshot();
  for (const auto& w : windows)
    for (const auto& t : truths)
      if (t->header.stamp == w->header.stamp) {
        const core::StereoObservation tracked = embedded_calibration_stereo::fromMsg(*w),
                                     truth = embedded_calibration_stereo::fromMsg(*t);
        core::CornerScore left, right;
        left.add(tracked.left, truth.left);
        right.add(tracked.right, truth.right);
        std::printf("  window at %.3f s against the truth: left %s, right %s; %zu scene correspondences\n",
                    w->header.stamp.toSec(), left.str().c_str(), right.str().c_str(), w->scene.size());
      }
  std::set<std::string> lines;  // the tracker's word on each burst (diagnostics, once a second)
  for (const auto& array : f.diagnostics.snapshot())
    for (const auto& status : array->status)
      for (const auto& kv : status.values)
        if (kv.key == "window tracking" && lines.insert(kv.value).second) std::printf("  %s\n", kv.value.c_str());
}

}  // namespace

TEST(DrivePhotoLive, ZoomThermalAndKnockAreRecalibratedAndNoCommitIsWorse) {
  Fixture& f = *fixture;
  ASSERT_TRUE(f.modes.waitForCount(5, 30.0)) << "no frames from the driver";
  // The tracker teaches itself at the first burst; a window solved follows.
  const CalibrationStatus::ConstPtr first = nextStatus(ros::Time(0), 30.0);
  ASSERT_TRUE(first) << "no calibration/status within 30 s";
  std::printf("first window: accepted %d (%s), %u frames, rms %.4f / %.4f px\n", first->accepted,
              first->reason.c_str(), first->frames_used, first->rms_left_px, first->rms_right_px);

  // Statuses arrive after their window: the light is off, the next window is a period away.
  SetRigDrift::Request zoom;
  zoom.focal_scale = 1.05;
  zoom.thermal_rate_deg_per_s = kThermalDegPerS;
  ASSERT_TRUE(setDrift(zoom));
  const ros::Time zoom_time = ros::Time::now();
  const ros::Time zoom_window = windowAfter(zoom_time, kWindowTimeoutS);
  ASSERT_FALSE(zoom_window.isZero()) << "no window tracked after the zoom";
  const CalibrationStatus::ConstPtr during = nextStatus(zoom_window, 5.0);
  ASSERT_TRUE(during) << "no window solved after the zoom";
  std::printf("window during the thermal rotation: accepted %d (%s)\n", during->accepted, during->reason.c_str());

  // The rotation stops where it got to (held as a fixed rotation), and a knock. The simulator's
  // time is the frame index over fps, so the rotation ran for the frames rendered since the zoom.
  int frames_since_zoom = 0;
  for (const auto& m : f.modes.snapshot()) frames_since_zoom += m->header.stamp > zoom_time;
  SetRigDrift::Request knock;
  knock.focal_scale = 1.05;
  knock.right_rotation_deg = {0.0, kThermalDegPerS * frames_since_zoom / kFps, 0.0};
  knock.knock_rotation_deg = {0.04, -0.03, 0.05};
  knock.knock_translation_m = {0.0008, 0.0003, -0.0005};
  ASSERT_TRUE(setDrift(knock));
  const ros::Time knock_time = ros::Time::now();
  const ros::Time knock_window = windowAfter(knock_time, kWindowTimeoutS);
  ASSERT_FALSE(knock_window.isZero()) << "no window tracked after the knock";
  const CalibrationStatus::ConstPtr after = nextStatus(knock_window, 5.0);
  ASSERT_TRUE(after) << "no window solved after the knock";
  std::printf("window after the knock: accepted %d (%s), epoch %u, %u frames, %u corners, rms %.4f / %.4f px, "
              "predicted misalignment %.4f px, bias %.4f px, depth error at 10 m %.3f %%\n",
              after->accepted, after->reason.c_str(), after->epoch, after->frames_used, after->corners_used,
              after->rms_left_px, after->rms_right_px, after->predicted_misalignment_rms_px,
              after->predicted_disparity_bias_rms_px, after->predicted_depth_error_pct[3]);
  // That window commits, or confirms the calibration in force: a burst whose light-off frame
  // before it preceded the knock but whose light-on frames all followed it may have committed
  // the correction already. Either way the calibration in force after it is judged.
  const bool confirmed = !after->accepted && after->reason.rfind(kInForceConfirmedReason, 0) == 0;
  ASSERT_TRUE(after->accepted || confirmed) << after->reason;

  // The calibration of the first frame of the committed epoch against that frame's truth (when
  // confirmed: of the newest frame, the epoch in force since an earlier commit).
  ASSERT_TRUE(f.modes.waitFor(
      [&](const auto& m) { return !m.empty() && m.back()->calibration_epoch >= after->epoch; }, 5.0));
  ASSERT_TRUE(f.modes.waitForCount(f.modes.snapshot().size() + 3, 5.0));  // its camera_info arrived
  const ros::Time committed_stamp = committedStamp(f.modes.snapshot(), after->epoch, confirmed);
  const Frame committed = frameAt(committed_stamp);
  ASSERT_TRUE(committed.ok) << "no camera_info of frame " << committed_stamp;
  expectCommittedAccurate(committed);
  const auto modes = f.modes.snapshot();
  expectNoCommitWorse(modes);
  printTracking(modes);
}

int main(int argc, char** argv) {
  return test_support::runTestsWithFixture(argc, argv, "drive_photo_live_test", 2, &fixture);
}
