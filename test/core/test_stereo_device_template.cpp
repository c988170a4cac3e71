// stereo_device_template.h: which frames the Separator separates, how a taught template is
// averaged (epochs, scenes), which frames score a learned one, when the burst under way is learned
// from and when a learned template replaces the one in use.
#include <gtest/gtest.h>

#include <stdexcept>

#include "embedded_calibration_stereo/core/depth/stereo_device_template.h"

namespace embedded_calibration_stereo::core {
namespace {

cv::Mat grey(double value, int size = 64) { return cv::Mat(size, size, CV_8UC1, cv::Scalar(value)); }

std::shared_ptr<const StereoSeparator> separatorOfEpoch(uint32_t epoch) {
  DeviceTemplate t;
  t.device = cv::Mat(64, 64, CV_32FC1, cv::Scalar(10.0));
  t.calibration_epoch = epoch;
  return std::make_shared<const StereoSeparator>(SeparatorOptions(), t, t);
}

TEST(SceneRoute, OnlySettledLightOnFramesWithAFittingTemplateAreSeparated) {
  const auto s = separatorOfEpoch(3);
  EXPECT_EQ(routeFrame(false, true, s.get(), 3, true), SceneRoute::kLightOff);
  EXPECT_EQ(routeFrame(false, false, s.get(), 3, true), SceneRoute::kLightOff);
  EXPECT_EQ(routeFrame(true, false, s.get(), 3, true), SceneRoute::kLightChanging);
  EXPECT_EQ(routeFrame(true, true, nullptr, 3, true), SceneRoute::kNoTemplate);
  EXPECT_EQ(routeFrame(true, true, s.get(), 4, true), SceneRoute::kOtherEpoch);
  EXPECT_EQ(routeFrame(true, true, s.get(), 4, false), SceneRoute::kSeparate);  // learned: stays in use
  EXPECT_EQ(routeFrame(true, true, s.get(), 3, true), SceneRoute::kSeparate);
}

TEST(StereoTemplateTeach, AveragesTheFramesMinusTheirScenesIntoBothTemplates) {
  StereoTemplateTeach teach(3, SeparatorOptions());
  EXPECT_FALSE(teach.active());
  teach.start();
  EXPECT_TRUE(teach.active());
  EXPECT_FALSE(teach.add(grey(10), grey(40), cv::Mat(), grey(30), 5).taught);
  EXPECT_FALSE(teach.add(grey(20), grey(50), cv::Mat(), grey(30), 5).taught);
  const StereoTemplateTeach::Step step = teach.add(grey(30), grey(60), cv::Mat(), grey(30), 5);
  ASSERT_TRUE(step.taught);
  EXPECT_FALSE(teach.active());
  EXPECT_EQ(step.taught->epoch(), 5u);
  EXPECT_EQ(step.taught->left.deviceTemplate().frames_averaged, 3);
  EXPECT_NEAR(cv::mean(step.taught->left.deviceTemplate().device)[0], 20.0, 1e-9);
  EXPECT_NEAR(cv::mean(step.taught->right.deviceTemplate().device)[0], 20.0, 1e-9);  // 50 - 30
}

TEST(StereoTemplateTeach, AFrameOfAnotherEpochStartsTheTeachOver) {
  StereoTemplateTeach teach(2, SeparatorOptions());
  teach.start();
  EXPECT_FALSE(teach.add(grey(100), grey(100), cv::Mat(), cv::Mat(), 1).restarted);
  EXPECT_EQ(teach.epoch(), 1u);
  const StereoTemplateTeach::Step moved = teach.add(grey(10), grey(10), cv::Mat(), cv::Mat(), 2);
  EXPECT_TRUE(moved.restarted);
  EXPECT_FALSE(moved.taught);  // one frame of epoch 2 so far
  const StereoTemplateTeach::Step done = teach.add(grey(20), grey(20), cv::Mat(), cv::Mat(), 2);
  ASSERT_TRUE(done.taught);
  EXPECT_EQ(done.taught->epoch(), 2u);
  EXPECT_NEAR(cv::mean(done.taught->left.deviceTemplate().device)[0], 15.0, 1e-9);  // epoch 1's frame left out
}

TEST(StereoTemplateTeach, ATeachForAnEpochStartsOnceAndEndsOnAFrameThatDoesNotFit) {
  StereoTemplateTeach teach(3, SeparatorOptions());
  EXPECT_TRUE(teach.startFor(4));
  teach.add(grey(10), grey(10), cv::Mat(), cv::Mat(), 4);
  EXPECT_FALSE(teach.startFor(4));  // under way: its frame is kept
  EXPECT_TRUE(teach.startFor(5));
  EXPECT_EQ(teach.epoch(), 5u);
  teach.add(grey(10), grey(10), cv::Mat(), cv::Mat(), 5);
  EXPECT_THROW(teach.add(grey(10, 32), grey(10, 32), cv::Mat(), cv::Mat(), 5), std::invalid_argument);
  EXPECT_FALSE(teach.active());
}

TEST(MiddleFrames, TheFramesALearnedTemplateDidNotSeeAtMostThreeEvenlySpaced) {
  WindowFrames frames;
  for (int i = 0; i < 20; ++i) frames.light_on.push_back(grey(i));
  const std::vector<cv::Mat> middle = middleFrames(frames, 4);  // frames 4..15 were not learned from
  ASSERT_EQ(middle.size(), 3u);
  EXPECT_EQ(middle[0].data, frames.light_on[4].data);
  EXPECT_EQ(middle[1].data, frames.light_on[8].data);
  EXPECT_EQ(middle[2].data, frames.light_on[12].data);
  frames.light_on.resize(8);
  EXPECT_EQ(middleFrames(frames, 4).size(), 8u);  // no middle: all of them
}

TEST(DeviceLearningPlan, TheFirstBurstIsLearnedFromItsFirstFramesOnceOnly) {
  DeviceLearningPlan plan(4);
  EXPECT_FALSE(plan.learnUnderWay(7, true));
  EXPECT_TRUE(plan.learnUnderWay(8, true));
  EXPECT_FALSE(plan.learnUnderWay(9, true));  // started at 8
  EXPECT_FALSE(plan.learnUnderWay(8, false));  // no light-off frame before it
  plan.adopted();
  EXPECT_FALSE(plan.learnUnderWay(8, true));
}

TEST(DeviceLearningPlan, ALearnedTemplateReplacesTheOneInUseUnlessItSeparatesTheBurstWorse) {
  DeviceLearningPlan plan(4);
  StereoLearnResult result;
  result.separator = separatorOfEpoch(0);
  result.residual_new = 9.0;
  result.residual_in_use = 5.0;
  EXPECT_TRUE(plan.adopt(result));  // no template in use yet
  plan.adopted();
  EXPECT_FALSE(plan.adopt(result));
  result.residual_new = 5.0;
  EXPECT_TRUE(plan.adopt(result));
  result.residual_new = 1.0;
  EXPECT_TRUE(plan.adopt(result));
  result.residual_in_use = result.residual_new = -1.0;  // not scored
  EXPECT_TRUE(plan.adopt(result));
  result.error = "left: too few pairs";
  EXPECT_FALSE(plan.adopt(result));
}

TEST(LearnStereoDevice, SaysWhichCameraCouldNotBeLearned) {
  WindowFrames left, right;
  left.light_on = {grey(10)};  // no light-off frame: no pair
  right.light_on = {grey(10)};
  right.light_off_before = {grey(5)};
  right.light_off_after = {grey(5)};
  const StereoLearnResult result =
      learnStereoDevice(left, right, true, 4, separatorLearnerOptions(), SeparatorOptions(), nullptr, 0);
  EXPECT_EQ(result.error.rfind("left: ", 0), 0u) << result.error;
  EXPECT_FALSE(result.separator);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
