// WindowTracker on the moving drive_photo scenario (the head drives through a photographed
// corridor, people cross; real-head optics): windows of 10 light-on frames at 30 fps between a
// light-off frame before and one after, with a zoom step and a knock of the right camera between
// windows. Every corner of the window's one observation is compared with the simulator's true
// corner of the same id; the per-frame tracker (raw images, boards aligned whole) on the same
// frames is the reference: the part of its error that its window's frames share (their mean
// error per corner) is what a window of per-frame observations gives the calibrator.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"
#include "embedded_calibration_stereo/test_support/corner_score.h"
#include "embedded_calibration_stereo/test_support/rendered_window.h"
#include "embedded_calibration_stereo/test_support/sim_prior.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kConfig = std::string(ECS_SOURCE_DIR) + "/config/drive_photo.yaml";
constexpr double kFps = 30.0;
constexpr int kLitFrames = 10;

TEST(WindowTracker, TracksMovingWindowsAgainstTheTruth) {
  SimRig sim(loadSimRigConfig(kConfig));
  const PatternPrior prior = teachSimPrior(sim, 1.0);
  WindowTracker window_tracker(prior, TrackerOptions(), WindowTrackerOptions());
  PatternTracker frame_tracker(prior, TrackerOptions());
  CornerScore score;
  double shared_sq = 0;
  int windows = 0;
  for (int w = 0; w < 3; ++w) {
    const int j = 45 + 60 * w;  // the light-off frame before the window
    if (w == 1) {
      DriftRequest zoom;
      zoom.focal_scale = 1.02;
      ASSERT_TRUE(sim.setDrift(zoom, (j - 5) / kFps).empty());
    } else if (w == 2) {
      DriftRequest knock;
      knock.knock_rotation_deg = Eigen::Vector3d(0.2, -0.25, 0.1);
      ASSERT_TRUE(sim.setDrift(knock, (j - 5) / kFps).empty());
    }
    const RenderedWindow window = renderWindow(sim, j, kLitFrames);
    WindowCornerErrors shared;
    for (int k = 1; k <= kLitFrames; ++k) {
      const SimFrame& lit = window.lit[k - 1];
      const StereoObservation per_frame = frame_tracker.trackStereo(lit.left, lit.right, (j + k) / kFps);
      shared.add(0, per_frame.left, lit.observations.left);
      shared.add(1, per_frame.right, lit.observations.right);
    }
    const SimFrame& lit = window.lit.back();
    const WindowTrack track = window_tracker.track(window.left, window.right, (j + kLitFrames) / kFps);
    CornerScore window_score;
    window_score.add(track.observation, lit.observations);
    score.add(track.observation, lit.observations);
    std::printf("  window %d: %s (%d saddle fits failed); per-frame tracker, error shared by the window's "
                "frames: %.3f px RMS\n",
                w, window_score.str().c_str(), track.saddle_failures, shared.sharedRms());
    shared_sq += shared.sharedRms() * shared.sharedRms();
    ++windows;
  }
  const double shared_rms = std::sqrt(shared_sq / windows);
  std::printf("  all windows: %s; per-frame tracker's shared error %.3f px\n", score.str().c_str(), shared_rms);
  EXPECT_GE(score.foundFraction(), 0.99) << score.str();
  EXPECT_EQ(score.wrong, 0u) << score.str();
  EXPECT_LE(score.rms(), 0.03) << score.str();
  // The point of combining the window: less than what its per-frame observations share.
  EXPECT_LT(score.rms(), 0.8 * shared_rms) << score.str();
}

