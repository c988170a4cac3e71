// LightBurstCollector (the frames of one light burst for the PatternTracker's window tracking):
// sequences of settled frames written out by hand; what each burst must hold follows from the
// sequence (which message came where), checked by pointer identity (no copies).
#include <gtest/gtest.h>

#include <boost/make_shared.hpp>

#include <string>
#include <vector>

#include "embedded_calibration_stereo/ros/light_burst.h"

namespace core = embedded_calibration_stereo::core;

namespace ecsr = embedded_calibration_stereo;
using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

namespace {

ImageConstPtr image(int seq, const std::string& encoding = "mono8", uint32_t width = 8) {
  auto m = boost::make_shared<Image>();
  m->header.seq = seq;
  m->encoding = encoding;
  m->width = width;
  m->height = 4;
  return m;
}

struct Frame {
  ImageConstPtr left, right;
  bool light_on;
  uint32_t epoch;
};

Frame frame(int seq, bool light_on, uint32_t epoch = 0, const std::string& encoding = "mono8", uint32_t width = 8) {
  return {image(seq, encoding, width), image(seq, encoding, width), light_on, epoch};
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// Feeds the frames; the bursts they ended, in order.
std::vector<ecsr::EndedBurst> feed(ecsr::LightBurstCollector* c, const std::vector<Frame>& frames) {
  std::vector<ecsr::EndedBurst> ended;
  for (const Frame& f : frames)
    if (auto e = c->add(f.left, f.right, f.light_on)) ended.push_back(std::move(*e));
  return ended;
}

}  // namespace

TEST(LightBurst, KeepsTheLitFramesAndTheLastLightOffFrameBeforeAndTheFirstAfterWithoutCopies) {
  ecsr::LightBurstCollector c(3);
  std::vector<Frame> frames = {frame(0, false), frame(1, false), frame(2, true), frame(3, true), frame(4, true),
                               frame(5, true), frame(6, false), frame(7, false)};
  const auto ended = feed(&c, frames);
  ASSERT_EQ(ended.size(), 1u);
  const ecsr::EndedBurst& e = ended[0];
  EXPECT_EQ(e.problem, "");
  EXPECT_EQ(e.light_on_frames, 4);
  EXPECT_EQ(e.burst.light_off_before.first, frames[1].left);
  EXPECT_EQ(e.burst.light_off_before.second, frames[1].right);
  EXPECT_EQ(e.burst.light_off_after.first, frames[6].left);
  EXPECT_EQ(e.burst.light_off_after.second, frames[6].right);
  ASSERT_EQ(e.burst.light_on.size(), 4u);
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(e.burst.light_on[i].first, frames[2 + i].left) << i;
    EXPECT_EQ(e.burst.light_on[i].second, frames[2 + i].right) << i;
  }
}

TEST(LightBurst, AShortFlashGivesNothingAndItsLightOffFrameStartsTheNextBurst) {
  ecsr::LightBurstCollector c(3);
  // A 1-frame flash, a 2-frame one (still under 3), then a burst of 3.
  std::vector<Frame> frames = {frame(0, false), frame(1, true), frame(2, false), frame(3, true), frame(4, true),
                               frame(5, false), frame(6, false), frame(7, true), frame(8, true), frame(9, true),
                               frame(10, false)};
  const auto ended = feed(&c, frames);
  ASSERT_EQ(ended.size(), 1u);
  EXPECT_EQ(ended[0].problem, "");
  EXPECT_EQ(ended[0].light_on_frames, 3);
  EXPECT_EQ(ended[0].burst.light_off_before.first, frames[6].left);
  EXPECT_EQ(ended[0].burst.light_off_after.first, frames[10].left);
  ASSERT_EQ(ended[0].burst.light_on.size(), 3u);
  EXPECT_EQ(ended[0].burst.light_on[0].first, frames[7].left);
}

