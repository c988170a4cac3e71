// The bring-up check's measures against what made the data: stamps and light levels built with
// a known offset and lag, the simulator's rendered frames and its true corners.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/calibration/bringup_check.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace core = embedded_calibration_stereo::core;

namespace {

const std::string kConfig = std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml";

TEST(BringupStamps, PairsByNearestStampAndMeasuresTheOffset) {
  std::vector<double> left, right;
  for (int k = 0; k < 100; ++k) {
    left.push_back(10.0 + k / 30.0);
    if (k == 40) continue;                          // a right image lost
    right.push_back(10.0 + k / 30.0 + (k == 70 ? 0.015 : 0.010));  // one 15 ms late: within half a frame
  }
  const core::StampPairing s = core::pairStereoStamps(left, right);
  EXPECT_EQ(s.left_frames, 100);
  EXPECT_EQ(s.right_frames, 99);
  EXPECT_NEAR(s.frame_period_s, 1.0 / 30.0, 1e-9);
  ASSERT_EQ(s.pairs.size(), 99u);  // every left image but the one whose right image was lost
  EXPECT_NEAR(s.median_offset_s, 0.010, 1e-9);
  EXPECT_NEAR(s.max_abs_offset_s, 0.015, 1e-9);
  for (const auto& p : s.pairs) EXPECT_NE(p.first, 40);
}

TEST(BringupStamps, AnImageMoreThanHalfAFrameAwayIsNotPaired) {
  std::vector<double> left, right;
  for (int k = 0; k < 30; ++k) left.push_back(k / 30.0), right.push_back(k / 30.0 + (k == 10 ? 0.02 : 0.0));
  const core::StampPairing s = core::pairStereoStamps(left, right);
  EXPECT_EQ(s.pairs.size(), 29u);
  EXPECT_NEAR(s.max_abs_offset_s, 0.0, 1e-12);
}

// Levels of a light commanded on at frame 20 and off at 40 (and 80/100), settled two frames
// after each command, whose image follows `lag` frames after the command: half-way for one
// frame, then fully.
struct LightRun {
  std::vector<double> left, right;
  std::vector<core::FrameMode> modes;
};

LightRun lightRun(int lag, int right_extra_lag = 0) {
  LightRun run;
  const auto commanded = [](int k) { return (k >= 20 && k < 40) || (k >= 80 && k < 100); };
  const auto level = [&](int k, int delay) {
    const bool now = commanded(k - delay - 1), before = commanded(k - delay - 2);
    const double f = now == before ? (now ? 1.0 : 0.0) : 0.5;
    return 80.0 + 100.0 * f;
  };
  for (int k = 0; k < 130; ++k) {
    run.left.push_back(level(k, lag));
    run.right.push_back(level(k, lag + right_extra_lag));
    const bool settled = commanded(k) == commanded(k - 1) && commanded(k) == commanded(k - 2);
    run.modes.push_back(core::FrameMode{true, commanded(k), settled});
  }
  return run;
}

TEST(BringupLight, AFastLightLeavesNoSettledFrameChanging) {
  const LightRun run = lightRun(-1);  // the image changes in the command's frame, fully on the next
  const core::LightTiming t = core::analyseLight(run.left, run.right, run.modes, core::BringupThresholds());
  ASSERT_TRUE(t.switched);
  EXPECT_NEAR(t.left_step, 100.0, 1e-9);
  ASSERT_EQ(t.switches.size(), 4u);
  EXPECT_EQ(t.settled_wrong, 0);
  EXPECT_EQ(t.split_switches, 0);
  EXPECT_EQ(t.switches[0].command_frame, 20);
  EXPECT_EQ(t.switches[0].change_frame, 20);
  EXPECT_EQ(t.switches[0].done_frame, 21);
  EXPECT_EQ(t.switches[0].settled_frame, 22);
  EXPECT_FALSE(t.switches[1].rise);
  EXPECT_EQ(t.switches[1].command_frame, 40);
}

TEST(BringupLight, ALightThreeFramesSlowIsMeasuredAndItsSettledFramesCounted) {
  const LightRun run = lightRun(2);  // three frames later than the fast light
  const core::LightTiming t = core::analyseLight(run.left, run.right, run.modes, core::BringupThresholds());
  ASSERT_EQ(t.switches.size(), 4u);
  EXPECT_EQ(t.switches[0].change_frame - t.switches[0].command_frame, 3);
  EXPECT_EQ(t.switches[0].done_frame - t.switches[0].command_frame, 4);
  // Settled from frame 22: 22 (still off), 23 (half) and the same at each of the four switches.
  EXPECT_EQ(t.settled_wrong, 4 * 2);
  core::BringupMeasurements m;
  m.light = t;
  m.has_modes = true;
  m.lit_frames = m.unlit_frames = 10;
  const core::BringupVerdict v = core::judgeBringup(m, core::BringupThresholds());
  EXPECT_FALSE(v.ready);
  ASSERT_EQ(v.reasons.size(), 1u);
  EXPECT_NE(v.reasons[0].find("starts to change 3 frames after its command and is fully on 4 frames"),
            std::string::npos)
      << v.reasons[0];
  EXPECT_NE(v.reasons[0].find("settled from 2 frames"), std::string::npos) << v.reasons[0];
}

TEST(BringupLight, CamerasAFrameApartSeeEachSwitchInDifferentFrames) {
  const LightRun run = lightRun(-1, 1);
  const core::LightTiming t = core::analyseLight(run.left, run.right, run.modes, core::BringupThresholds());
  ASSERT_EQ(t.switches.size(), 4u);
  EXPECT_EQ(t.split_switches, 4);
  EXPECT_EQ(t.switches[0].right_middle - t.switches[0].left_middle, 1);
}

// An auto-exposure answering the light: the gain falls while the light is on and recovers after,
// scene and boards alike. Taken out, the settled frames are steady; left in, they are not.
TEST(BringupLight, AnExposureFollowingTheLightIsTakenOut) {
  const LightRun run = lightRun(-1);
  std::vector<double> left, right, scene;
  double gain = 1.0;
  for (size_t k = 0; k < run.left.size(); ++k) {
    gain += ((run.left[k] > 130.0 ? 0.6 : 1.0) - gain) / 4.0;  // toward its target, a quarter a frame
    left.push_back(gain * run.left[k]);
    right.push_back(gain * run.right[k]);
    scene.push_back(gain * 90.0);
  }
  const core::BringupThresholds th;
  EXPECT_GT(core::analyseLight(left, right, run.modes, th).settled_wrong, 0);
  const core::LightTiming t = core::analyseLight(core::withoutExposureChanges(left, scene),
                                               core::withoutExposureChanges(right, scene), run.modes, th);
  EXPECT_EQ(t.settled_wrong, 0);
  ASSERT_EQ(t.switches.size(), 4u);
  EXPECT_EQ(t.switches[0].done_frame, 21);
  const std::vector<double> corrected = core::withoutExposureChanges(left, scene);
  const double unlit = corrected[10];
  for (size_t k = 0; k < corrected.size(); ++k) {
    if (run.left[k] == 80.0) {
      EXPECT_NEAR(corrected[k], unlit, 1e-9) << "frame " << k;
    }
  }
}

// A light in time, and one settled frame in the middle of a burst brighter (the scene): the
// verdict blames the scene or the exposure, not the light.
TEST(BringupLight, ASettledFrameThatJumpsIsTheSceneNotTheLight) {
  LightRun run = lightRun(-1);
  run.left[30] += 30.0;
  run.right[30] += 30.0;
  core::BringupMeasurements m;
  m.light = core::analyseLight(run.left, run.right, run.modes, core::BringupThresholds());
  EXPECT_EQ(m.light.settled_wrong_frames, std::vector<int>{30});
  m.has_modes = true;
  m.lit_frames = m.unlit_frames = 10;
  const core::BringupVerdict v = core::judgeBringup(m, core::BringupThresholds());
  ASSERT_EQ(v.reasons.size(), 1u);
  EXPECT_NE(v.reasons[0].find("the scene or the exposure changed"), std::string::npos) << v.reasons[0];
  EXPECT_NE(v.reasons[0].find("first: stereo frame 30"), std::string::npos) << v.reasons[0];
}

TEST(BringupLight, NoStepIsNoLight) {
  std::vector<double> left(60), right(60);
  for (int k = 0; k < 60; ++k) left[k] = 100.0 + (k % 3), right[k] = 90.0 - (k % 2);
  const core::LightTiming t = core::analyseLight(left, right, {}, core::BringupThresholds());
  EXPECT_FALSE(t.switched);
  core::BringupMeasurements m;
  m.light = t;
  EXPECT_FALSE(core::judgeBringup(m, core::BringupThresholds()).ready);
}

TEST(BringupImage, ClippedPixelsAreCountedInsideTheMaskOnly) {
  cv::Mat grey(100, 100, CV_8UC1, cv::Scalar(120));
  cv::Mat mask = cv::Mat::zeros(grey.size(), CV_8UC1);
  mask(cv::Rect(0, 0, 50, 100)).setTo(255);                 // 5000 pixels inside
  grey(cv::Rect(0, 0, 10, 10)).setTo(255);                  // 100 clipped inside
  grey(cv::Rect(0, 10, 5, 10)).setTo(0);                    // 50 clipped at zero inside
  grey(cv::Rect(60, 0, 20, 20)).setTo(255);                 // outside: not counted
  cv::Mat surround = cv::Mat::zeros(grey.size(), CV_8UC1);
  surround(cv::Rect(0, 0, 60, 100)).setTo(255);
  grey(cv::Rect(90, 0, 10, 100)).setTo(20);                 // outside the surround: 400 at 255, 1000 at 20
  const core::ImageLevels l = core::measureImage(grey, mask, surround);
  EXPECT_NEAR(l.clipped_fraction, 150.0 / 5000.0, 1e-12);
  EXPECT_NEAR(l.device_level, (100 * 255.0 + 4850 * 120.0) / 5000.0, 1e-9);
  EXPECT_NEAR(l.scene_level, (400 * 255.0 + 1000 * 20.0 + 2600 * 120.0) / 4000.0, 1e-9);
}

class BringupBoards : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    config_ = new core::SimRigConfig(core::loadSimRigConfig(kConfig));
    core::SimRig sim(*config_);
    lit_ = new core::SimFrame(sim.render(0.0, 1.0, 1));
    unlit_ = new core::SimFrame(sim.render(0.0, 0.0, 2));
  }
  static void TearDownTestSuite() {
    delete config_;
    delete lit_;
    delete unlit_;
  }
  static cv::Mat difference(const cv::Mat& lit, const cv::Mat& unlit) {
    cv::Mat a, b;
    lit.convertTo(a, CV_32FC1);
    unlit.convertTo(b, CV_32FC1);
    return a - b;
  }
  static core::SimRigConfig* config_;
  static core::SimFrame *lit_, *unlit_;
};
core::SimRigConfig* BringupBoards::config_ = nullptr;
core::SimFrame* BringupBoards::lit_ = nullptr;
core::SimFrame* BringupBoards::unlit_ = nullptr;

