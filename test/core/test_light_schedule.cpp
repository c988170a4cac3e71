// Light schedule: periodic bursts, requests through set_light and the settled flag.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "embedded_calibration_stereo/core/light/light_schedule.h"

namespace core = embedded_calibration_stereo::core;

namespace {

core::LightScheduleConfig config(double period_s, int calibration_frames, int settle_frames) {
  core::LightScheduleConfig c;
  c.period_s = period_s;
  c.calibration_frames = calibration_frames;
  c.settle_frames = settle_frames;
  return c;
}

// Steps the schedule at `fps` for `frames` frames starting at t0.
std::vector<core::LightState> run(core::LightSchedule* schedule, double t0, double fps, int frames) {
  std::vector<core::LightState> states;
  for (int i = 0; i < frames; ++i) states.push_back(schedule->step(t0 + i / fps));
  return states;
}

}  // namespace

TEST(LightSchedule, ValidateNamesTheBadField) {
  EXPECT_EQ(config(0, 10, 2).validate(), "");
  EXPECT_NE(config(-1, 10, 2).validate().find("calibration_period_s"), std::string::npos);
  EXPECT_NE(config(0, -1, 2).validate().find("calibration_frames"), std::string::npos);
  // calibration_frames 0 counts the burst in time, which then needs a duration.
  EXPECT_NE(config(0, 0, 2).validate().find("calibration_duration_s"), std::string::npos);
  auto timed = config(0, 0, 2);
  timed.calibration_duration_s = 1.0;
  EXPECT_EQ(timed.validate(), "");
  timed.calibration_duration_s = -1.0;
  EXPECT_NE(timed.validate().find("calibration_duration_s"), std::string::npos);
  EXPECT_NE(config(0, 10, -1).validate().find("settle_frames"), std::string::npos);
}

TEST(LightSchedule, ZeroPeriodStaysOffUntilRequested) {
  core::LightSchedule schedule(config(0.0, 5, 2));
  for (const auto& s : run(&schedule, 0.0, 30.0, 300)) {
    EXPECT_FALSE(s.light_on);
    EXPECT_TRUE(s.settled);
    EXPECT_EQ(s.light_level, 0.0);
  }
}

