// The drivers' small decisions, ROS-free: which input holds the LightController's frames back
// (InputArrivalWatch), when the CameraDriver takes its next frame (FramePacer) and when it marks
// a calibration verified GOOD (VerifiedMarking).
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>

#include "embedded_calibration_stereo/core/driver/frame_pacer.h"
#include "embedded_calibration_stereo/core/driver/input_arrivals.h"
#include "embedded_calibration_stereo/core/calibration/verified_marking.h"

namespace core = embedded_calibration_stereo::core;

namespace {

core::InputArrivalWatch fourInputs() {
  return core::InputArrivalWatch({"image on /l", "camera_info on /li", "image on /r", "camera_info on /ri"},
                                "they do not pair");
}

}  // namespace

TEST(InputArrivalWatch, NamesTheInputsSilentOverAPeriodWithoutFrames) {
  core::InputArrivalWatch watch = fourInputs();
  EXPECT_EQ(watch.tick(), "") << "nothing arrived at all: the driver has not started, nothing to name";
  watch.arrived(0);
  watch.arrived(2);
  watch.arrived(2);
  EXPECT_EQ(watch.tick(), "no camera_info on /li, no camera_info on /ri");
  watch.arrived(0);
  watch.arrived(1);
  watch.arrived(2);
  EXPECT_EQ(watch.tick(), "no camera_info on /ri") << "each period on its own arrivals";
}

TEST(InputArrivalWatch, SaysTheInputsDoNotPairWhenAllArriveButNoFrame) {
  core::InputArrivalWatch watch = fourInputs();
  for (size_t i = 0; i < 4; ++i) watch.arrived(i);
  EXPECT_EQ(watch.tick(), "they do not pair");
}

TEST(InputArrivalWatch, NothingIsMissingWhileFramesComeIn) {
  core::InputArrivalWatch watch = fourInputs();
  watch.arrived(0);
  watch.arrived(2);
  watch.frameIn();
  EXPECT_EQ(watch.tick(), "") << "a frame came in over the period";
  EXPECT_EQ(watch.framesIn(), 1u);
  watch.arrived(0);
  EXPECT_EQ(watch.tick(), "no camera_info on /li, no image on /r, no camera_info on /ri")
      << "the previous period's frame does not count for this one";
}

TEST(FramePacer, KeepsTheCadenceThroughSmallDelays) {
  using Clock = core::FramePacer::Clock;
  const Clock::time_point start{};
  const auto period = std::chrono::milliseconds(100);
  core::FramePacer pacer(10.0, start);
  EXPECT_EQ(pacer.next(start + std::chrono::milliseconds(20)), start + period);
  // The frame finished 50 ms late: the next one is still on the grid (a shorter wait).
  EXPECT_EQ(pacer.next(start + std::chrono::milliseconds(150)), start + 2 * period);
  EXPECT_EQ(pacer.next(start + std::chrono::milliseconds(290)), start + 3 * period);
}

TEST(FramePacer, RestartsTheCadenceAfterAStallInsteadOfCatchingUp) {
  using Clock = core::FramePacer::Clock;
  const Clock::time_point start{};
  core::FramePacer pacer(10.0, start);
  pacer.next(start);
  // Stalled for a second: the next frame at once, then every period from there, not ten frames
  // back to back.
  const Clock::time_point late = start + std::chrono::milliseconds(1000);
  EXPECT_EQ(pacer.next(late), late);
  EXPECT_EQ(pacer.next(late + std::chrono::milliseconds(10)), late + std::chrono::milliseconds(100));
}

TEST(VerifiedMarking, OnlyGoodByAVerificationAgainstTheBoardsAndOncePerEpoch) {
  core::VerifiedMarking marking;
  EXPECT_FALSE(marking.due(false, 1.0, 3)) << "not GOOD";
  EXPECT_FALSE(marking.due(true, -1.0, 3)) << "GOOD by the scene rows alone (no verification)";
  EXPECT_FALSE(marking.due(true, std::nan(""), 3)) << "no verification age";
  EXPECT_TRUE(marking.due(true, 0.0, 3));
  marking.done(3);
  EXPECT_FALSE(marking.due(true, 2.0, 3)) << "the same epoch twice";
  EXPECT_TRUE(marking.due(true, 2.0, 4)) << "a new epoch";
}
