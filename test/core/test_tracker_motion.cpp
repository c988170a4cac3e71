// PatternTracker in a moving world (config/drive_photo.yaml, config/handheld_photo.yaml): the head
// moves through photographed scenes with moving objects, so the light-off frame the tracker may
// hold shows a scene that has moved since (a stale background), or there is none. Taught once
// from a light-on/light-off pair, then tracked over windows of light-on frames 3-10 frames after
// their light-off frame, with a zoom step and a knock between windows (the boards move in the
// image; a tracker that repeated its last corners would fail). The scenarios carry the real-head
// optics. Every reported corner is compared with the simulator's true corner of the same
// (board id, corner id).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>

#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/test_support/corner_score.h"
#include "embedded_calibration_stereo/test_support/sim_prior.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kConfigDir = std::string(ECS_SOURCE_DIR) + "/config/";
constexpr double kFps = 30.0;

using Score = CornerScore;

enum class Background { kStale, kNone };

struct MotionRun {
  Score score;
  int stale_frames = 0;  // frames where the tracker found its background stale (both cameras)
  int tracked_frames = 0;
};

// Windows of light-on frames: the light-off frame at frame j, light-on frames j+3 .. j+10 (the
// tracker keeps the light-off frame as its background in kStale mode). Between windows the rig
// drifts: a zoom step, then a knock of the right camera.
MotionRun runWindows(SimRig* sim, Background mode, int first_frame) {
  PatternTracker tracker(teachSimPrior(*sim, first_frame / kFps), TrackerOptions());
  MotionRun run;
  const int kWindows = 3;
  const int kOnFrames[] = {3, 6, 10};
  for (int w = 0; w < kWindows; ++w) {
    const int j = first_frame + 15 + 25 * w;
    if (w == 1) {
      DriftRequest zoom;
      zoom.focal_scale = 1.02;
      EXPECT_TRUE(sim->setDrift(zoom, (j - 5) / kFps).empty());
    } else if (w == 2) {
      DriftRequest knock;
      knock.knock_rotation_deg = Eigen::Vector3d(0.2, -0.25, 0.1);
      EXPECT_TRUE(sim->setDrift(knock, (j - 5) / kFps).empty());
    }
    if (mode == Background::kStale) {
      const SimFrame off = sim->render(j / kFps, 0.0, 500 + j);
      tracker.setBackground(off.left, off.right);
    }
    for (int d : kOnFrames) {
      const double t = (j + d) / kFps;
      const SimFrame f = sim->render(t, 1.0, 1000 + j + d);
      run.score.add(tracker.trackStereo(f.left, f.right, t), f.observations);
      run.stale_frames += tracker.camera(0).lastBackgroundStale() && tracker.camera(1).lastBackgroundStale();
      ++run.tracked_frames;
    }
  }
  return run;
}

// RMS bound against the truth: the target, 0.05 px, in both scenarios (the hand-held room's
// brick walls, with mortar lines along the boards' edges, are the harder one).
constexpr double kRmsBoundPx = 0.05;

void expectAccurate(const std::string& scenario, Background mode, int first_frame) {
  SimRig sim(loadSimRigConfig(kConfigDir + scenario + ".yaml"));
  const MotionRun run = runWindows(&sim, mode, first_frame);
  ASSERT_GT(run.score.truth, 0u);
  std::printf("  %s, %s background: %s (stale detected in %d/%d frames)\n", scenario.c_str(),
              mode == Background::kStale ? "stale (3-10 frames old)" : "no", run.score.str().c_str(),
              run.stale_frames, run.tracked_frames);
  EXPECT_GE(run.score.foundFraction(), 0.99) << run.score.str();
  EXPECT_LE(run.score.rms(), kRmsBoundPx) << run.score.str();
  EXPECT_EQ(run.score.wrong, 0u) << run.score.str();
  if (mode == Background::kStale) {
    EXPECT_EQ(run.stale_frames, run.tracked_frames);
  }
}

TEST(TrackerMotion, DrivePhotoStaleBackground) { expectAccurate("drive_photo", Background::kStale, 30); }
TEST(TrackerMotion, DrivePhotoNoBackground) { expectAccurate("drive_photo", Background::kNone, 30); }
TEST(TrackerMotion, HandheldPhotoStaleBackground) { expectAccurate("handheld_photo", Background::kStale, 30); }
TEST(TrackerMotion, HandheldPhotoNoBackground) { expectAccurate("handheld_photo", Background::kNone, 30); }

// A dim device (reflectance 0.25) over the photographed corridor, no background, with the
// scenario's real-head optics (half-mirror ghost, vignetting, auto-exposure, shot and read noise):
// the pattern's contrast is half that of the scene's texture.
TEST(TrackerMotion, DrivePhotoDimDeviceNoBackground) {
  SimRigConfig config = loadSimRigConfig(kConfigDir + "drive_photo.yaml");
  config.optics.transmittance = 0.75;
  config.optics.reflectance = 0.25;
  SimRig sim(config);
  const MotionRun run = runWindows(&sim, Background::kNone, 30);
  std::printf("  drive_photo t=0.75 r=0.25, no background: %s\n", run.score.str().c_str());
  ASSERT_GT(run.score.truth, 0u);
  EXPECT_GE(run.score.foundFraction(), 0.95) << run.score.str();
  EXPECT_LE(run.score.rms(), 0.1) << run.score.str();
  EXPECT_EQ(run.score.wrong, 0u) << run.score.str();
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