TEST(LightSchedule, RequestSwitchesAtNextFrameAndSettlesAfterSettleFrames) {
  const int settle = 3;
  core::LightSchedule schedule(config(0.0, 5, settle));
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
  core::LightSchedule schedule(config(period, calib, settle));
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

// Settled light-on frames of each burst, stepping the schedule at the given frame times.
std::vector<int> settledFramesPerBurst(core::LightSchedule* schedule, const std::vector<double>& times) {
  std::vector<int> bursts;
  bool on = false;
  for (double t : times) {
    const core::LightState s = schedule->step(t);
    if (s.light_on && !on) bursts.push_back(0);
    if (s.light_on && s.settled) ++bursts.back();
    on = s.light_on;
  }
  return bursts;
}

TEST(LightSchedule, TimedBurstsLastTheSameTimeAtAnyFrameRate) {
  for (const double duration : {1.0, 0.33, 0.4}) {
    for (const double fps : {10.0, 15.0, 25.0, 29.97, 30.0, 60.0}) {
      auto c = config(4.0, 0, 2);
      c.calibration_duration_s = duration;
      core::LightSchedule schedule(c);
      // Frame times with up to 3 ms of jitter, as a driver's stamps have.
      std::vector<double> times;
      for (int i = 0; i < static_cast<int>(10.0 * fps); ++i) times.push_back(50.0 + i / fps + 0.003 * ((i * 7) % 3 - 1));
      const std::vector<int> bursts = settledFramesPerBurst(&schedule, times);
      ASSERT_EQ(bursts.size(), 3u) << fps;
      for (int n : bursts) EXPECT_EQ(n, std::lround(duration * fps)) << duration << " s at " << fps << " fps";
    }
  }
}

TEST(LightSchedule, ATimedBurstEndsOnTimeWhenFramesAreLost) {
  auto c = config(10.0, 0, 1);
  c.calibration_duration_s = 1.0;
  core::LightSchedule schedule(c);
  double first_settled = -1.0, last_settled = -1.0;
  for (int i = 0; i < 90; ++i) {
    if (i >= 10 && i % 2 == 1) continue;  // from frame 10 on, every other frame of 30 fps is lost
    const double t = i / 30.0;
    const core::LightState s = schedule.step(t);
    if (!s.light_on || !s.settled) continue;
    if (first_settled < 0.0) first_settled = t;
    last_settled = t;
  }
  // The settled frames cover 1 s at the rate they came (15 fps at the end), give or take a frame.
  EXPECT_NEAR(last_settled - first_settled + 1.0 / 15.0, 1.0, 1.0 / 15.0);
}

TEST(LightSchedule, ReleasingTheRequestEndsABurst) {
  core::LightSchedule schedule(config(10.0, 50, 1));
  auto first = run(&schedule, 0.0, 30.0, 3);
  EXPECT_TRUE(first[0].light_on);
  schedule.request(false);
  EXPECT_FALSE(schedule.step(0.2).light_on);
}

TEST(LightSchedule, FollowTracksSettlingOfAnExternalState) {
  core::LightSchedule schedule(config(0.0, 5, 2));
  const bool recorded[] = {false, true, true, true, true, false, false, false};
  const bool expected_settled[] = {true, false, false, true, true, false, false, true};
  for (int i = 0; i < 8; ++i) {
    const auto s = schedule.follow(recorded[i]);
    EXPECT_EQ(s.light_on, recorded[i]) << i;
    EXPECT_EQ(s.settled, expected_settled[i]) << i;
  }
}

TEST(LightSchedule, ZeroSettleFramesSwitchesInstantly) {
  core::LightSchedule schedule(config(0.0, 5, 0));
  schedule.request(true);
  const auto s = schedule.step(0.0);
  EXPECT_TRUE(s.light_on);
  EXPECT_TRUE(s.settled);
  EXPECT_EQ(s.light_level, 1.0);
}

namespace {

core::LightScheduleConfig healthConfig(core::CalibrationTrigger trigger, double period_s, double min_interval_s,
                                      double verification_period_s) {
  core::LightScheduleConfig c = config(period_s, 10, 2);
  c.trigger = trigger;
  c.min_interval_s = min_interval_s;
  c.verification_period_s = verification_period_s;
  return c;
}

// Runs of commanded light-on frames: (first frame index, length, settled frames, verification).
struct Run {
  int first, length, settled;
  bool verification;
};
std::vector<Run> runs(const std::vector<core::LightState>& states) {
  std::vector<Run> out;
  for (size_t i = 0; i < states.size(); ++i) {
    if (!states[i].light_on || (i > 0 && states[i - 1].light_on)) continue;
    Run r{static_cast<int>(i), 0, 0, states[i].verification};
    for (size_t j = i; j < states.size() && states[j].light_on; ++j) {
      ++r.length;
      r.settled += states[j].settled ? 1 : 0;
      EXPECT_EQ(states[j].verification, r.verification) << "frame " << j << " changes kind inside one run";
    }
    out.push_back(r);
  }
  return out;
}

}  // namespace

TEST(LightSchedule, ValidateNamesTheHealthFields) {
  EXPECT_EQ(healthConfig(core::CalibrationTrigger::kOnDemand, 0, 5, 6).validate(), "");
  EXPECT_NE(healthConfig(core::CalibrationTrigger::kOnDemand, 0, -1, 6).validate().find("min_calibration_interval_s"),
            std::string::npos);
  EXPECT_NE(healthConfig(core::CalibrationTrigger::kOnDemand, 0, 5, -1).validate().find("verification_period_s"),
            std::string::npos);
}

// A flash: settle_frames + 1 frames on, exactly one of them settled, every verification period.
TEST(LightSchedule, VerificationFlashesGiveOneSettledLightOnFrameEachPeriod) {
  const double fps = 30.0;
  core::LightSchedule schedule(healthConfig(core::CalibrationTrigger::kPeriodic, 0.0, 0.0, 2.0));
  const auto states = run(&schedule, 50.0, fps, static_cast<int>(7 * fps));
  const auto flashes = runs(states);
  ASSERT_EQ(flashes.size(), 3u);  // at 2, 4 and 6 s: the first period starts at the first frame
  for (size_t k = 0; k < flashes.size(); ++k) {
    EXPECT_TRUE(flashes[k].verification);
    EXPECT_EQ(flashes[k].length, 3) << k;
    EXPECT_EQ(flashes[k].settled, 1) << k;
    EXPECT_NEAR(flashes[k].first / fps, 2.0 * (k + 1), 1.0 / fps + 1e-9) << k;
  }
}

// The interval counts from a burst's last lit frame: a longer burst leaves its window the same
// time to be tracked, solved and committed before the next burst.
TEST(LightSchedule, OnDemandBurstsOnlyWhileDemandedAndAtMostOncePerMinIntervalAfterTheLast) {
  const double fps = 30.0;
  for (const int frames : {10, 30}) {
    // No safety net (period 0), no flashes: the light stays off until demanded.
    core::LightScheduleConfig c = healthConfig(core::CalibrationTrigger::kOnDemand, 0.0, 3.0, 0.0);
    c.calibration_frames = frames;
    core::LightSchedule schedule(c);
    auto idle = run(&schedule, 0.0, fps, 60);
    EXPECT_TRUE(runs(idle).empty());
    schedule.demand(true);
    const auto states = run(&schedule, 2.0, fps, static_cast<int>(10 * fps));  // 2 .. 12 s
    const auto bursts = runs(states);
    ASSERT_EQ(bursts.size(), 3u) << frames << " frames";
    const int length = frames + 2;  // settle_frames 2
    for (size_t k = 0; k < bursts.size(); ++k) {
      EXPECT_FALSE(bursts[k].verification);
      EXPECT_EQ(bursts[k].length, length) << k;
      EXPECT_EQ(bursts[k].settled, frames) << k;
      // Each starts 3 s after the frame that ended the one before.
      EXPECT_NEAR(bursts[k].first / fps, k * (3.0 + (length - 1) / fps), 1.0 / fps + 1e-9) << frames << " frames, " << k;
    }
    schedule.demand(false);
    EXPECT_TRUE(runs(run(&schedule, 12.0, fps, static_cast<int>(10 * fps))).empty());
  }
}

// A burst cut short by set_light false counts from its start: the next one still waits.
TEST(LightSchedule, OnDemandBurstCutShortStillWaitsTheIntervalFromItsStart) {
  const double fps = 30.0;
  core::LightSchedule schedule(healthConfig(core::CalibrationTrigger::kOnDemand, 0.0, 3.0, 0.0));
  schedule.demand(true);
  auto states = run(&schedule, 0.0, fps, 4);  // a burst from the first frame
  schedule.request(false);                     // cut short
  auto rest = run(&schedule, 4 / fps, fps, static_cast<int>(4 * fps));
  states.insert(states.end(), rest.begin(), rest.end());
  const auto bursts = runs(states);
  ASSERT_EQ(bursts.size(), 2u);
  EXPECT_EQ(bursts[0].length, 4);
  EXPECT_NEAR(bursts[1].first / fps, 3.0, 1.0 / fps + 1e-9);
}

TEST(LightSchedule, OnDemandSafetyNetRestartsAfterEachDemandedBurst) {
  const double fps = 30.0;
  core::LightSchedule schedule(healthConfig(core::CalibrationTrigger::kOnDemand, 4.0, 1.0, 0.0));
  auto states = run(&schedule, 0.0, fps, static_cast<int>(3 * fps));  // burst at 0 (the first frame)
  schedule.demand(true);
  auto demanded = run(&schedule, 3.0, fps, 1);                        // burst at 3
  schedule.demand(false);
  auto rest = run(&schedule, 3.0 + 1 / fps, fps, static_cast<int>(6 * fps));
  states.insert(states.end(), demanded.begin(), demanded.end());
  states.insert(states.end(), rest.begin(), rest.end());
  const auto bursts = runs(states);
  ASSERT_EQ(bursts.size(), 3u);
  EXPECT_NEAR(bursts[0].first / fps, 0.0, 1e-9);
  EXPECT_NEAR(bursts[1].first / fps, 3.0, 1e-9);
  EXPECT_NEAR(bursts[2].first / fps, 7.0, 1.0 / fps + 1e-9) << "the safety net counts from the demanded burst";
}

TEST(LightSchedule, VerifySoonFlashesAtTheNextFrameUnlessABurstVerifiesAlready) {
  core::LightSchedule schedule(healthConfig(core::CalibrationTrigger::kPeriodic, 100.0, 0.0, 50.0));
  // The first burst (12 frames) runs; verifySoon during it is answered by the burst's own frames.
  auto states = run(&schedule, 0.0, 30.0, 3);
  schedule.verifySoon();
  auto more = run(&schedule, 0.1, 30.0, 30);
  states.insert(states.end(), more.begin(), more.end());
  const auto r = runs(states);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_FALSE(r[0].verification);
  EXPECT_EQ(r[0].length, 12);
  // verifySoon when idle: a flash from the next frame; again during that flash (its settled
  // frame is still to come): no second flash.
  schedule.verifySoon();
  auto flash = run(&schedule, 2.0, 30.0, 1);
  schedule.verifySoon();
  const auto rest = run(&schedule, 2.0 + 1 / 30.0, 30.0, 10);
  flash.insert(flash.end(), rest.begin(), rest.end());
  const auto f = runs(flash);
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].first, 0);
  EXPECT_TRUE(f[0].verification);
  EXPECT_EQ(f[0].length, 3);
  EXPECT_EQ(f[0].settled, 1);
}

