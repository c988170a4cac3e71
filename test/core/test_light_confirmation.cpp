// Light confirmation from the images (core/light/light_confirmation.h) on simulator
// renderings: frames exposed while the light changed must be unsettled, whatever the driver's
// delay between the command and the light (0 to 3 frames), and no settled frame may carry the
// wrong light state.
//
// A frame exposed while the light switched integrates both states: the sim's image is linear in
// the light level before noise and quantisation, so such a frame is rendered as the blend
// (1 - p) * I_off + p * I_on of noise-free light-off and light-on renderings, p being the
// fraction of the exposure with the light on, plus its own sensor noise. The truth of each frame
// is p, computed from the light's switching time and the exposure window, independently of the
// code under test.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "embedded_calibration_stereo/core/light/light_confirmation.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace core = embedded_calibration_stereo::core;

namespace {

const std::string kConfigPath = std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml";

// Noise-free light-off and light-on renderings of both cameras, and the truth, rendered once.
struct Renderings {
  cv::Mat off[2], on[2];
  core::StereoObservation truth;
  std::vector<core::VirtualBoard> boards;
  double noise_sigma = 1.0;
};

const Renderings& renderings() {
  static const std::unique_ptr<Renderings> r = [] {
    core::SimRigConfig config = core::loadSimRigConfig(kConfigPath);
    auto out = std::make_unique<Renderings>();
    out->noise_sigma = config.noise_sigma;
    config.noise_sigma = 0.0;
    const core::SimRig sim(config);
    const core::SimFrame off = sim.render(0.0, 0.0, 1);
    const core::SimFrame on = sim.render(0.0, 1.0, 1);
    out->off[0] = off.left;
    out->off[1] = off.right;
    out->on[0] = on.left;
    out->on[1] = on.right;
    out->truth = on.observations;
    out->boards = sim.virtualBoards();
    return out;
  }();
  return *r;
}

// Sensor noise of the sim's sigma: a pool of independent images, picked by seed (drawing a
// fresh image per frame costs more than the rest of the test).
const cv::Mat& noiseFrame(int camera, uint64_t seed) {
  static const std::vector<cv::Mat> pool = [] {
    std::vector<cv::Mat> images;
    cv::RNG rng(12345);
    for (int i = 0; i < 2 * 23; ++i) {
      cv::Mat noise(renderings().off[0].size(), CV_32F);
      rng.fill(noise, cv::RNG::NORMAL, 0.0, renderings().noise_sigma);
      images.push_back(noise);
    }
    return images;
  }();
  return pool[(2 * seed + camera) % pool.size()];
}

// A frame exposed with the light on for the fraction `p` of its exposure, with sensor noise.
cv::Mat frameAt(int camera, double p, uint64_t seed, double scene_gain = 1.0) {
  const Renderings& r = renderings();
  cv::Mat off0, on0;
  r.off[camera].convertTo(off0, CV_32F);
  r.on[camera].convertTo(on0, CV_32F);
  const cv::Mat off = off0 * scene_gain;
  const cv::Mat on = on0 + off - off0;  // the lit device over the (possibly brighter) scene
  cv::Mat blend = (1.0 - p) * off + p * on + noiseFrame(camera, seed), out;
  blend.convertTo(out, CV_8U);  // rounds and saturates like the sensor
  return out;
}

// Fraction of the exposure [k, k + exposure] (in frame periods) during which the light is on,
// for a light switched on at `on_at` and off at `off_at` (frame periods), rising linearly over
// `rise` periods after each switch (0 = instantly). Integrated numerically.
double exposedFraction(int k, double exposure, double on_at, double off_at, double rise) {
  const auto level = [&](double t) {
    const auto ramp = [&](double since) { return since <= 0 ? 0.0 : rise <= 0 ? 1.0 : std::min(1.0, since / rise); };
    return std::max(0.0, ramp(t - on_at) - ramp(t - off_at));
  };
  const int steps = 2000;
  double sum = 0.0;
  for (int i = 0; i < steps; ++i) sum += level(k + exposure * (i + 0.5) / steps);
  const double p = sum / steps;
  // Exact 0 and 1 are the frames not touched by a change (numerical crumbs rounded away).
  return p < 1e-9 ? 0.0 : p > 1.0 - 1e-9 ? 1.0 : p;
}

struct Scenario {
  int delay_frames = 0;      // driver: frames between the command and the light's change
  double phase = 0.0;        // where in the frame period the light changes (0 = at exposure start)
  double exposure = 0.6;     // exposure time, in frame periods
  double rise = 0.0;         // rise/fall time of the light, frame periods
  int right_lag_frames = 0;  // independent drivers: the right camera's frames lag by this many
  cv::Mat mask[2];           // regions (empty: whole image)
};

struct Outcome {
  int frames = 0, settled_on = 0, settled_off = 0;
  int wrong = 0;                   // settled with a partial exposure or the wrong state
  int clean_unsettled = 0;         // frames away from any change that were not settled
  std::string first_wrong;
  std::string watch_fault;
};

// Commands the light on at frame `command_on` and off at `command_off` (the frames at whose
// arrival the command is given, so it can act from the next frame on), renders what a driver
// with the scenario's delay delivers, and checks every decision against the truth.
Outcome run(const Scenario& s, int frames = 60, int command_on = 12, int command_off = 36) {
  core::StereoLightConfirmer confirmer;
  core::LightCommandWatch watch(3);
  std::vector<double> p[2];
  for (int k = 0; k < frames; ++k) {
    for (int c = 0; c < 2; ++c) {
      const int lag = c == 1 ? s.right_lag_frames : 0;
      const double on_at = command_on + 1 + s.delay_frames + lag + s.phase;
      const double off_at = command_off + 1 + s.delay_frames + lag + s.phase;
      p[c].push_back(exposedFraction(k, s.exposure, on_at, off_at, s.rise));
    }
  }
  Outcome out;
  for (int k = 0; k < frames; ++k) {
    const cv::Mat left = frameAt(0, p[0][k], 1000 + 2 * k), right = frameAt(1, p[1][k], 1001 + 2 * k);
    const auto decided = confirmer.push(core::regionLevel(left, s.mask[0]), core::regionLevel(right, s.mask[1]));
    watch.update(k >= command_on && k < command_off, decided);
    if (!out.watch_fault.empty() || !watch.fault().empty()) out.watch_fault = watch.fault();
    if (!decided) continue;
    const int j = k - 1;  // the decision is for the previous frame
    ++out.frames;
    const bool partial = (p[0][j] != 0.0 && p[0][j] != 1.0) || (p[1][j] != 0.0 && p[1][j] != 1.0);
    const bool both_on = p[0][j] == 1.0 && p[1][j] == 1.0;
    if (decided->settled) {
      (decided->light_on ? out.settled_on : out.settled_off)++;
      if (partial || p[0][j] != p[1][j] || decided->light_on != both_on) {
        ++out.wrong;
        if (out.first_wrong.empty())
          out.first_wrong = "frame " + std::to_string(j) + " settled light_on=" + std::to_string(decided->light_on) +
                            " but exposed " + std::to_string(p[0][j]) + " / " + std::to_string(p[1][j]);
      }
    } else {
      // Frames two or more frames away from any change in either camera must be usable.
      bool near_change = j < 2;
      for (int c = 0; c < 2; ++c)
        for (int i = std::max(0, j - 2); i <= std::min(frames - 1, j + 2); ++i)
          if (p[c][i] != p[c][j]) near_change = true;
      if (!near_change) ++out.clean_unsettled;
    }
  }
  return out;
}

void expectClean(const Outcome& o, int on_frames_commanded, const std::string& what) {
  EXPECT_EQ(o.wrong, 0) << what << ": " << o.first_wrong;
  EXPECT_EQ(o.clean_unsettled, 0) << what << ": frames away from any change were not settled";
  // The light window loses at most the partial frames and one frame on each side of them.
  EXPECT_GE(o.settled_on, on_frames_commanded - 4) << what;
  EXPECT_GT(o.settled_off, 0) << what;
  EXPECT_EQ(o.watch_fault, "") << what;
}

}  // namespace

