// GPIO light backend: without a GPIO chip on the test machine only the refusals can be
// checked; each names its parameter.
#include <gtest/gtest.h>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/light_backend.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;

namespace {

std::string refusedParameter(const GpioLightParams& params) {
  try {
    makeGpioLight(params);
  } catch (const core::ConfigError& e) {
    return e.parameter();
  }
  return "(accepted)";
}

}  // namespace

TEST(GpioLight, RefusesAMissingChipOrLine) {
  GpioLightParams params;
  params.chip = "ecs_no_such_gpiochip";
  params.line = 3;
  const std::string refused = refusedParameter(params);
  if (refused == "light_backend") GTEST_SKIP() << "built without libgpiod";
  EXPECT_EQ(refused, "gpio_chip");
  params.line = -1;
  EXPECT_EQ(refusedParameter(params), "gpio_line");
  params.chip.clear();
  params.line = 0;
  EXPECT_EQ(refusedParameter(params), "gpio_chip");
}