// The first burst waits first_burst_delay_s of settled light-off frames (its device image is
// learned against them), periodic or on demand; later bursts keep their own timing.
TEST(LightSchedule, TheFirstBurstComesAfterTheDelayWithSettledLightOffFramesBeforeIt) {
  const double fps = 15.0;
  for (const auto trigger : {core::CalibrationTrigger::kPeriodic, core::CalibrationTrigger::kOnDemand}) {
    core::LightScheduleConfig c = healthConfig(trigger, 4.0, 1.0, 0.0);
    c.first_burst_delay_s = 0.5;
    core::LightSchedule schedule(c);
    schedule.demand(true);
    const auto states = run(&schedule, 10.0, fps, static_cast<int>(6 * fps));
    const auto bursts = runs(states);
    ASSERT_GE(bursts.size(), 1u);
    // The first frame at or after 0.5 s (0.5 s is 7.5 frame periods at 15 fps).
    EXPECT_EQ(bursts[0].first, 8) << "the first burst 0.5 s after the first frame";
    for (int i = 0; i < bursts[0].first; ++i) EXPECT_TRUE(!states[i].light_on && states[i].settled) << i;
    if (trigger == core::CalibrationTrigger::kPeriodic) {
      ASSERT_EQ(bursts.size(), 2u);
      EXPECT_EQ(bursts[1].first, 68) << "then every period (4.5 s is 67.5 frame periods)";
    }
  }
  core::LightScheduleConfig bad = config(1.0, 10, 2);
  bad.first_burst_delay_s = -1.0;
  EXPECT_NE(bad.validate().find("first_burst_delay_s"), std::string::npos);
  // The parameter travels apart from the sentence: a refusal names it without parsing text.
  EXPECT_EQ(bad.problem().parameter, "first_burst_delay_s");
  EXPECT_EQ(bad.problem().problem, "must be >= 0");
  core::LightScheduleConfig frames = config(1.0, -1, 2);
  EXPECT_EQ(frames.problem().parameter, "calibration_frames");
  EXPECT_TRUE(config(1.0, 10, 2).problem().ok());
  EXPECT_THROW(core::throwIfProblem(frames.problem()), core::ConfigError);
}

