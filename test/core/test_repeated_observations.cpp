// RepeatedObservations (the calibrator's filter of copied window observations): copies are
// recognised whatever their stamp; any change of a corner, an id or a scene match, or a board
// moved from one camera to the other, makes another observation; the memory is bounded.
#include <gtest/gtest.h>

#include "embedded_calibration_stereo/core/calibration/repeated_observations.h"

namespace core = embedded_calibration_stereo::core;

namespace {

core::StereoObservation window(float shift) {
  core::StereoObservation o;
  o.stamp = 10.0;
  core::BoardCorners b;
  b.board_id = 3;
  for (int i = 0; i < 12; ++i) {
    b.corner_ids.push_back(i);
    b.u.push_back(100.0f + 10.0f * i + shift);
    b.v.push_back(200.0f + 5.0f * i);
  }
  o.left.push_back(b);
  b.board_id = 4;
  o.right.push_back(b);
  o.scene.push_back({300.0f, 100.0f, 280.0f, 100.5f});
  return o;
}

}  // namespace

TEST(RepeatedObservations, ACopyIsRecognisedWhateverItsStamp) {
  core::RepeatedObservations recent;
  core::StereoObservation first = window(0.0f);
  EXPECT_FALSE(recent.repeats(first));
  first.stamp = 10.001;  // republished 1 ms later
  EXPECT_TRUE(recent.repeats(first));
}

TEST(RepeatedObservations, AnyChangeOfContentIsAnotherObservation) {
  const core::StereoObservation base = window(0.0f);
  std::vector<core::StereoObservation> variants(6, base);
  variants[0].left[0].u[5] += 0.001f;  // one coordinate, a thousandth of a pixel
  variants[1].right[0].v[0] -= 0.5f;
  variants[2].left[0].corner_ids[2] = 40;
  variants[3].left[0].board_id = 5;
  variants[4].scene[0].right_u += 1.0f;
  std::swap(variants[5].left, variants[5].right);  // boards seen by the other camera
  for (size_t i = 0; i < variants.size(); ++i) {
    core::RepeatedObservations recent;
    ASSERT_FALSE(recent.repeats(base));
    EXPECT_FALSE(recent.repeats(variants[i])) << "variant " << i;
  }
}

TEST(RepeatedObservations, RemembersTheLastCapacityObservations) {
  core::RepeatedObservations recent(3);
  for (int i = 0; i < 4; ++i) EXPECT_FALSE(recent.repeats(window(static_cast<float>(i))));
  EXPECT_TRUE(recent.repeats(window(3.0f)));
  EXPECT_TRUE(recent.repeats(window(1.0f)));
  EXPECT_FALSE(recent.repeats(window(0.0f))) << "the oldest was forgotten";
}