TEST(LightConfirmation, OptionsNameTheBadField) {
  core::LightConfirmationOptions o;
  EXPECT_EQ(o.validate(), "");
  o.min_step = 0;
  EXPECT_NE(o.validate().find("min_step"), std::string::npos);
  o = core::LightConfirmationOptions();
  o.switch_fraction = 1.0;
  EXPECT_NE(o.validate().find("switch_fraction"), std::string::npos);
  o = core::LightConfirmationOptions();
  o.plateau_fraction = 0.6;
  EXPECT_NE(o.validate().find("plateau_fraction"), std::string::npos);
}

// The blend is the physics of a switch during the exposure; check it against the simulator's
// own rendering at an intermediate level (what its ramp renders), away from saturation.
TEST(LightConfirmation, BlendMatchesTheSimulatorsIntermediateLevel) {
  core::SimRigConfig config = core::loadSimRigConfig(kConfigPath);
  config.noise_sigma = 0.0;
  const core::SimRig sim(config);
  const cv::Mat half = sim.render(0.0, 0.5, 1).left;
  const Renderings& r = renderings();
  cv::Mat off, on, blend;
  r.off[0].convertTo(off, CV_32F);
  r.on[0].convertTo(on, CV_32F);
  cv::Mat(0.5 * off + 0.5 * on).convertTo(blend, CV_8U);
  cv::Mat diff;
  cv::absdiff(half, blend, diff);
  // Each of the three renderings is rounded to whole grey levels: the blend differs by <= 1.
  EXPECT_LE(cv::norm(diff, cv::NORM_INF), 1.0);
  EXPECT_LT(cv::mean(diff)[0], 0.6);
}