// A calibration that comes into force is checked against the boards at the next frame; the one
// in force when the schedule first hears of it (start-up) and an unchanged epoch are not.
TEST(LightSchedule, ANewCalibrationEpochFlashesAtTheNextFrameTheFirstDoesNot) {
  core::LightSchedule schedule(healthConfig(core::CalibrationTrigger::kPeriodic, 0.0, 0.0, 50.0));
  schedule.calibrationInForce(3);  // at start-up: what is in force is verified on the schedule
  const auto start = runs(run(&schedule, 0.0, 30.0, 10));
  EXPECT_TRUE(start.empty()) << "the epoch in force at start-up flashed";
  schedule.calibrationInForce(3);
  EXPECT_TRUE(runs(run(&schedule, 1.0, 30.0, 10)).empty()) << "an unchanged epoch flashed";
  schedule.calibrationInForce(4);
  const auto changed = runs(run(&schedule, 2.0, 30.0, 10));
  ASSERT_EQ(changed.size(), 1u) << "a new calibration in force was not verified";
  EXPECT_EQ(changed[0].first, 0);
  EXPECT_TRUE(changed[0].verification);
}

// Under the periodic trigger the health's demand neither bursts nor reads as demanded.
TEST(LightSchedule, DemandIsIgnoredUnderThePeriodicTrigger) {
  core::LightSchedule periodic(healthConfig(core::CalibrationTrigger::kPeriodic, 0.0, 0.0, 0.0));
  periodic.demand(true);
  EXPECT_FALSE(periodic.demanded());
  EXPECT_TRUE(runs(run(&periodic, 0.0, 30.0, 60)).empty());
  core::LightSchedule on_demand(healthConfig(core::CalibrationTrigger::kOnDemand, 0.0, 0.0, 0.0));
  on_demand.demand(true);
  EXPECT_TRUE(on_demand.demanded());
}
