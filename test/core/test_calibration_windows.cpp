// The OnlineCalibrator's calibration windows (core::CalibrationWindows): which frames a window
// collects, when it closes and is solved, what an idle window and a time jump do, a request's
// window and the whole-burst window observations. Stamps are small nanosecond counts here.
#include <gtest/gtest.h>

#include "embedded_calibration_stereo/core/calibration/calibration_windows.h"

namespace core = embedded_calibration_stereo::core;

namespace embedded_calibration_stereo::core {
namespace {

constexpr StampNs kFrame = 100000000;  // 10 frames a second

StampNs frame(int i) { return (i + 1) * kFrame; }

// One board seen in both cameras; `tag` makes its content unique.
StereoObservation board(float tag = 0.0f) {
  BoardCorners b;
  b.board_id = 1;
  b.corner_ids = {0, 1};
  b.u = {10.0f + tag, 20.0f};
  b.v = {30.0f, 40.0f};
  StereoObservation o;
  o.left = o.right = {b};
  return o;
}

CalibrationWindowOptions options(int min_frames = 3, int max_frames = 5) {
  CalibrationWindowOptions o;
  o.min_frames = min_frames;
  o.max_frames = max_frames;
  o.window_timeout_s = 5.0;
  o.stamp_tolerance_s = 2.0;
  return o;
}

// Frame i with its mode, then its observation; returns what its mode closed.
ModeResult addFrame(CalibrationWindows* w, int i, bool light_on, bool settled = true, double now_s = 0.0) {
  const ModeResult r = w->addMode({frame(i), light_on, settled, 7}, now_s);
  w->addObservation(board(static_cast<float>(i)), frame(i), now_s);
  return r;
}

TEST(CalibrationWindows, TheLightGoingOffClosesTheWindowOfItsSettledFrames) {
  CalibrationWindows w(options());
  addFrame(&w, 0, true, false);  // light on, not settled yet: not collected
  for (int i = 1; i <= 4; ++i) EXPECT_FALSE(addFrame(&w, i, true).solve);
  EXPECT_EQ(w.windowSize(), 4u);
  const ModeResult off = addFrame(&w, 5, false);
  ASSERT_TRUE(off.solve);
  ASSERT_EQ(off.solve->size(), 4u);
  EXPECT_DOUBLE_EQ(off.solve->front().stamp, 0.2);  // frame 1, stamped in seconds
  EXPECT_EQ(w.windowSize(), 0u);
  // The light staying off closes nothing more.
  EXPECT_FALSE(addFrame(&w, 6, false).solve);
}

TEST(CalibrationWindows, AFrameOfAClosedWindowMatchedLateStaysOut) {
  CalibrationWindows w(options(1));
  addFrame(&w, 0, true);
  w.addMode({frame(1), true, true, 7}, 0.0);  // its observation is late
  ASSERT_TRUE(w.addMode({frame(2), false, false, 7}, 0.0).solve);  // the light went off
  EXPECT_EQ(w.addObservation(board(1), frame(1), 0.0), ObservationFate::kMatched);
  EXPECT_EQ(w.windowSize(), 0u);
}

TEST(CalibrationWindows, AWindowWithFewerThanMinFramesIsDroppedUnsolved) {
  CalibrationWindows w(options(3));
  addFrame(&w, 0, true);
  addFrame(&w, 1, true);
  EXPECT_FALSE(addFrame(&w, 2, false).solve);
  EXPECT_EQ(w.windowSize(), 0u);
  // Exactly min_frames is solved.
  for (int i = 3; i <= 5; ++i) addFrame(&w, i, true);
  const ModeResult off = addFrame(&w, 6, false);
  ASSERT_TRUE(off.solve);
  EXPECT_EQ(off.solve->size(), 3u);
}

TEST(CalibrationWindows, AWindowKeepsItsFirstMaxFrames) {
  CalibrationWindows w(options(1, 2));
  for (int i = 0; i < 4; ++i) addFrame(&w, i, true);
  EXPECT_EQ(w.windowSize(), 2u);
  const ModeResult off = addFrame(&w, 4, false);
  ASSERT_TRUE(off.solve);
  EXPECT_DOUBLE_EQ(off.solve->back().stamp, 0.2);  // frame 1
}

TEST(CalibrationWindows, ObservationsAreMatchedWithTheirModeWhicheverComesFirst) {
  CalibrationWindows w(options(2));
  EXPECT_EQ(w.addObservation(board(1), frame(0), 0.0), ObservationFate::kPending);
  EXPECT_EQ(w.windowSize(), 0u);
  w.addMode({frame(0), true, true, 7}, 0.0);  // its mode: the pending observation joins
  EXPECT_EQ(w.windowSize(), 1u);
  w.addMode({frame(1), true, true, 7}, 0.0);
  EXPECT_EQ(w.addObservation(board(2), frame(1), 0.0), ObservationFate::kMatched);
  EXPECT_EQ(w.windowSize(), 2u);
  // A frame that sees nothing adds nothing.
  w.addMode({frame(2), true, true, 7}, 0.0);
  EXPECT_EQ(w.addObservation(StereoObservation{}, frame(2), 0.0), ObservationFate::kNoBoard);
  EXPECT_EQ(w.windowSize(), 2u);
}

TEST(CalibrationWindows, AnObservationNotAfterThePreviousOneIsDroppedAndCounted) {
  CalibrationWindows w(options());
  addFrame(&w, 0, true);
  addFrame(&w, 1, true);
  StampNs previous = 0;
  EXPECT_EQ(w.addObservation(board(9), frame(1), 0.0, &previous), ObservationFate::kBackwards);
  EXPECT_EQ(previous, frame(1));
  EXPECT_EQ(w.addObservation(board(9), frame(0), 0.0), ObservationFate::kBackwards);
  EXPECT_EQ(w.backwards(), 2u);
  EXPECT_EQ(w.windowSize(), 2u);
}

TEST(CalibrationWindows, ASecondModeOfAStampIsIgnored) {
  CalibrationWindows w(options(1));
  addFrame(&w, 0, true);
  // The same stamp again, light off: it would close the window.
  const ModeResult again = w.addMode({frame(0), false, false, 8}, 0.0);
  EXPECT_EQ(again.kind, ModeResult::Kind::kDuplicate);
  EXPECT_FALSE(again.solve);
  EXPECT_EQ(w.windowSize(), 1u);
  EXPECT_EQ(w.frames().back().epoch, 7u);
}

TEST(CalibrationWindows, AnIdleWindowEndsAfterTheTimeoutSolvedWithMinFrames) {
  CalibrationWindows w(options(3));
  for (int i = 0; i < 3; ++i) addFrame(&w, i, true, true, 100.0 + i);
  EXPECT_FALSE(w.endIdleWindow(106.9));  // 4.9 s since the last frame
  const std::optional<IdleWindow> idle = w.endIdleWindow(107.0);
  ASSERT_TRUE(idle);
  EXPECT_EQ(idle->end, IdleWindowEnd::kSolving);
  EXPECT_EQ(idle->frames, 3u);
  EXPECT_DOUBLE_EQ(idle->idle_s, 5.0);
  EXPECT_EQ(idle->solve.size(), 3u);
  EXPECT_EQ(w.windowSize(), 0u);
  EXPECT_FALSE(w.endIdleWindow(200.0));  // nothing open
  // The frames of the ended window stay out of the next one, even when their mode comes late.
  w.addMode({frame(3), true, true, 7}, 201.0);
  w.addObservation(board(3), frame(3), 201.0);
  EXPECT_EQ(w.windowSize(), 1u);
}

TEST(CalibrationWindows, AnIdleWindowSaysWhyItIsNotSolved) {
  const auto idleEnd = [](CalibrationWindowOptions o, int frames) {
    CalibrationWindows w(o);
    for (int i = 0; i < frames; ++i) addFrame(&w, i, true);
    const std::optional<IdleWindow> idle = w.endIdleWindow(10.0);
    EXPECT_TRUE(idle);
    EXPECT_TRUE(!idle || idle->end == IdleWindowEnd::kSolving || idle->solve.empty());
    return idle ? idle->end : IdleWindowEnd::kSolving;
  };
  EXPECT_EQ(idleEnd(options(3), 2), IdleWindowEnd::kTooFewFrames);
  CalibrationWindowOptions off = options(1);
  off.auto_calibrate = false;
  EXPECT_EQ(idleEnd(off, 2), IdleWindowEnd::kAutoCalibrateOff);
  CalibrationWindowOptions bursts = options(1);
  bursts.window_observations = true;
  EXPECT_EQ(idleEnd(bursts, 2), IdleWindowEnd::kWindowObservationsInstead);
}

TEST(CalibrationWindows, ATimeJumpBackForgetsEverythingAndStartsOver) {
  CalibrationWindows w(options(2));
  for (int i = 100; i < 103; ++i) addFrame(&w, i, true);
  EXPECT_EQ(w.windowSize(), 3u);
  // Back by more than the stamp tolerance (2 s): another timeline.
  const ModeResult jump = w.addMode({frame(0), true, true, 7}, 0.0);
  ASSERT_TRUE(jump.time_jump_from);
  EXPECT_EQ(*jump.time_jump_from, frame(102));
  EXPECT_EQ(jump.kind, ModeResult::Kind::kCurrent);
  EXPECT_EQ(w.windowSize(), 0u);
  EXPECT_EQ(w.frames().size(), 1u);
  // The observation stamps start over too: frame 0's observation is taken.
  EXPECT_EQ(w.addObservation(board(0), frame(0), 0.0), ObservationFate::kMatched);
  addFrame(&w, 1, true);
  const ModeResult off = addFrame(&w, 2, false);
  ASSERT_TRUE(off.solve);
  EXPECT_EQ(off.solve->size(), 2u);
}

TEST(CalibrationWindows, AModeLessFarBackIsLateItNeitherRestartsNorClosesTheWindow) {
  CalibrationWindows w(options(1));
  addFrame(&w, 10, true);
  addFrame(&w, 12, true);
  // Frame 11's mode comes late (light off: it says nothing about the light now).
  const ModeResult late = w.addMode({frame(11), false, false, 6}, 0.0);
  EXPECT_EQ(late.kind, ModeResult::Kind::kLate);
  EXPECT_FALSE(late.time_jump_from);
  EXPECT_FALSE(late.solve);
  EXPECT_EQ(w.windowSize(), 2u);
  ASSERT_EQ(w.frames().size(), 3u);
  EXPECT_EQ(w.frames()[1].stamp, frame(11));  // kept in stamp order
  EXPECT_EQ(w.frames().back().epoch, 7u);
}

TEST(CalibrationWindows, ARequestCollectsItsOwnFramesAndTheLightGoingOffDoesNotCloseIt) {
  CalibrationWindows w(options(3, 30));
  addFrame(&w, 0, true);  // an automatic window was open: dropped
  w.startRequest(2);
  EXPECT_EQ(w.windowSize(), 0u);
  EXPECT_FALSE(w.requestFull());
  EXPECT_FALSE(addFrame(&w, 1, false).solve);  // light off before it came on: nothing closes
  addFrame(&w, 2, true);
  addFrame(&w, 3, true);
  addFrame(&w, 4, true);  // beyond the request's frames
  EXPECT_TRUE(w.requestFull());
  EXPECT_FALSE(w.endIdleWindow(1000.0));  // a request's window never idles out
  const std::vector<StereoObservation> frames = w.endRequest();
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_DOUBLE_EQ(frames.front().stamp, 0.3);  // frame 2
  EXPECT_FALSE(w.requestFull());
  w.requestDone();
  // Frames up to the newest one belong to the finished request, also when matched late.
  w.addMode({frame(5), true, true, 7}, 0.0);
  EXPECT_EQ(w.windowSize(), 0u);
  w.addObservation(board(5), frame(5), 0.0);
  EXPECT_EQ(w.windowSize(), 1u);
}

TEST(CalibrationWindows, WindowObservationsAreSolvedOnceEachAndInStampOrder) {
  CalibrationWindowOptions o = options();
  o.window_observations = true;
  CalibrationWindows w(o);
  std::optional<StereoObservation> solve;
  EXPECT_EQ(w.addWindowObservation(board(1), frame(1), &solve), WindowObservationFate::kSolve);
  ASSERT_TRUE(solve);
  solve.reset();
  // A copy (whatever its stamp) teaches nothing; an older stamp is a replayed source.
  EXPECT_EQ(w.addWindowObservation(board(1), frame(5), &solve), WindowObservationFate::kRepeated);
  StampNs previous = 0;
  EXPECT_EQ(w.addWindowObservation(board(2), frame(0), &solve, &previous), WindowObservationFate::kBackwards);
  EXPECT_EQ(previous, frame(1));
  EXPECT_FALSE(solve);
  EXPECT_EQ(w.backwards(), 1u);
  EXPECT_EQ(w.windowObservations(), 1u);
  EXPECT_EQ(w.addWindowObservation(StereoObservation{}, frame(6), &solve), WindowObservationFate::kIgnored);
  // The per-frame windows are not solved.
  for (int i = 10; i < 15; ++i) addFrame(&w, i, true);
  EXPECT_FALSE(addFrame(&w, 15, false).solve);
}

TEST(CalibrationWindows, ARequestTakesItsBurstsWindowObservation) {
  CalibrationWindowOptions o = options();
  o.window_observations = true;
  CalibrationWindows w(o);
  addFrame(&w, 10, false);
  w.startRequest(3);
  std::optional<StereoObservation> solve;
  // Stamped before the request started: an automatic window's.
  EXPECT_EQ(w.addWindowObservation(board(1), frame(9), &solve), WindowObservationFate::kSolve);
  EXPECT_FALSE(w.hasRequestWindow());
  EXPECT_EQ(w.addWindowObservation(board(2), frame(12), &solve), WindowObservationFate::kForRequest);
  EXPECT_TRUE(w.hasRequestWindow());
  const std::optional<StereoObservation> taken = w.takeRequestWindow();
  ASSERT_TRUE(taken);
  EXPECT_FLOAT_EQ(taken->left.front().u.front(), 12.0f);
  EXPECT_FALSE(w.hasRequestWindow());
  // No longer waited for: the next one is an automatic window again.
  EXPECT_EQ(w.addWindowObservation(board(3), frame(13), &solve), WindowObservationFate::kSolve);
  CalibrationWindowOptions off = o;
  off.auto_calibrate = false;
  CalibrationWindows manual(off);
  EXPECT_EQ(manual.addWindowObservation(board(4), frame(1), &solve), WindowObservationFate::kIgnored);
}

TEST(CalibrationWindows, TheNewestHealthVerdictBelowGoodIsKept) {
  CalibrationWindows w(options());
  EXPECT_FALSE(w.healthProblemS());
  w.noteHealthVerdict(false, 5.0);  // GOOD: nothing changed
  EXPECT_FALSE(w.healthProblemS());
  w.noteHealthVerdict(true, 10.0);
  w.noteHealthVerdict(true, 8.0);  // an older one does not move it back
  ASSERT_TRUE(w.healthProblemS());
  EXPECT_EQ(*w.healthProblemS(), 10.0);
}

TEST(CalibrationWindows, StampSecondsRoundsAsRosTimeDoes) {
  const StampNs stamp = 1700000000LL * 1000000000LL + 123456789LL;
  EXPECT_EQ(stampSeconds(stamp), 1700000000.0 + 1e-9 * 123456789.0);
  EXPECT_EQ(stampSeconds(0), 0.0);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