TEST(LightConfirmation, DriverDelayOfZeroToThreeFramesAndSwitchesDuringTheExposure) {
  for (int delay = 0; delay <= 3; ++delay) {
    // 0.58: the light changes 0.02 periods before the end of a 0.6 exposure, so that frame differs
    // from its predecessor by less than the plateau tolerance: only its successor gives it away.
    for (double phase : {0.0, 0.3, 0.55, 0.58, 0.8}) {
      Scenario s;
      s.delay_frames = delay;
      s.phase = phase;
      const Outcome o = run(s);
      expectClean(o, 24, "delay " + std::to_string(delay) + " phase " + std::to_string(phase));
    }
  }
}

// Both the switch during the exposure (phase 0.3 of a 0.6 exposure) and a light that needs
// 1.5 frames to reach full brightness produce several partly lit frames in a row.
TEST(LightConfirmation, SlowLightRiseAndFall) {
  for (int delay : {0, 3}) {
    Scenario s;
    s.delay_frames = delay;
    s.phase = 0.3;
    s.rise = 1.5;
    const Outcome o = run(s);
    expectClean(o, 24 - 2, "rise 1.5 frames, delay " + std::to_string(delay));
  }
}

// Two independent drivers: the right camera's frames lag the left's by one frame, so at each
// switch one stereo frame has one camera lit and the other not.
TEST(LightConfirmation, CamerasOfIndependentDriversSwitchingOneFrameApart) {
  Scenario s;
  s.delay_frames = 1;
  s.phase = 0.55;
  s.right_lag_frames = 1;
  const Outcome o = run(s);
  expectClean(o, 24 - 1, "right camera one frame late");
}

