// The sim light backend and the sim frame source pass the light's command and its switch time
// to the simulated rig, so that its light response model (optics.light) renders frames taken
// while the light changes as partly lit; without the command the schedule's ramp is rendered.
#include <gtest/gtest.h>

#include <memory>

#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/ros/frame_source.h"
#include "embedded_calibration_stereo/ros/light_backend.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;

namespace {

std::shared_ptr<core::SimRig> responseRig() {
  core::SimRigConfig c = core::loadSimRigConfig(std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml");
  c.scene.enabled = false;  // only the level matters here
  c.optics.light.model = "response";
  c.optics.light.rise_time_s = 0.05;
  c.optics.light.fall_time_s = 0.05;
  c.optics.light.delay_s = 0.01;
  c.optics.exposure.time_s = 0.008;
  return std::make_shared<core::SimRig>(c);
}

// Frame times k / 30; the light is requested on at frame 2 and off at frame 8.
std::vector<double> renderedLevels(bool with_command, std::vector<double>* schedule_levels) {
  auto level = std::make_shared<std::atomic<double>>(0.0);
  auto command = std::make_shared<std::atomic<uint64_t>>(0);
  auto rig = responseRig();
  auto light = with_command ? makeSimLight(level, command) : makeSimLight(level);
  auto source = with_command ? makeSimFrameSource(rig, level, command, 30.0) : makeSimFrameSource(rig, level, 30.0);
  core::LightSchedule schedule(core::LightScheduleConfig{0.0, 10, 2});
  std::vector<double> levels;
  for (int k = 0; k < 12; ++k) {
    if (k == 2) schedule.request(true);
    if (k == 8) schedule.request(false);
    const double t = k / 30.0;
    const core::LightState state = schedule.step(t);
    std::string error;
    EXPECT_TRUE(light->apply(state, &error)) << error;
    StereoFrame frame;
    EXPECT_TRUE(source->grab(t, &frame, &error)) << error;
    levels.push_back(frame.truth->light_level);
    schedule_levels->push_back(state.light_level);
  }
  return levels;
}

TEST(SimLightResponse, TheDriverPassesTheCommandAndItsSwitchTime) {
  std::vector<double> schedule;
  const std::vector<double> levels = renderedLevels(true, &schedule);
  // Switched on at frame 2 (t = 2/30): 10 ms later a 0.05 s linear rise, averaged over 8 ms
  // exposures (the switched frame's exposure ends before the light starts); off at frame 8.
  const double T = 0.008, delay = 0.01, rise = 0.05, frame = 1.0 / 30;
  const double ramp = (frame + T / 2 - delay) / rise;
  const double expected[12] = {0, 0, 0, ramp, 1, 1, 1, 1, 1, 1 - ramp, 0, 0};
  for (int k = 0; k < 12; ++k) EXPECT_NEAR(levels[k], expected[k], 1e-9) << "frame " << k;
}

TEST(SimLightResponse, WithoutTheCommandTheScheduleRampIsRendered) {
  std::vector<double> schedule;
  const std::vector<double> levels = renderedLevels(false, &schedule);
  for (int k = 0; k < 12; ++k) EXPECT_DOUBLE_EQ(levels[k], schedule[k]) << "frame " << k;
  EXPECT_DOUBLE_EQ(schedule[2], 1.0 / 3);  // the ramp, as a control that the light did switch
}

}  // namespace
