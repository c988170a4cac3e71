// GroundTruthPairing (tracker_teaching.h): the PatternTracker's test-only teaching pairs the
// latest light-on frames with the simulator's scenes of the same stamp, whichever came first.
#include <gtest/gtest.h>

#include <boost/make_shared.hpp>

#include "embedded_calibration_stereo/ros/tracker_teaching.h"

namespace ecsr = embedded_calibration_stereo;
using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

namespace {

ImageConstPtr stamped(double t) {
  auto m = boost::make_shared<Image>();
  m->header.stamp = ros::Time(t);
  return m;
}

ecsr::StereoImages pair(double t) { return {stamped(t), stamped(t)}; }

TEST(GroundTruthPairing, TheNewestLightOnFrameWhoseTwoScenesCameIsTaughtOn) {
  ecsr::GroundTruthPairing p;
  const ecsr::StereoImages first = pair(1), second = pair(2);
  p.addLightOn(first);
  p.addLightOn(second);
  EXPECT_FALSE(p.newest());
  const ImageConstPtr left1 = stamped(1), right1 = stamped(1), left2 = stamped(2);
  p.addScene(0, left1);
  p.addScene(0, left2);
  EXPECT_FALSE(p.newest()) << "no right scene yet";
  p.addScene(1, right1);
  auto match = p.newest();
  ASSERT_TRUE(match);
  EXPECT_EQ(match->light_on.first, first.first);
  EXPECT_EQ(match->scene.first, left1);
  EXPECT_EQ(match->scene.second, right1);
  const ImageConstPtr right2 = stamped(2);
  p.addScene(1, right2);
  match = p.newest();
  ASSERT_TRUE(match);
  EXPECT_EQ(match->light_on.second, second.second);
  EXPECT_EQ(match->scene.second, right2);
  p.clear();
  EXPECT_FALSE(p.newest());
}

TEST(GroundTruthPairing, KeepsOnlyTheLatestFramesOfEachKind) {
  ecsr::GroundTruthPairing p;
  p.addLightOn(pair(0));
  for (size_t i = 1; i <= ecsr::GroundTruthPairing::kKept; ++i) p.addLightOn(pair(100 + i));
  p.addScene(0, stamped(0));
  p.addScene(1, stamped(0));
  EXPECT_FALSE(p.newest()) << "the light-on frame of stamp 0 was dropped";
  p.addLightOn(pair(0));
  EXPECT_TRUE(p.newest());
  for (size_t i = 1; i <= ecsr::GroundTruthPairing::kKept; ++i) p.addScene(1, stamped(200 + i));
  EXPECT_FALSE(p.newest()) << "the right scene of stamp 0 was dropped";
}

}  // namespace
