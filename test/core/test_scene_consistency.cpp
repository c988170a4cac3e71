// The scene matches of the light-off frames before a burst against those after it
// (scene_consistency.h), synthetic on the drive_photo head with the matcher's noise and wrong
// matches, measured against a guide calibration that is not the truth (the nominal one after a
// zoom and a turn, as a head's guide may be):
//  - the same rig on both sides, window after window: consistent, the change within its noise;
//  - the demo's knock between the sides: a change of the size the truth shows (the true
//    vertical misalignment of one rig against the other, stereo_accuracy.h, an independent
//    measure), flagged;
//  - a turn too small to matter is not flagged; too few matches are not compared; bad options.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/scene_consistency.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"
#include "embedded_calibration_stereo/test_support/synthetic_window.h"

namespace embedded_calibration_stereo::core {
namespace {

constexpr double kSceneNoisePx = 0.06;  // the matcher's spread on drive_photo (test_scene_constraints)
constexpr int kMatchesPerSide = 120;    // about half a window's matches

// The rig after the demo's knock (0.07 deg and 1 mm), scaled.
StereoRig knocked(const StereoRig& rig, double scale) {
  Eigen::Isometry3d knock = Eigen::Isometry3d::Identity();
  const Eigen::Vector3d rotation_rad = Eigen::Vector3d(0.04, -0.03, 0.05) * scale * M_PI / 180.0;
  knock.linear() = Eigen::AngleAxisd(rotation_rad.norm(), rotation_rad.normalized()).toRotationMatrix();
  knock.translation() = Eigen::Vector3d(0.0008, 0.0003, -0.0005) * scale;
  StereoRig r = rig;
  r.right_from_left = knock * rig.right_from_left;
  return r;
}

struct Sides {
  std::vector<SceneMatch> before, after;
};

Sides sides(const StereoRig& before, const StereoRig& after, int seed) {
  return {generateSyntheticSceneMatches(before, kMatchesPerSide, kSceneNoisePx, 0.05, 3000 + seed),
          generateSyntheticSceneMatches(after, kMatchesPerSide, kSceneNoisePx, 0.05, 4000 + seed)};
}

class SceneConsistencyTest : public ::testing::Test {
 protected:
  const ScenarioHead head = loadScenarioHead(ECS_SOURCE_DIR "/config/drive_photo.yaml");
  const StereoRig guide = driftedRig(head.truth, 1.05, Eigen::Vector3d(0.05, 0.1, -0.05));
};

TEST_F(SceneConsistencyTest, TheSameRigOnBothSidesIsConsistent) {
  double worst = 0.0;
  for (int seed = 0; seed < 20; ++seed) {
    const Sides s = sides(head.truth, head.truth, seed);
    const SceneConsistency c = compareSceneSides(s.before, s.after, guide);
    ASSERT_TRUE(c.compared);
    EXPECT_TRUE(c.consistent) << "seed " << seed << ": " << c.change_px << " px";
    // The change is noise: about its own standard deviation (six coefficients' worth).
    EXPECT_LT(c.change_px, 4.0 * c.change_stddev_px) << "seed " << seed;
    worst = std::max(worst, c.change_px);
  }
  std::printf("[ figures  ] the same rig, 20 windows: change at most %.4f px\n", worst);
  EXPECT_LT(worst, 0.5 * SceneConsistencyOptions().max_change_px);
}

TEST_F(SceneConsistencyTest, AKnockBetweenTheSidesIsFlaggedAtItsSize) {
  for (int seed = 0; seed < 5; ++seed) {
    const StereoRig after = knocked(head.truth, 1.0);
    const Sides s = sides(head.truth, after, seed);
    const SceneConsistency c = compareSceneSides(s.before, s.after, guide);
    // The truth: how far one rig's rows lie from the other's over the field, in the rectified
    // images (not the Sampson distance: that splits the offset between the two points).
    const double misalignment = evaluateStereoAccuracy(after, head.truth).misalignment_px.rms;
    std::printf("[ figures  ] knock, window %d: change %.3f px (+- %.4f), true misalignment %.3f px\n", seed,
                c.change_px, c.change_stddev_px, misalignment);
    ASSERT_TRUE(c.compared);
    EXPECT_FALSE(c.consistent);
    EXPECT_NEAR(c.change_px * M_SQRT2, misalignment, 0.3 * misalignment);
  }
}

TEST_F(SceneConsistencyTest, ATurnTooSmallToMatterIsNotFlagged) {
  // A twentieth of the knock: a few hundredths of a pixel.
  const StereoRig after = knocked(head.truth, 0.05);
  const Sides s = sides(head.truth, after, 7);
  const SceneConsistency c = compareSceneSides(s.before, s.after, guide);
  EXPECT_TRUE(c.compared);
  EXPECT_TRUE(c.consistent) << c.change_px << " px";
  EXPECT_LT(c.change_px, SceneConsistencyOptions().max_change_px);
}

TEST_F(SceneConsistencyTest, TooFewMatchesAreNotCompared) {
  Sides s = sides(head.truth, knocked(head.truth, 1.0), 8);
  s.after.resize(SceneConsistencyOptions().min_matches - 1);
  const SceneConsistency c = compareSceneSides(s.before, s.after, guide);
  EXPECT_FALSE(c.compared);
  EXPECT_TRUE(c.consistent);
  SceneConsistencyOptions bad;
  bad.min_matches = 6;
  EXPECT_THROW(compareSceneSides(s.before, s.after, guide, bad), std::invalid_argument);
  bad = SceneConsistencyOptions();
  bad.max_change_px = -1.0;
  EXPECT_NE(bad.validate(), "");
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
