// The diagnostics summaries of the CameraDriver and the LightController: the problem a user must
// see first leads, and the frame rate warning starts below 90 % of the configured rate.
#include <gtest/gtest.h>

#include "embedded_calibration_stereo/core/driver/status_summary.h"

namespace embedded_calibration_stereo::core {
namespace {

using Level = StatusSummary::Level;

TEST(DriverSummary, ACaptureErrorLeadsThenTheCalibrationThenTheRate) {
  EXPECT_EQ(driverSummary("camera unplugged", "file rejected", 3.0, 30.0).text, "camera unplugged");
  EXPECT_EQ(driverSummary("camera unplugged", "", 30.0, 30.0).level, Level::kError);
  const StatusSummary calibration = driverSummary("", "file rejected", 3.0, 30.0);
  EXPECT_EQ(calibration.level, Level::kError);
  EXPECT_EQ(calibration.text, "file rejected");
  const StatusSummary slow = driverSummary("", "", 26.9, 30.0);
  EXPECT_EQ(slow.level, Level::kWarn);
  EXPECT_EQ(slow.text, "26.9 fps, below 30.0");
  const StatusSummary fine = driverSummary("", "", 27.0, 30.0);  // 90 % of 30 fps is enough
  EXPECT_EQ(fine.level, Level::kOk);
  EXPECT_EQ(fine.text, "publishing");
}

TEST(LightControllerSummary, EachProblemLeadsOverTheLesserOnes) {
  LightControllerState all;
  all.backend_error = "serial port closed";
  all.fault = "no light step seen";
  all.held_back = "right camera_info";
  all.uncalibrated = true;
  all.frames_out = 0;
  const std::pair<Level, std::string> expected[] = {
      {Level::kError, "light backend: serial port closed"}, {Level::kError, "light not working: no light step seen"},
      {Level::kError, "frames held back: right camera_info"}, {Level::kWarn, "driver's camera_info uncalibrated"},
      {Level::kWarn, "no frame from the driver yet"},         {Level::kOk, "confirming the light"}};
  // Solve the problems one by one, the leading one first.
  LightControllerState state = all;
  for (int i = 0; i < 6; ++i) {
    const StatusSummary summary = lightControllerSummary(state);
    EXPECT_EQ(summary.level, expected[i].first) << i;
    EXPECT_EQ(summary.text, expected[i].second) << i;
    if (i == 0) state.backend_error.clear();
    if (i == 1) state.fault.clear();
    if (i == 2) state.held_back.clear();
    if (i == 3) state.uncalibrated = false;
    if (i == 4) state.frames_out = 1;
  }
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
