// Calibration while the world moves, end to end in the core, deterministic: the CI's minute of
// `bench_calibrate_moving` (rendered drive_photo with its movers and real-head optics, the window
// tracker with each window's scene correspondences and the prior of earlier windows, the quality
// gate with the calibrator's refinement ratio; a window every 6 s and a drift event every other window: a 5 % zoom, a thermal rotation
// started and stopped, a knock). No commit may be worse than the calibration it replaced (the
// bench's exit status and its summary line), and every change must have been committed. The
// ten-minute run and its figures: docs/figures.md.
#include <gtest/gtest.h>

#include <cstdio>
#include <string>

#include "embedded_calibration_stereo/test_support/run_command.h"

namespace embedded_calibration_stereo::core {
namespace {

TEST(CalibrateMoving, AMinuteOfDrivePhotoCommitsNothingWorse) {
  std::string out;
  const int status = runCommand(std::string("ECS_SOURCE_DIR=" ECS_SOURCE_DIR " " ECS_BENCH_CALIBRATE_MOVING) +
                                    " --minutes 1 --period 6 --min-change 0 --learn-window 2 --fps 30 --scene 1"
                                    " --light-off-gap 3 --filter 1 --refine 0.85 2>/dev/null",
                                &out);
  std::printf("%s", out.c_str());
  int windows = 0, commits = 0, rejected = 0, worse = -1;
  const size_t summary = out.rfind("windows, ");
  ASSERT_NE(summary, std::string::npos) << "no summary line";
  const size_t line = out.rfind('\n', summary) + 1;
  ASSERT_EQ(std::sscanf(out.c_str() + line, "%d windows, %d commits, %d rejected, %d commits worse", &windows, &commits,
                        &rejected, &worse),
            4);
  EXPECT_EQ(status, 0);
  EXPECT_EQ(worse, 0);
  EXPECT_EQ(windows, 10);
  // The zoom, the thermal rotation (its start and its stop) and the knock each move the rig.
  EXPECT_GE(commits, 4);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
