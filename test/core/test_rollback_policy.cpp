// RollbackPolicy (when a new calibration is rolled back, and to what): scenarios of commits and
// verdicts written out by hand, calibrations named by letters.
#include <gtest/gtest.h>

#include <string>

#include "embedded_calibration_stereo/core/calibration/rollback_policy.h"

namespace core = embedded_calibration_stereo::core;

using core::CalibrationHealth;
using Policy = core::RollbackPolicy<std::string>;
using Outcome = Policy::Outcome;

TEST(RollbackPolicy, ACalibrationReplacedBeforeItsVerdictIsNeverTheReference) {
  Policy policy;
  policy.start(1, false);
  policy.observe(1, "A", CalibrationHealth::kGood);
  // B comes into force (epoch 2) and is replaced by C (epoch 3) before any verdict on B.
  ASSERT_EQ(policy.start(2, true)->calibration, "A");
  policy.observe(2, "B", CalibrationHealth::kBad);  // a depth-only verdict while B is under test
  const auto for_c = policy.start(3, true);
  ASSERT_TRUE(for_c);
  EXPECT_EQ(for_c->calibration, "A") << "a rollback would restore B, which nobody verified";
  const auto decision = policy.decide(3, "C", CalibrationHealth::kBad);
  EXPECT_EQ(decision.outcome, Outcome::kRestore);
  EXPECT_EQ(decision.reference->calibration, "A");
}

TEST(RollbackPolicy, ACalibrationThatFailedItsTestIsNeverTheReference) {
  Policy policy;
  policy.start(1, false);
  policy.observe(1, "A", CalibrationHealth::kGood);
  policy.start(2, true);
  EXPECT_EQ(policy.decide(2, "B", CalibrationHealth::kBad).outcome, Outcome::kRestore);
  policy.observe(2, "B", CalibrationHealth::kBad);  // still in force while the restore runs
  // C arrives before the restore: tested against A, not against B's BAD ("no worse").
  const auto for_c = policy.start(3, true);
  ASSERT_TRUE(for_c);
  EXPECT_EQ(for_c->calibration, "A");
  EXPECT_EQ(policy.decide(3, "C", CalibrationHealth::kBad).outcome, Outcome::kRestore);
}

TEST(RollbackPolicy, ARigThatDriftedTestsTheNewCalibrationAgainstTheStateItReached) {
  Policy policy;
  policy.start(1, false);
  policy.observe(1, "A", CalibrationHealth::kGood);
  policy.observe(1, "A", CalibrationHealth::kBad);  // the rig drifted under A
  EXPECT_EQ(policy.start(2, true)->state, CalibrationHealth::kBad);
  EXPECT_EQ(policy.decide(2, "B", CalibrationHealth::kDegraded).outcome, Outcome::kKept) << "better than A now";
  // B passed: it is the reference of the next one.
  const auto for_c = policy.start(3, true);
  EXPECT_EQ(for_c->calibration, "B");
  EXPECT_EQ(policy.decide(3, "C", CalibrationHealth::kBad).outcome, Outcome::kRestore);
}

TEST(RollbackPolicy, NoVerdictNoDecisionAndRestoresAreNotTested) {
  Policy policy;
  EXPECT_FALSE(policy.start(1, true)) << "nothing verified yet: no reference, no test";
  policy.observe(1, "A", CalibrationHealth::kGood);
  policy.start(2, true);
  EXPECT_EQ(policy.decide(2, "B", CalibrationHealth::kUnknown).outcome, Outcome::kUndecided);
  EXPECT_TRUE(policy.testing(2)) << "the next verification decides";
  EXPECT_EQ(policy.decide(2, "B", CalibrationHealth::kGood).outcome, Outcome::kKept);
  EXPECT_FALSE(policy.start(3, false)) << "a restore is not tested";
  EXPECT_EQ(policy.decide(3, "A", CalibrationHealth::kBad).outcome, Outcome::kUndecided);
}

TEST(RollbackPolicy, AfterARestartTheCalibrationVerifiedBeforeIsTheReference) {
  Policy policy;
  // The driver starts with C (unverified, epoch 0); A was verified GOOD before the restart.
  policy.start(0, true);
  EXPECT_FALSE(policy.testing(0)) << "nothing to test against yet";
  policy.seedEarlierRun("A");
  ASSERT_TRUE(policy.reference());
  EXPECT_EQ(policy.reference()->epoch, Policy::kEarlierRun);
  ASSERT_EQ(policy.start(0, true)->calibration, "A");
  const auto decision = policy.decide(0, "C", CalibrationHealth::kDegraded);
  EXPECT_EQ(decision.outcome, Outcome::kRestore);
  EXPECT_EQ(decision.reference->calibration, "A");
  EXPECT_EQ(decision.reference->state, CalibrationHealth::kGood);
}

TEST(RollbackPolicy, AVerdictOfThisRunOutranksTheOneBeforeTheRestart) {
  Policy policy;
  policy.start(0, false);
  policy.observe(0, "B", CalibrationHealth::kGood);
  policy.seedEarlierRun("A");  // arrives late: this run has its own reference already
  EXPECT_EQ(policy.reference()->calibration, "B");
  EXPECT_EQ(policy.start(1, true)->calibration, "B");
}