TEST(WindowTracker, RefusesAWindowItCannotLearnFrom) {
  SimRig sim(loadSimRigConfig(kConfig));
  const PatternPrior prior = teachSimPrior(sim, 1.0);
  WindowTracker tracker(prior, TrackerOptions(), WindowTrackerOptions());
  const SimFrame lit = sim.render(2.0, 1.0, 7), off = sim.render(2.1, 0.0, 8);
  WindowFrames no_off{{}, {}, {lit.left, lit.left, lit.left}};
  WindowFrames ok_right{{off.right}, {}, {lit.right, lit.right, lit.right}};
  EXPECT_THROW(tracker.track(no_off, ok_right, 2.0), std::invalid_argument);
  WindowFrames flash{{off.left}, {}, {lit.left}};  // a verification flash: one light-on frame
  EXPECT_THROW(tracker.track(flash, ok_right, 2.0), std::invalid_argument);
  cv::Mat small;
  cv::resize(off.left, small, cv::Size(), 0.5, 0.5);
  WindowFrames mixed{{small}, {}, {lit.left, lit.left, lit.left}};
  EXPECT_THROW(tracker.track(mixed, ok_right, 2.0), std::invalid_argument);
  WindowTrackerOptions bad;
  bad.min_light_on_frames = 0;
  EXPECT_THROW(WindowTracker(prior, TrackerOptions(), bad), std::exception);
  bad = WindowTrackerOptions();
  bad.max_board_motion_px = 0.0;
  EXPECT_THROW(WindowTracker(prior, TrackerOptions(), bad), std::exception);
}

// The boards move during a burst only when the camera does. A knock of the right camera just
// before a burst's first light-on frame: the window's corners are those of the knocked rig
// (against the truth), and its first and last light-on frames agree. Knocked after the sixth of
// its ten frames, or zoomed by 5 % there (which the scene's epipolar geometry hardly shows), the
// window carries nothing, and is not learned: learned whole, it would mix the two rigs.
TEST(WindowTracker, DropsAWindowWhoseBoardsMovedDuringTheBurst) {
  const SimRigConfig config = loadSimRigConfig(kConfig);
  struct Case {
    const char* name;
    int after;  // light-on frames before the event
    bool zoom;
  };
  for (const Case& event : {Case{"knock before the burst", 0, false}, Case{"knock within the burst", 6, false},
                            Case{"zoom within the burst", 6, true}}) {
    SimRig sim(config);
    const PatternPrior prior = teachSimPrior(sim, 1.0);
    WindowTracker tracker(prior, TrackerOptions(), WindowTrackerOptions(), config.rig);
    const int j = 45;  // the light-off frame before the window
    const RenderedWindow window = renderWindow(sim, j, kLitFrames, [&](int k) {
      if (k != event.after + 1) return;
      DriftRequest drift;
      if (event.zoom)
        drift.focal_scale = 1.05;
      else
        drift.knock_rotation_deg = Eigen::Vector3d(0.2, -0.25, 0.1);
      ASSERT_TRUE(sim.setDrift(drift, (j + k - 0.5) / kFps).empty());
    });
    const SimFrame& lit = window.lit.back();
    const WindowTrack track = tracker.track(window.left, window.right, (j + kLitFrames) / kFps);
    CornerScore score;
    score.add(track.observation, lit.observations);
    std::printf("  %s: scene sides %s (%.2f px), a board moved %.2f px; %s\n", event.name,
                !track.scene_sides.compared ? "not compared" : track.scene_sides.consistent ? "consistent" : "changed",
                track.scene_sides.change_px, track.board_motion_px, score.str().c_str());
    ASSERT_TRUE(track.board_motion_checked) << event.name;
    if (event.after == 0) {
      EXPECT_FALSE(track.scene_sides.consistent);
      EXPECT_FALSE(track.boards_moved);
      EXPECT_LE(track.board_motion_px, 0.25);
      EXPECT_GE(score.foundFraction(), 0.99) << score.str();
      EXPECT_LE(score.rms(), 0.03) << score.str();
      EXPECT_TRUE(track.observation.scene.empty());
    } else {
      EXPECT_TRUE(track.boards_moved) << event.name;
      EXPECT_GE(track.board_motion_px, 2.0) << event.name;
      EXPECT_TRUE(track.observation.left.empty() && track.observation.right.empty()) << event.name;
      EXPECT_TRUE(track.device[0].empty() && track.device[1].empty()) << event.name;
    }
  }
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
