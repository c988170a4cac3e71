// Calibration health without drift, end to end in the core, deterministic: the CI's minute of
// `bench_calibration_monitor --no-drift-only` (rendered drive_photo with its movers and real-head
// optics, the true calibration in force, the depth mode every second frame at 30 fps and a
// verification every 2 s from the PatternTracker's corners): every frame GOOD. The ten-minute
// run: docs/figures.md.
#include <gtest/gtest.h>

#include <cstdio>
#include <string>

#include "embedded_calibration_stereo/test_support/run_command.h"

namespace embedded_calibration_stereo::core {
namespace {

TEST(HealthNoFalseAlarm, AMinuteOfDrivePhotoWithoutDriftStaysGood) {
  std::string out;
  const int status = runCommand(std::string("ECS_SOURCE_DIR=" ECS_SOURCE_DIR " " ECS_BENCH_CALIBRATION_MONITOR) +
                                    " --no-drift-only --minutes 1 2>/dev/null",
                                &out);
  std::printf("%s", out.c_str());
  int frames = 0, not_good = -1;
  const size_t line = out.rfind("no drift, ");
  ASSERT_NE(line, std::string::npos) << "no summary line";
  ASSERT_EQ(std::sscanf(out.c_str() + line, "no drift, %*f min (%d frames, %*d lit = %*f %%): %d frames not GOOD",
                        &frames, &not_good),
            2);
  EXPECT_EQ(frames, 1800);
  EXPECT_EQ(not_good, 0);
  EXPECT_EQ(status, 0);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