// The taught board regions: a mask built from the truth's outer corners (as teaching records
// them) covers every visible true corner, concentrates the device's signal (a larger step than
// the whole image's) and confirms the light as well.
TEST(LightConfirmation, TaughtBoardRegions) {
  const Renderings& r = renderings();
  Scenario s;
  for (int c = 0; c < 2; ++c) {
    core::CameraPrior prior;
    prior.width = r.off[c].cols;
    prior.height = r.off[c].rows;
    for (const core::BoardCorners& b : c == 0 ? r.truth.left : r.truth.right) {
      const auto board = std::find_if(r.boards.begin(), r.boards.end(),
                                      [&](const core::VirtualBoard& v) { return v.virtual_id == b.board_id; });
      ASSERT_NE(board, r.boards.end());
      const int cols = board->cols, rows = board->rows;
      const int outer[4] = {0, cols - 1, rows * cols - 1, (rows - 1) * cols};
      core::BoardPrior bp;
      bp.board_id = b.board_id;
      bp.cols = cols;
      bp.rows = rows;
      bp.outer_mean = cv::Mat(1, 8, CV_64F);
      bool complete = true;
      for (int i = 0; i < 4; ++i) {
        const auto it = std::find(b.corner_ids.begin(), b.corner_ids.end(), outer[i]);
        if (it == b.corner_ids.end()) {
          complete = false;
          break;
        }
        bp.outer_mean.at<double>(0, 2 * i) = b.u[it - b.corner_ids.begin()];
        bp.outer_mean.at<double>(0, 2 * i + 1) = b.v[it - b.corner_ids.begin()];
      }
      if (complete) prior.boards.push_back(bp);
    }
    ASSERT_GE(prior.boards.size(), 4u) << "camera " << c;
    s.mask[c] = core::boardRegionMask(prior);
    ASSERT_EQ(s.mask[c].size(), r.off[c].size());
    // Every true corner of the taught boards lies inside the mask.
    for (const core::BoardCorners& b : c == 0 ? r.truth.left : r.truth.right) {
      if (std::none_of(prior.boards.begin(), prior.boards.end(), [&](const core::BoardPrior& p) { return p.board_id == b.board_id; }))
        continue;
      for (size_t i = 0; i < b.size(); ++i)
        EXPECT_GT(s.mask[c].at<uint8_t>(cvRound(b.v[i]), cvRound(b.u[i])), 0) << "board " << b.board_id;
    }
    // The device's step is larger in its regions than over the whole image.
    const double region_step = core::regionLevel(r.on[c], s.mask[c]) - core::regionLevel(r.off[c], s.mask[c]);
    const double whole_step = core::regionLevel(r.on[c], cv::Mat()) - core::regionLevel(r.off[c], cv::Mat());
    EXPECT_GT(region_step, 1.3 * whole_step) << "camera " << c;
  }
  for (int delay : {0, 2}) {
    s.delay_frames = delay;
    s.phase = 0.3;
    expectClean(run(s), 24, "board regions, delay " + std::to_string(delay));
  }
}

// No device in view when the light should be on: the images never change, the watch reports
// the light as not working once the longest delay has passed; with the device lit it does not.
TEST(LightConfirmation, WatchReportsALightThatDoesNotShow) {
  core::StereoLightConfirmer confirmer;
  core::LightCommandWatch watch(3);
  int first_fault = -1;
  for (int k = 0; k < 40; ++k) {
    const auto decided = confirmer.push(core::regionLevel(frameAt(0, 0.0, 3 * k), cv::Mat()),
                                        core::regionLevel(frameAt(1, 0.0, 3 * k + 1), cv::Mat()));
    watch.update(k >= 10, decided);
    if (!watch.fault().empty() && first_fault < 0) first_fault = k;
    if (decided && k >= 2) {
      EXPECT_TRUE(decided->settled) << k;
      EXPECT_FALSE(decided->light_on) << k;
    }
  }
  // Commanded at frame 10's arrival: delay 3 + confirmation: a fault from frame 10 + 3 + 3 on.
  EXPECT_GE(first_fault, 10 + 3 + 3) << watch.fault();
  EXPECT_LE(first_fault, 10 + 3 + 4) << watch.fault();
  EXPECT_NE(watch.fault().find("do not show the device lit"), std::string::npos) << watch.fault();
}