TEST_F(BringupBoards, TheProjectedGridLiesOnTheRenderedCorners) {
  for (bool right : {false, true}) {
    const auto regions = core::projectBoardRegions(config_->device, config_->rig, right);
    const auto& truth = right ? lit_->observations.right : lit_->observations.left;
    ASSERT_EQ(regions.size(), truth.size());
    for (const core::BoardCorners& board : truth) {
      const core::BoardRegion& region = regions[board.board_id];
      EXPECT_DOUBLE_EQ(region.inside_fraction, 1.0);
      // Block 0's third point is inner corner (1, 1): id cols + 1.
      const int cols = config_->device.boards[0].cols;
      for (size_t i = 0; i < board.size(); ++i) {
        if (board.corner_ids[i] != cols + 1) continue;
        EXPECT_NEAR(region.blocks[0][2].x, board.u[i], 0.05);
        EXPECT_NEAR(region.blocks[0][2].y, board.v[i], 0.05);
      }
    }
  }
}

TEST_F(BringupBoards, EveryLitBoardIsSeenAndACoveredOneIsNot) {
  const core::BringupThresholds th;
  const auto regions = core::projectBoardRegions(config_->device, config_->rig, false);
  const auto clean = core::measureBoards(difference(lit_->left, unlit_->left), regions, th);
  ASSERT_EQ(clean.size(), 6u);
  // The lit squares differ by reflectance * (white - black) of full scale, blurred a little.
  const double expected = 0.5 * (0.95 - 0.05) * 255.0;
  for (const auto& b : clean) {
    EXPECT_GT(b.contrast, 0.8 * expected) << "board " << b.board_id;
    EXPECT_LT(b.contrast, 1.05 * expected) << "board " << b.board_id;
    EXPECT_DOUBLE_EQ(b.seen_fraction, 1.0) << "board " << b.board_id;
  }
  // Board 2 covered in the lit frame: its true corners' hull, a square wider, shows the unlit image.
  cv::Mat covered = lit_->left.clone();
  for (const core::BoardCorners& board : lit_->observations.left) {
    if (board.board_id != 2) continue;
    std::vector<cv::Point2f> points;
    for (size_t i = 0; i < board.size(); ++i) points.emplace_back(board.u[i], board.v[i]);
    std::vector<cv::Point2f> hull;
    cv::convexHull(points, hull);
    cv::Mat mask = cv::Mat::zeros(covered.size(), CV_8UC1);
    std::vector<cv::Point> polygon;
    for (const auto& p : hull) polygon.emplace_back(cvRound(p.x), cvRound(p.y));
    cv::fillConvexPoly(mask, polygon, cv::Scalar(255));
    cv::dilate(mask, mask, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(41, 41)));
    unlit_->left.copyTo(covered, mask);
  }
  const auto hidden = core::measureBoards(difference(covered, unlit_->left), regions, th);
  for (const auto& b : hidden) {
    if (b.board_id == 2) {
      EXPECT_LT(b.contrast, 5.0);
      EXPECT_DOUBLE_EQ(b.seen_fraction, 0.0);
    } else {
      EXPECT_DOUBLE_EQ(b.seen_fraction, 1.0) << "board " << b.board_id;
    }
  }
  core::BringupMeasurements m;
  m.light.switched = true;
  m.lit_frames = m.unlit_frames = 1;
  m.boards[0] = hidden;
  m.boards[1] = clean;
  const core::BringupVerdict v = core::judgeBringup(m, th);
  ASSERT_EQ(v.reasons.size(), 1u);
  EXPECT_NE(v.reasons[0].find("board 2 in the left camera: contrast"), std::string::npos) << v.reasons[0];
  m.boards[0] = clean;
  EXPECT_TRUE(core::judgeBringup(m, th).ready);
}

TEST(BringupVerdict, StampsAndClippingAreNamedWithTheirFigures) {
  core::BringupMeasurements m;
  m.light.switched = true;
  m.lit_frames = m.unlit_frames = 10;
  std::vector<double> left, right;
  for (int k = 0; k < 50; ++k) left.push_back(k / 30.0), right.push_back(k / 30.0 + 0.010);
  m.stamps = core::pairStereoStamps(left, right);
  m.clipped_fraction[1] = 0.2;
  m.clipped_frames[1] = 10;
  const core::BringupVerdict v = core::judgeBringup(m, core::BringupThresholds());
  ASSERT_EQ(v.reasons.size(), 2u);
  EXPECT_NE(v.reasons[0].find("10.0 ms from the left's"), std::string::npos) << v.reasons[0];
  EXPECT_NE(v.reasons[1].find("20.0 % of the boards' pixels are clipped"), std::string::npos) << v.reasons[1];
  EXPECT_NE(v.reasons[1].find("right camera"), std::string::npos) << v.reasons[1];
}

}  // namespace