TEST(LightBurst, ConsecutiveBurstsEachStartFromTheLastLightOffFrameBeforeThem) {
  ecsr::LightBurstCollector c(3);
  std::vector<Frame> frames = {frame(0, false), frame(1, true),  frame(2, true),  frame(3, true),
                               frame(4, false), frame(5, false), frame(6, true),  frame(7, true),
                               frame(8, true),  frame(9, false), frame(10, true), frame(11, true),
                               frame(12, true), frame(13, false)};
  const auto ended = feed(&c, frames);
  ASSERT_EQ(ended.size(), 3u);
  const int before[3] = {0, 5, 9}, after[3] = {4, 9, 13}, first_lit[3] = {1, 6, 10};
  for (int b = 0; b < 3; ++b) {
    EXPECT_EQ(ended[b].problem, "") << b;
    EXPECT_EQ(ended[b].burst.light_off_before.first, frames[before[b]].left) << b;
    EXPECT_EQ(ended[b].burst.light_off_after.first, frames[after[b]].left) << b;
    ASSERT_EQ(ended[b].burst.light_on.size(), 3u) << b;
    EXPECT_EQ(ended[b].burst.light_on[0].first, frames[first_lit[b]].left) << b;
  }
}

// The burst under way, as the Separator reads it to learn within a first burst: the light-off
// frame before it and the light-on frames so far; nothing between bursts or for a burst that
// will be dropped.
TEST(LightBurst, TheBurstUnderWayHoldsItsFramesSoFar) {
  ecsr::LightBurstCollector c(3);
  const std::vector<Frame> frames = {frame(0, false), frame(1, true), frame(2, true)};
  feed(&c, frames);
  ecsr::LightBurst now = c.underWay();
  EXPECT_EQ(now.light_off_before.first, frames[0].left);
  ASSERT_EQ(now.light_on.size(), 2u);
  EXPECT_EQ(now.light_on[1].second, frames[2].right);
  feed(&c, {frame(3, true), frame(4, false)});
  EXPECT_TRUE(c.underWay().light_on.empty()) << "between bursts";
  feed(&c, {frame(5, true, 0, "mono16")});
  EXPECT_TRUE(c.underWay().light_on.empty()) << "a burst that will be dropped";
}

// lightOnFramesKept counts what underWay() holds (the PatternTracker teaches on a burst under way
// once it has enough).
TEST(LightBurst, CountsTheLightOnFramesTheBurstUnderWayHolds) {
  ecsr::LightBurstCollector c(3);
  EXPECT_EQ(c.lightOnFramesKept(), 0);
  feed(&c, {frame(0, false), frame(1, true), frame(2, true)});
  EXPECT_EQ(c.lightOnFramesKept(), 2);
  EXPECT_EQ(c.lightOnFramesKept(), static_cast<int>(c.underWay().light_on.size()));
  feed(&c, {frame(3, false)});
  EXPECT_EQ(c.lightOnFramesKept(), 0);
  feed(&c, {frame(4, true), frame(5, true, 0, "mono16")});
  EXPECT_EQ(c.lightOnFramesKept(), 0) << "a burst that will be dropped";
}

// Reading a stereo frame for the tracker: the messages' own pixels, the colour order of rgb8, and
// why a frame cannot be read.
TEST(LightBurst, ReadsAStereoFrameWithoutCopyingOrSaysWhyNot) {
  auto colour = [](const std::string& encoding) {
    auto m = boost::make_shared<Image>();
    m->encoding = encoding;
    m->width = 4;
    m->height = 2;
    m->step = 12;
    m->data.assign(24, 7);
    return ImageConstPtr(m);
  };
  const ImageConstPtr left = colour("rgb8"), right = colour("rgb8");
  cv::Mat l, r;
  core::ColorOrder order = core::ColorOrder::kBgr;
  EXPECT_EQ(ecsr::readStereo(left, right, &l, &r, &order), "");
  EXPECT_EQ(l.data, left->data.data());
  EXPECT_EQ(r.data, right->data.data());
  EXPECT_EQ(order, core::ColorOrder::kRgb);
  EXPECT_TRUE(contains(ecsr::readStereo(left, colour("bgr8"), &l, &r, &order), "differ"));
  EXPECT_TRUE(contains(ecsr::readStereo(colour("yuv422"), colour("yuv422"), &l, &r, &order), "yuv422"));
  auto short_data = boost::make_shared<Image>(*left);
  short_data->data.resize(3);
  EXPECT_FALSE(ecsr::readStereo(short_data, short_data, &l, &r, &order).empty());
}

