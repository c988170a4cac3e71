// TeachingPlan (teaching_plan.h): when the PatternTracker teaches its prior, on what, and what
// each light burst that ends is used for, written out case by case.
#include <gtest/gtest.h>

#include "embedded_calibration_stereo/core/tracker/teaching_plan.h"

namespace embedded_calibration_stereo::core {
namespace {

using Step = TeachingPlan::LightOnStep;
using Burst = TeachingPlan::BurstStep;
using Level = TeachingPlan::Level;

TeachingPlan tracking(TeachFrom from) {
  TeachingPlan plan(from);
  plan.tracking();
  return plan;
}

TEST(TeachingPlan, AMissingPriorIsTaughtAtStartOrLeavesTheTrackerIdle) {
  TeachingPlan teach(TeachFrom::kBurst);
  teach.priorMissing(true);
  EXPECT_TRUE(teach.teachRequested());
  EXPECT_TRUE(teach.needsInputs());
  EXPECT_EQ(teach.summary(false, "").level, Level::kWarn);
  EXPECT_EQ(teach.summary(false, "").text, "prior missing: teaching at the next light burst");

  TeachingPlan idle(TeachFrom::kBurst);
  idle.priorMissing(false);
  EXPECT_FALSE(idle.teachRequested());
  EXPECT_FALSE(idle.needsInputs());
  EXPECT_EQ(idle.summary(false, "").level, Level::kError);
  EXPECT_EQ(idle.summary(false, "").text, "prior missing: idle until teaching");
  EXPECT_EQ(idle.idleReason(), "is missing");
  EXPECT_EQ(idle.lightOn(20, true), Step::kNone);
}

TEST(TeachingPlan, AnUnusablePriorIsAnErrorUntilTeachingIsRequested) {
  TeachingPlan plan(TeachFrom::kBurst);
  plan.priorUnusable("bad yaml");
  EXPECT_EQ(plan.state(), PriorState::kCorrupt);
  EXPECT_EQ(plan.idleReason(), "is unusable (bad yaml)");
  EXPECT_EQ(plan.summary(false, "").level, Level::kError);
  EXPECT_EQ(plan.summary(false, "").text, "corrupt: bad yaml");
  EXPECT_TRUE(plan.request());
  EXPECT_EQ(plan.summary(false, "").level, Level::kWarn);
  plan.tracking();
  EXPECT_EQ(plan.error(), "");
  EXPECT_EQ(plan.summary(false, "").text, "tracking");
  EXPECT_EQ(plan.summary(true, "disk full").level, Level::kWarn);
  EXPECT_EQ(plan.summary(true, "disk full").text, "tracking; prior file not written yet: disk full");
}

TEST(TeachingPlan, ABurstUnderWayIsTaughtOnOnceItHasEnoughLightOnFrames) {
  TeachingPlan plan(TeachFrom::kBurst);
  plan.priorMissing(true);
  EXPECT_EQ(plan.lightOn(TeachingPlan::kTeachLightOnFrames - 1, true), Step::kWaitForBurst);
  EXPECT_EQ(plan.lightOn(TeachingPlan::kTeachLightOnFrames, false), Step::kTeachOnBurstUnderWay);
  plan.teachingStarted(true);
  EXPECT_EQ(plan.state(), PriorState::kTeaching);
  EXPECT_FALSE(plan.teachRequested());
  EXPECT_TRUE(plan.needsInputs());  // the frames that collect the outcome
  EXPECT_EQ(plan.lightOn(20, true), Step::kNone);
  EXPECT_FALSE(plan.request());  // busy
}

TEST(TeachingPlan, LightOffTeachingWaitsForALightOffFrameOfTheFramesFormat) {
  TeachingPlan plan = tracking(TeachFrom::kLightOff);
  EXPECT_EQ(plan.lightOn(20, true), Step::kNone);
  EXPECT_TRUE(plan.request());
  EXPECT_EQ(plan.teachesAt(), std::string("teaching at the next settled light-on frame"));
  EXPECT_EQ(plan.lightOn(20, false), Step::kWaitForLightOff);
  EXPECT_EQ(plan.lightOn(0, true), Step::kTeachOnLightOff);
  EXPECT_FALSE(plan.needsGroundTruth());
}

TEST(TeachingPlan, GroundTruthTeachingNeedsTheSimulatorsSceneOnlyWhileItWaits) {
  TeachingPlan plan(TeachFrom::kGroundTruth);
  plan.priorMissing(false);
  EXPECT_FALSE(plan.needsGroundTruth());
  EXPECT_TRUE(plan.request());
  EXPECT_TRUE(plan.needsGroundTruth());
  EXPECT_EQ(plan.lightOn(0, false), Step::kMatchGroundTruth);
  plan.teachingStarted(false);
  EXPECT_FALSE(plan.needsGroundTruth());
  EXPECT_TRUE(plan.needsInputs());
}

TEST(TeachingPlan, APriorTaughtOnABurstUnderWayThatMissesBoardsIsTaughtAgainAtABurstsEndOnce) {
  TeachingPlan plan(TeachFrom::kBurst);
  plan.priorMissing(true);
  plan.teachingStarted(true);
  plan.tracking();
  EXPECT_TRUE(plan.teachAgainIfBoardsMissing(4, 3, 4));
  EXPECT_TRUE(plan.teachRequested());
  EXPECT_EQ(plan.lightOn(20, true), Step::kWaitForBurst);  // not on a burst under way again
  EXPECT_EQ(plan.burstEnded(true, false), Burst::kTeach);
  plan.teachingStarted(false);
  plan.tracking();
  EXPECT_FALSE(plan.teachAgainIfBoardsMissing(4, 3, 4));  // a whole burst's prior stays
  EXPECT_FALSE(plan.teachRequested());
}

TEST(TeachingPlan, APriorWithEveryBoardOrTaughtOnAWholeBurstIsKept) {
  TeachingPlan partial(TeachFrom::kBurst);
  partial.teachingStarted(true);
  partial.tracking();
  EXPECT_FALSE(partial.teachAgainIfBoardsMissing(4, 4, 4));
  TeachingPlan whole(TeachFrom::kBurst);
  whole.teachingStarted(false);
  whole.tracking();
  EXPECT_FALSE(whole.teachAgainIfBoardsMissing(0, 0, 4));
  TeachingPlan failed(TeachFrom::kBurst);
  failed.teachingStarted(true);
  failed.teachFailed("no board");
  EXPECT_EQ(failed.state(), PriorState::kTeachFailed);
  EXPECT_EQ(failed.idleReason(), "was not taught (no board)");
  EXPECT_EQ(failed.summary(false, "").text, "teaching failed: no board");
  failed.tracking();
  EXPECT_FALSE(failed.teachAgainIfBoardsMissing(0, 0, 4));
}

TEST(TeachingPlan, AnEndedBurstIsTaughtOnTrackedHeldOrDropped) {
  TeachingPlan waiting(TeachFrom::kBurst);
  waiting.priorMissing(true);
  EXPECT_EQ(waiting.burstEnded(true, false), Burst::kTeach);
  EXPECT_EQ(waiting.burstEnded(true, true), Burst::kTeachThenTrack);
  EXPECT_EQ(waiting.burstEnded(false, false), Burst::kCannotTeach);
  EXPECT_EQ(waiting.burstEnded(false, true), Burst::kDropUnusable);

  TeachingPlan teaching(TeachFrom::kBurst);
  teaching.teachingStarted(true);
  EXPECT_EQ(teaching.burstEnded(true, true), Burst::kTrackOncePrior);
  EXPECT_EQ(teaching.burstEnded(true, false), Burst::kIgnore);
  EXPECT_EQ(teaching.burstEnded(false, true), Burst::kDropUnusable);

  TeachingPlan loaded = tracking(TeachFrom::kBurst);
  EXPECT_EQ(loaded.burstEnded(true, true), Burst::kTrack);
  EXPECT_EQ(loaded.burstEnded(false, true), Burst::kDropUnusable);
  EXPECT_EQ(loaded.burstEnded(true, false), Burst::kIgnore);

  TeachingPlan idle(TeachFrom::kBurst);
  idle.priorMissing(false);
  EXPECT_EQ(idle.burstEnded(true, true), Burst::kDropNoPrior);

  TeachingPlan light_off(TeachFrom::kLightOff);
  light_off.priorMissing(true);
  EXPECT_EQ(light_off.burstEnded(false, false), Burst::kIgnore);  // it waits for a frame, not a burst
  EXPECT_EQ(light_off.burstEnded(true, true), Burst::kDropNoPrior);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
