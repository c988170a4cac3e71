// FrameStampGate (which calibration_mode messages join a synchroniser). Each scenario is written
// out by hand, frame by frame: the expected fate of every message follows from the stamps of
// the images around it, not from the gate's code. A "message" here is a counter that its release
// increments, so a message passed twice, or both passed at once and released, shows.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "embedded_calibration_stereo/ros/frame_stamp_gate.h"

namespace ecsr = embedded_calibration_stereo;
using Verdict = ecsr::FrameStampGate::Verdict;

namespace {

constexpr double kPeriod = 1.0 / 30;

struct Harness {
  explicit Harness(size_t held_per_input = 4)
      : gate({"/left", "/right", "/mode"}, "owner", held_per_input,
             [this](const std::string& w) { warnings.push_back(w); }, [this] { return now; }) {}
  double now = 50.0;
  std::vector<std::string> warnings;
  // Inputs as LazySyncedInput gives them: left image, right image, calibration_mode (index 2).
  ecsr::FrameStampGate gate;
  int passed_later = 0;  // messages released after being held

  Verdict mode(double t, const std::string& publisher = "/driver") {
    return gate.offer(2, ros::Time(t), publisher, [this] { ++passed_later; });
  }
  // Both images of a frame; returns how many held messages they released.
  int images(double t) {
    int released = 0;
    for (int side = 0; side < 2; ++side)
      for (const auto& release : gate.image(ros::Time(t))) {
        release();
        ++released;
      }
    return released;
  }
};

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

}  // namespace

TEST(FrameStampGate, ADriversModeJoinsItsFrameWhetherItComesBeforeOrAfterTheImages) {
  Harness h;
  for (int i = 0; i < 10; ++i) {
    const double t = 1000.0 + i * kPeriod;
    if (i % 2 == 0) {  // images first: the mode goes on at once
      EXPECT_EQ(h.images(t), 0);
      EXPECT_EQ(h.mode(t), Verdict::kPass) << "frame " << i;
    } else {  // mode first: held, then released by the frame's first image, once
      EXPECT_EQ(h.mode(t), Verdict::kHold) << "frame " << i;
      EXPECT_EQ(h.images(t), 1) << "frame " << i;
    }
  }
  EXPECT_EQ(h.passed_later, 5);
  EXPECT_EQ(h.gate.dropped(), 0u);
  EXPECT_TRUE(h.warnings.empty());
}

TEST(FrameStampGate, ModesStampedAheadOfTheImagesWaitBoundedAndNeverPushOutTheFramesOwn) {
  Harness h;
  h.images(1000.0);
  // Every frame: the driver's mode for the next frame arrives before its images, among 6 rogue
  // messages stamped 0.5-1.9 s ahead (as many as held_per_input and more), between frames'
  // stamps (one at a frame's own stamp would take that frame's place: a cost of the rogue frames).
  int rogue = 0;
  for (int i = 1; i <= 60; ++i) {
    const double t = 1000.0 + i * kPeriod;
    for (int k = 0; k < 3; ++k) EXPECT_NE(h.mode(t + 0.507 + 0.23 * ((i * 3 + k) % 7), "/rogue"), Verdict::kPass);
    EXPECT_EQ(h.mode(t), Verdict::kHold) << "frame " << i;
    for (int k = 3; k < 6; ++k) EXPECT_NE(h.mode(t + 0.507 + 0.23 * ((i * 3 + k) % 7), "/rogue"), Verdict::kPass);
    rogue += 6;
    EXPECT_EQ(h.images(t), 1) << "the driver's mode of frame " << i << " was not released with its images";
    h.now += kPeriod;
  }
  EXPECT_EQ(h.passed_later, 60) << "only the driver's modes went on";
  // At most held_per_input (4) rogue messages are held at the end; all the others were dropped.
  EXPECT_GE(h.gate.dropped(), static_cast<uint64_t>(rogue - 4));
  ASSERT_FALSE(h.warnings.empty());
  EXPECT_TRUE(contains(h.warnings[0], "/mode")) << h.warnings[0];
  EXPECT_TRUE(contains(h.warnings[0], "/rogue")) << h.warnings[0];
  EXPECT_TRUE(contains(h.warnings[0], "owner")) << h.warnings[0];
  EXPECT_LE(h.warnings.size(), 1u + static_cast<size_t>(60 * kPeriod / ecsr::FrameStampGate::kWarnPeriodS))
      << "throttled per input";
}

TEST(FrameStampGate, ModesAtStampsNoImageHasAreDroppedOnceLaterFramesArrive) {
  // A rogue stream stamped with the clock: just ahead of the frame being delivered, never equal;
  // two per frame: two frame periods of it and a frame's own message fit in 5 held.
  Harness h(5);
  for (int i = 0; i < 30; ++i) {
    const double t = 1000.0 + i * kPeriod;
    h.images(t);
    EXPECT_EQ(h.mode(t), Verdict::kPass);
    EXPECT_NE(h.mode(t + 0.011, "/rogue"), Verdict::kPass);
    EXPECT_NE(h.mode(t + 0.022, "/rogue"), Verdict::kPass);
  }
  // Everything older than the two latest frames is gone; what is held is ahead of the second latest.
  EXPECT_GE(h.gate.dropped(), 2u * 30 - 5);
  EXPECT_EQ(h.passed_later, 0);
  // The stream held nothing that keeps the next frame's mode, arriving before its images, out.
  EXPECT_EQ(h.mode(1000.0 + 30 * kPeriod), Verdict::kHold);
  EXPECT_EQ(h.images(1000.0 + 30 * kPeriod), 1);
  // A mode older than the two latest frames, whose stamp no image had, is dropped at once.
  EXPECT_EQ(h.mode(1000.0 + 28.5 * kPeriod, "/late"), Verdict::kDrop);
}

TEST(FrameStampGate, ASecondModeForAFrameIsDroppedWithItsPublisherNamed) {
  Harness h;
  h.images(1000.0);
  EXPECT_EQ(h.mode(1000.0), Verdict::kPass);
  EXPECT_EQ(h.mode(1000.0, "/copy"), Verdict::kDrop);
  // Two held for one future frame: only the first is released.
  EXPECT_EQ(h.mode(1000.0 + kPeriod), Verdict::kHold);
  EXPECT_EQ(h.mode(1000.0 + kPeriod, "/copy"), Verdict::kDrop);
  EXPECT_EQ(h.images(1000.0 + kPeriod), 1);
  EXPECT_EQ(h.gate.dropped(), 2u);
  ASSERT_EQ(h.warnings.size(), 1u) << "throttled";
  EXPECT_TRUE(contains(h.warnings[0], "/copy")) << h.warnings[0];
  EXPECT_TRUE(contains(h.warnings[0], "second message")) << h.warnings[0];
}

TEST(FrameStampGate, AResetForgetsFramesAndHeldModes) {
  Harness h;
  h.images(1000.0);
  EXPECT_EQ(h.mode(1000.0 + kPeriod), Verdict::kHold);
  h.gate.reset();
  EXPECT_EQ(h.images(1000.0 + kPeriod), 0) << "a held mode survived the reset";
  // A replayed bag: earlier stamps are new frames after a reset.
  h.gate.reset();
  h.images(900.0);
  EXPECT_EQ(h.mode(900.0), Verdict::kPass);
}