// A collector that does not need the light-off frame before (the Separator's: it may subscribe
// during a burst) keeps such a burst, with a null light_off_before; the default one drops it.
TEST(LightBurst, ABurstWithoutALightOffFrameBeforeIsKeptWhenAllowed) {
  const std::vector<Frame> frames = {frame(0, true), frame(1, true), frame(2, true), frame(3, false)};
  ecsr::LightBurstCollector strict(3), lenient(3, false);
  const auto dropped = feed(&strict, frames);
  ASSERT_EQ(dropped.size(), 1u);
  EXPECT_EQ(dropped[0].problem, "no settled light-off frame before it");
  const auto kept = feed(&lenient, frames);
  ASSERT_EQ(kept.size(), 1u);
  EXPECT_EQ(kept[0].problem, "");
  EXPECT_FALSE(kept[0].burst.light_off_before.first);
  EXPECT_EQ(kept[0].burst.light_off_after.first, frames[3].left);
  ASSERT_EQ(kept[0].burst.light_on.size(), 3u);
  EXPECT_EQ(kept[0].burst.light_on[0].first, frames[0].left);
}

// A commit during a burst (the calibration epoch changes) does not touch its images: kept whole.
TEST(LightBurst, ABurstAcrossACommitIsKept) {
  ecsr::LightBurstCollector c(3);
  const std::vector<Frame> frames = {frame(0, false, 4), frame(1, true, 4), frame(2, true, 4),
                                     frame(3, true, 6),  frame(4, true, 6), frame(5, false, 6)};
  const auto ended = feed(&c, frames);
  ASSERT_EQ(ended.size(), 1u);
  EXPECT_EQ(ended[0].problem, "");
  EXPECT_EQ(ended[0].light_on_frames, 4);
  ASSERT_EQ(ended[0].burst.light_on.size(), 4u);
  EXPECT_EQ(ended[0].burst.light_on[3].first, frames[4].left);
  EXPECT_EQ(ended[0].burst.light_off_before.first, frames[0].left);
  EXPECT_EQ(ended[0].burst.light_off_after.first, frames[5].left);
}

TEST(LightBurst, FramesOfDifferentSizesOrEncodingsAreDroppedWithTheReason) {
  struct Case {
    std::vector<Frame> frames;
    std::string reason;
  };
  Frame mixed = frame(3, true);
  mixed.right = image(3, "mono8", 16);
  const std::vector<Case> cases = {
      {{frame(0, false), frame(1, true), frame(2, true, 0, "mono8", 16), frame(3, true), frame(4, false)},
       "differ in size or encoding (mono8 16x4, the light-off frame before it mono8 8x4)"},
      {{frame(0, false), frame(1, true, 0, "bgr8"), frame(2, true, 0, "bgr8"), frame(3, true, 0, "bgr8"),
        frame(4, false)},
       "differ in size or encoding (bgr8 8x4, the light-off frame before it mono8 8x4)"},
      {{frame(0, false), frame(1, true), frame(2, true), frame(3, true), frame(4, false, 0, "mono8", 16)},
       "the light-off frame after it mono8 16x4"},
      {{frame(0, false), frame(1, true), frame(2, true), mixed, frame(4, false)}, "left and right differ"},
      {{frame(0, false, 0, "mono16"), frame(1, true, 0, "mono16"), frame(2, true, 0, "mono16"),
        frame(3, true, 0, "mono16"), frame(4, false, 0, "mono16")},
       "encoding 'mono16'"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    ecsr::LightBurstCollector c(3);
    const auto ended = feed(&c, cases[i].frames);
    ASSERT_EQ(ended.size(), 1u) << i;
    EXPECT_TRUE(contains(ended[0].problem, cases[i].reason)) << i << ": " << ended[0].problem;
    EXPECT_TRUE(ended[0].burst.light_on.empty()) << i;
  }
}

TEST(LightBurst, ABurstWithNoLightOffFrameBeforeItIsDropped) {
  ecsr::LightBurstCollector c(3);
  const auto ended = feed(&c, {frame(0, true), frame(1, true), frame(2, true), frame(3, false), frame(4, true),
                               frame(5, true), frame(6, true), frame(7, false)});
  ASSERT_EQ(ended.size(), 2u);
  EXPECT_TRUE(contains(ended[0].problem, "no settled light-off frame before it")) << ended[0].problem;
  EXPECT_EQ(ended[1].problem, "");  // the control: the light-off frame after the first one starts the second
}