// A scene brightening by a third of the light's step while the light is off is the scene, not
// the light; a slow drift of the scene's brightness keeps the plateau settled.
TEST(LightConfirmation, SceneChangesBelowHalfTheStepAreNotTheLight) {
  const Renderings& r = renderings();
  const double step = core::regionLevel(r.on[0], cv::Mat()) - core::regionLevel(r.off[0], cv::Mat());
  const double scene = core::regionLevel(r.off[0], cv::Mat());
  core::LightLevelTracker tracker;
  int settled_on = 0;
  for (int k = 0; k < 60; ++k) {
    const double p = k >= 10 && k < 20 ? 1.0 : 0.0;
    // A sudden brightening by step/3 at frame 30, then a slow drift of 0.05 % per frame.
    double gain = k >= 30 ? 1.0 + step / 3.0 / scene : 1.0;
    if (k >= 40) gain *= 1.0 + 0.0005 * (k - 40);
    const auto decided = tracker.push(core::regionLevel(frameAt(0, p, 7 * k, gain), cv::Mat()));
    if (!decided) continue;
    const int j = k - 1;
    const bool truth_on = j >= 10 && j < 20;
    if (decided->settled) {
      EXPECT_EQ(decided->light_on, truth_on) << "frame " << j;
      settled_on += decided->light_on;
    }
    if (j >= 33 && j < 58) {
      EXPECT_TRUE(decided->settled) << "frame " << j << " (slow scene drift)";
    }
  }
  EXPECT_GE(settled_on, 8);
  EXPECT_NEAR(tracker.step(), step, 0.05 * step);
}

// New regions change what a level means: the tracker forgets its levels and its state, and
// reports frames unsettled until the next switch shows the state again, whichever it is.
TEST(LightConfirmation, ForgettingLevelsWaitsForTheNextSwitch) {
  const Renderings& r = renderings();
  for (const bool on_at_forget : {true, false}) {
    core::LightLevelTracker tracker;
    cv::Mat regions = cv::Mat::zeros(r.off[0].size(), CV_8UC1);
    regions(cv::Rect(0, 0, regions.cols, regions.rows / 2)).setTo(255);
    // Light on for frames [10, 30) when forgetting at 20, on for [25, 45) otherwise.
    const int on_from = on_at_forget ? 10 : 25, on_to = on_at_forget ? 30 : 45, forget_at = 20;
    int settled_after_switch = 0;
    for (int k = 0; k < 60; ++k) {
      if (k == forget_at) tracker.forgetLevels();
      const double p = k >= on_from && k < on_to ? 1.0 : 0.0;
      const auto decided = tracker.push(core::regionLevel(frameAt(0, p, 5 * k), k >= forget_at ? regions : cv::Mat()));
      if (!decided) continue;
      const int j = k - 1;
      const bool truth_on = j >= on_from && j < on_to;
      const int next_switch = on_at_forget ? on_to : on_from;
      if (decided->settled) {
        EXPECT_EQ(decided->light_on, truth_on) << "frame " << j << (on_at_forget ? " (on" : " (off") << " when forgetting)";
      }
      if (j >= forget_at && j < next_switch - 1) {
        EXPECT_FALSE(decided->settled) << "frame " << j << ": state unknown";
      }
      if (j >= next_switch + 2) settled_after_switch += decided->settled;
    }
    EXPECT_GE(settled_after_switch, 10) << (on_at_forget ? "on" : "off") << " when forgetting";
    EXPECT_TRUE(tracker.known());
  }
}
