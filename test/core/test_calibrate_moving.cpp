// Calibration while the world moves, end to end in the core, deterministic: the CI's minute of
// `bench_calibrate_moving` (rendered drive_photo with its movers and real-head optics, the window
// tracker with each window's scene correspondences and the prior of earlier windows, the quality
// gate with the calibrator's refinement ratio; a window every 6 s and a drift event every other window: a 5 % zoom, a thermal rotation
// started and stopped, a knock). No commit may be worse than the calibration it replaced (the
// bench's exit status and its summary line), and every change must have been committed. The
// ten-minute run and its figures: docs/figures.md. The same minute with each event just before a
// burst (a knock between a window's two sides of light-off frames).
#include <gtest/gtest.h>

#include <cstdio>
#include <string>

#include "embedded_calibration_stereo/test_support/run_command.h"

namespace embedded_calibration_stereo::core {
namespace {

struct Summary {
  int status = -1, windows = 0, commits = 0, rejected = 0, worse = -1;
  std::string out;
};

// One minute of the bench in the product's configuration, plus `extra` arguments.
Summary runMinute(const std::string& extra) {
  Summary s;
  s.status = runCommand(std::string("ECS_SOURCE_DIR=" ECS_SOURCE_DIR " " ECS_BENCH_CALIBRATE_MOVING) +
                            " --minutes 1 --period 6 --min-change 0 --learn-window 2 --fps 30 --scene 1"
                            " --light-off-gap 3 --filter 1 --refine 0.85 --scene-test 0.001 " +
                            extra + " 2>/dev/null",
                        &s.out);
  std::printf("%s", s.out.c_str());
  const size_t summary = s.out.rfind("windows, ");
  if (summary == std::string::npos) return s;
  const size_t line = s.out.rfind('\n', summary) + 1;
  std::sscanf(s.out.c_str() + line, "%d windows, %d commits, %d rejected, %d commits worse", &s.windows, &s.commits,
              &s.rejected, &s.worse);
  return s;
}

int count(const std::string& text, const std::string& part) {
  int n = 0;
  for (size_t at = text.find(part); at != std::string::npos; at = text.find(part, at + 1)) ++n;
  return n;
}

// Ten windows, nothing committed worse than what it replaced, and the zoom, the thermal rotation
// (its start and its stop) and the knock each committed (they each move the rig).
void expectTenWindowsNothingWorse(const Summary& s) {
  EXPECT_EQ(s.status, 0);
  EXPECT_EQ(s.worse, 0);
  EXPECT_EQ(s.windows, 10);
  EXPECT_GE(s.commits, 4);
}

TEST(CalibrateMoving, AMinuteOfDrivePhotoCommitsNothingWorse) { expectTenWindowsNothingWorse(runMinute("")); }

// Each drift event just before a burst: the light-off frames before the window show the rig of
// before it. The zoom's and the knock's windows are found out and solved on their boards.
TEST(CalibrateMoving, EventsJustBeforeABurstCommitNothingWorse) {
  const Summary s = runMinute("--event-at-burst 1");
  expectTenWindowsNothingWorse(s);
  EXPECT_EQ(count(s.out, "CHANGED, not used"), 2);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
