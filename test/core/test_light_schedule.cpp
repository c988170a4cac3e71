// Light schedule: periodic bursts, requests through set_light and the settled flag.
#include <gtest/gtest.h>

#include <vector>

#include "embedded_calibration_stereo/core/calibration/light_schedule.h"

namespace {

ecs::LightScheduleConfig config(double period_s, int calibration_frames, int settle_frames) {
  ecs::LightScheduleConfig c;
  c.period_s = period_s;
  c.calibration_frames = calibration_frames;
  c.settle_frames = settle_frames;
  return c;
}

// Steps the schedule at `fps` for `frames` frames starting at t0.
std::vector<ecs::LightState> run(ecs::LightSchedule* schedule, double t0, double fps, int frames) {
  std::vector<ecs::LightState> states;
  for (int i = 0; i < frames; ++i) states.push_back(schedule->step(t0 + i / fps));
  return states;
}

}  // namespace

TEST(LightSchedule, ValidateNamesTheBadField) {
  EXPECT_EQ(config(0, 10, 2).validate(), "");
  EXPECT_NE(config(-1, 10, 2).validate().find("calibration_period_s"), std::string::npos);
  EXPECT_NE(config(0, 0, 2).validate().find("calibration_frames"), std::string::npos);
  EXPECT_NE(config(0, 10, -1).validate().find("settle_frames"), std::string::npos);
}

TEST(LightSchedule, ZeroPeriodStaysOffUntilRequested) {
  ecs::LightSchedule schedule(config(0.0, 5, 2));
  for (const auto& s : run(&schedule, 0.0, 30.0, 300)) {
    EXPECT_FALSE(s.light_on);
    EXPECT_TRUE(s.settled);
    EXPECT_EQ(s.light_level, 0.0);
  }
}

TEST(LightSchedule, RequestSwitchesAtNextFrameAndSettlesAfterSettleFrames) {
  const int settle = 3;
  ecs::LightSchedule schedule(config(0.0, 5, settle));
  run(&schedule, 0.0, 30.0, 4);
  schedule.request(true);
  auto on = run(&schedule, 1.0, 30.0, 10);
  EXPECT_TRUE(on[0].switched);
  for (int i = 0; i < 10; ++i) {
    EXPECT_TRUE(on[i].light_on) << i;
    EXPECT_EQ(on[i].settled, i >= settle) << i;
    if (i > 0) {
      EXPECT_FALSE(on[i].switched) << i;
    }
  }
  // The level ramps strictly up during settling and is full once settled.
  for (int i = 1; i < settle; ++i) EXPECT_GT(on[i].light_level, on[i - 1].light_level);
  EXPECT_LT(on[settle - 1].light_level, 1.0);
  EXPECT_EQ(on[settle].light_level, 1.0);

  schedule.request(false);
  auto off = run(&schedule, 2.0, 30.0, 6);
  EXPECT_TRUE(off[0].switched);
  for (int i = 0; i < 6; ++i) {
    EXPECT_FALSE(off[i].light_on) << i;
    EXPECT_EQ(off[i].settled, i >= settle) << i;
  }
  EXPECT_GT(off[0].light_level, 0.0);
  EXPECT_EQ(off[settle].light_level, 0.0);
}

TEST(LightSchedule, PeriodicBurstsYieldCalibrationFramesSettledFrames) {
  const double fps = 20.0, period = 2.0;
  const int calib = 6, settle = 2;
  ecs::LightSchedule schedule(config(period, calib, settle));
  const auto states = run(&schedule, 100.0, fps, static_cast<int>(3 * period * fps));
  int bursts = 0;
  for (size_t i = 0; i < states.size(); ++i) {
    if (states[i].switched && states[i].light_on) {
      ++bursts;
      // One burst: settle + calib frames on, of which exactly `calib` settled, then off.
      int on_frames = 0, settled_on = 0;
      size_t j = i;
      for (; j < states.size() && states[j].light_on; ++j) {
        ++on_frames;
        if (states[j].settled) ++settled_on;
      }
      EXPECT_EQ(on_frames, settle + calib);
      EXPECT_EQ(settled_on, calib);
      // Bursts start every period seconds, the first at the first frame.
      EXPECT_NEAR(i / fps, (bursts - 1) * period, 1.0 / fps + 1e-9);
    }
  }
  EXPECT_EQ(bursts, 3);
}

TEST(LightSchedule, ReleasingTheRequestEndsABurst) {
  ecs::LightSchedule schedule(config(10.0, 50, 1));
  auto first = run(&schedule, 0.0, 30.0, 3);
  EXPECT_TRUE(first[0].light_on);
  schedule.request(false);
  EXPECT_FALSE(schedule.step(0.2).light_on);
}

TEST(LightSchedule, FollowTracksSettlingOfAnExternalState) {
  ecs::LightSchedule schedule(config(0.0, 5, 2));
  const bool recorded[] = {false, true, true, true, true, false, false, false};
  const bool expected_settled[] = {true, false, false, true, true, false, false, true};
  for (int i = 0; i < 8; ++i) {
    const auto s = schedule.follow(recorded[i]);
    EXPECT_EQ(s.light_on, recorded[i]) << i;
    EXPECT_EQ(s.settled, expected_settled[i]) << i;
  }
}

TEST(LightSchedule, ZeroSettleFramesSwitchesInstantly) {
  ecs::LightSchedule schedule(config(0.0, 5, 0));
  schedule.request(true);
  const auto s = schedule.step(0.0);
  EXPECT_TRUE(s.light_on);
  EXPECT_TRUE(s.settled);
  EXPECT_EQ(s.light_level, 1.0);
}
