// CalibrationHealthPolicy (what the health nodelet decides around the monitor's verdicts):
// rollback and restore, when a calibration is wanted, refinements, which calibrator statuses
// count, and the wait for a solve's boards; scenarios written out by hand, calibrations named by
// letters.
#include <gtest/gtest.h>

#include <string>

#include "embedded_calibration_stereo/core/calibration/calibration_health_policy.h"

namespace core = embedded_calibration_stereo::core;

namespace {

using core::CalibrationHealth;
using Policy = core::CalibrationHealthPolicy<std::string>;
using Outcome = Policy::Verified::Outcome;

Policy makePolicy(core::CalibrationHealthPolicyOptions options = {}) {
  return Policy(options, [](const std::string& in_force, const std::string& other) { return in_force == other; });
}

// A report of `state` whose verification measured a disparity bias of `bias_px` (the only
// signal, so severity() = bias_px / disparity_bias_degraded_px).
core::HealthReport report(CalibrationHealth state, double bias_px = 0.0, const std::string& reason = "") {
  core::HealthReport r;
  r.state = state;
  r.board_age_s = 0.0;
  r.disparity_bias_px = bias_px;
  r.reason = reason;
  return r;
}

core::CalibratorStatus confirmation(uint32_t epoch, double newest_frame_s) {
  core::CalibratorStatus status;
  status.epoch = epoch;
  status.in_force_confirmed = true;
  status.newest_frame_s = newest_frame_s;
  return status;
}

core::CalibratorStatus commit(uint32_t epoch, double newest_frame_s, double predicted_px) {
  core::CalibratorStatus status;
  status.epoch = epoch;
  status.accepted = true;
  status.newest_frame_s = newest_frame_s;
  status.predicted_misalignment_px = predicted_px;
  return status;
}

// --- Rollback

TEST(CalibrationHealthPolicy, ANewCalibrationThatVerifiesWorseIsRestoredToTheOneVerifiedBefore) {
  Policy policy = makePolicy();
  policy.newCalibration(1, "A");
  EXPECT_FALSE(policy.testing()) << "nothing verified before A: nothing to test it against";
  policy.published(report(CalibrationHealth::kGood), 1.0);  // A verified GOOD: the reference
  policy.newCalibration(2, "B");
  ASSERT_TRUE(policy.testing());
  EXPECT_NE(policy.published(report(CalibrationHealth::kUnknown), 2.0).reason.find("awaiting its verification"),
            std::string::npos);
  const Policy::Verified verified = policy.afterVerification(report(CalibrationHealth::kBad, 2.0, "tilted"));
  ASSERT_EQ(verified.outcome, Outcome::kRestore);
  ASSERT_TRUE(verified.restore);
  EXPECT_EQ(*verified.restore, "A");
  EXPECT_EQ(verified.text,
            "the calibration of epoch 2 verified BAD (tilted) where the previous one (epoch 1) was GOOD: restoring the "
            "previous one");
  EXPECT_TRUE(policy.restoreRunning());
  // While the restore runs, the verdicts say why; a second verification decides nothing.
  EXPECT_NE(policy.published(report(CalibrationHealth::kBad), 3.0).reason.find("restoring the previous one"),
            std::string::npos);
  EXPECT_EQ(policy.afterVerification(report(CalibrationHealth::kBad)).outcome, Outcome::kNone);
  EXPECT_TRUE(policy.restoreFinished(""));
  EXPECT_FALSE(policy.restoreRunning());
  EXPECT_EQ(policy.restores(), 1u);
  EXPECT_FALSE(policy.restoreFailed());
  // A comes back as epoch 3: a restore, not tested again.
  policy.newCalibration(3, "A");
  EXPECT_FALSE(policy.testing()) << "the restored calibration must not be tested (and rolled back) again";
  EXPECT_NE(policy.reason(report(CalibrationHealth::kUnknown)).find("; restored"), std::string::npos);
  EXPECT_EQ(policy.reason(report(CalibrationHealth::kGood)).find("restor"), std::string::npos)
      << "once it has a verdict of its own the restore is no longer news";
}

TEST(CalibrationHealthPolicy, WhileARestoreRunsTheNextCalibrationIsNotDecided) {
  Policy policy = makePolicy();
  policy.newCalibration(1, "A");
  policy.published(report(CalibrationHealth::kGood), 1.0);
  policy.newCalibration(2, "B");
  ASSERT_EQ(policy.afterVerification(report(CalibrationHealth::kBad)).outcome, Outcome::kRestore);
  // C is committed before the restore of A has finished: its verification waits for it.
  policy.newCalibration(3, "C");
  ASSERT_TRUE(policy.testing());
  EXPECT_EQ(policy.afterVerification(report(CalibrationHealth::kBad)).outcome, Outcome::kNone)
      << "a second restore must not start while one runs";
  EXPECT_TRUE(policy.testing()) << "the next verification decides";
  policy.restoreFinished("");
  const Policy::Verified verified = policy.afterVerification(report(CalibrationHealth::kBad));
  ASSERT_EQ(verified.outcome, Outcome::kRestore);
  ASSERT_TRUE(verified.restore);
  EXPECT_EQ(*verified.restore, "A");
}

TEST(CalibrationHealthPolicy, ANewCalibrationNoWorseThanItsReferenceIsKept) {
  Policy policy = makePolicy();
  policy.newCalibration(1, "A");
  policy.published(report(CalibrationHealth::kDegraded), 1.0);
  policy.newCalibration(2, "B");
  EXPECT_EQ(policy.afterVerification(report(CalibrationHealth::kUnknown)).outcome, Outcome::kNone)
      << "no verdict yet: the next verification decides";
  const Policy::Verified verified = policy.afterVerification(report(CalibrationHealth::kDegraded));
  EXPECT_EQ(verified.outcome, Outcome::kKept);
  EXPECT_EQ(verified.text, "the calibration of epoch 2 verified DEGRADED");
  EXPECT_FALSE(policy.testing());
  EXPECT_FALSE(policy.restoreRunning());
}

TEST(CalibrationHealthPolicy, AFailedRestoreIsAFlagAndTheNextOneMayStart) {
  Policy policy = makePolicy();
  policy.newCalibration(1, "A");
  policy.published(report(CalibrationHealth::kGood), 1.0);
  policy.newCalibration(2, "B");
  ASSERT_EQ(policy.afterVerification(report(CalibrationHealth::kBad)).outcome, Outcome::kRestore);
  EXPECT_FALSE(policy.restoreFinished("left/set_camera_info refused: busy"));
  EXPECT_TRUE(policy.restoreFailed());
  EXPECT_NE(policy.lastRestore().find("; restore failed: left/set_camera_info refused: busy"), std::string::npos);
  // A arriving later is not the restore (it failed): as any new calibration, it is tested.
  policy.newCalibration(3, "A");
  EXPECT_TRUE(policy.testing());
}

TEST(CalibrationHealthPolicy, NoRollbackWhenRollbackIsOff) {
  core::CalibrationHealthPolicyOptions options;
  options.rollback = false;
  Policy policy = makePolicy(options);
  policy.newCalibration(1, "A");
  policy.published(report(CalibrationHealth::kGood), 1.0);
  policy.newCalibration(2, "B");
  EXPECT_FALSE(policy.testing());
  EXPECT_EQ(policy.afterVerification(report(CalibrationHealth::kBad)).outcome, Outcome::kNone);
}

TEST(CalibrationHealthPolicy, AfterARestartTheCalibrationInForceIsTestedAgainstTheOneVerifiedBefore) {
  Policy policy = makePolicy();
  policy.newCalibration(1, "B");  // the driver started with B, A was verified GOOD before the restart
  policy.earlierRunVerified("A");
  ASSERT_TRUE(policy.testing());
  const Policy::Verified verified = policy.afterVerification(report(CalibrationHealth::kBad, 0.0, "x"));
  ASSERT_EQ(verified.outcome, Outcome::kRestore);
  ASSERT_TRUE(verified.restore);
  EXPECT_EQ(*verified.restore, "A");
  EXPECT_NE(verified.text.find("the one verified before the restart"), std::string::npos);

  Policy same = makePolicy();
  same.newCalibration(1, "A");
  same.earlierRunVerified("A");
  EXPECT_FALSE(same.testing()) << "the calibration verified before the restart is not tested against itself";
}

// --- When a calibration is wanted

TEST(CalibrationHealthPolicy, BadAlwaysWantsACalibrationDegradedUntilConfirmedThenAgainOnceASignalDoubles) {
  Policy policy = makePolicy();  // disparity_bias_degraded_px 0.08
  policy.newCalibration(1, "A");
  EXPECT_FALSE(policy.published(report(CalibrationHealth::kUnknown), 1.0).calibration_wanted);
  EXPECT_FALSE(policy.published(report(CalibrationHealth::kGood, 0.02), 2.0).calibration_wanted);
  EXPECT_TRUE(policy.published(report(CalibrationHealth::kDegraded, 0.1), 3.0).calibration_wanted);
  // The calibrator confirms A from a window of frames up to 4 s (after the change seen at 3 s).
  ASSERT_TRUE(policy.confirmsInForce(confirmation(1, 4.0), true));
  policy.confirmedInForce(report(CalibrationHealth::kDegraded, 0.1));  // severity 1.25
  EXPECT_TRUE(policy.published(report(CalibrationHealth::kDegraded, 0.24), 5.0).calibration_wanted)
      << "0.24 px is more than twice the 0.1 px confirmed";
  EXPECT_FALSE(policy.published(report(CalibrationHealth::kDegraded, 0.19), 6.0).calibration_wanted)
      << "a signal below twice the one confirmed wants no window";
  EXPECT_NE(policy.published(report(CalibrationHealth::kDegraded, 0.19), 6.5).reason.find("found nothing better"),
            std::string::npos);
  EXPECT_TRUE(policy.published(report(CalibrationHealth::kBad, 0.19), 7.0).calibration_wanted)
      << "BAD wants a calibration whatever was confirmed";
  // GOOD again: a later change wants a window again.
  policy.published(report(CalibrationHealth::kGood, 0.02), 8.0);
  EXPECT_TRUE(policy.published(report(CalibrationHealth::kDegraded, 0.1), 9.0).calibration_wanted);
}

TEST(CalibrationHealthPolicy, AConfirmationFromAWindowOlderThanTheChangeCountsNot) {
  Policy policy = makePolicy();
  policy.newCalibration(2, "A");
  policy.published(report(CalibrationHealth::kGood), 10.0);
  policy.published(report(CalibrationHealth::kDegraded, 0.1), 12.0);  // left GOOD at 12 s
  policy.published(report(CalibrationHealth::kDegraded, 0.1), 13.0);
  EXPECT_FALSE(policy.confirmsInForce(confirmation(2, 11.5), true)) << "its window was lit before the change";
  EXPECT_TRUE(policy.confirmsInForce(confirmation(2, 12.0), true));
  EXPECT_FALSE(policy.confirmsInForce(confirmation(1, 12.5), true)) << "another epoch's";
  EXPECT_FALSE(policy.confirmsInForce(confirmation(2, 12.5), false)) << "the monitor has no calibration";
  core::CalibratorStatus accepted = confirmation(2, 12.5);
  accepted.accepted = true;
  EXPECT_FALSE(policy.confirmsInForce(accepted, true)) << "a commit confirms nothing";
  core::CalibratorStatus rejected = confirmation(2, 12.5);
  rejected.in_force_confirmed = false;
  EXPECT_FALSE(policy.confirmsInForce(rejected, true)) << "a rejection for another reason confirms nothing";
  // While GOOD a confirmation changes nothing.
  policy.published(report(CalibrationHealth::kGood), 14.0);
  policy.confirmedInForce(report(CalibrationHealth::kGood));
  EXPECT_TRUE(policy.published(report(CalibrationHealth::kDegraded, 0.1), 15.0).calibration_wanted);
}

// --- Refinement

TEST(CalibrationHealthPolicy, ACommitPredictedWorseThanTheLimitWantsMoreBurstsUntilALaterSolve) {
  Policy policy = makePolicy();  // refine_predicted_px 0.08, max_refinements 2
  policy.newCalibration(1, "A");
  policy.published(report(CalibrationHealth::kGood), 1.0);
  policy.noteRefinement(commit(2, 2.0, 0.05));
  policy.newCalibration(2, "B");
  EXPECT_FALSE(policy.published(report(CalibrationHealth::kGood), 3.0).calibration_wanted)
      << "predicted better than the limit";
  policy.noteRefinement(commit(3, 4.0, 0.12));
  policy.newCalibration(3, "C");
  EXPECT_FALSE(policy.published(report(CalibrationHealth::kUnknown), 5.0).calibration_wanted)
      << "not before its first verdict";
  const core::HealthVerdict refining = policy.published(report(CalibrationHealth::kGood), 6.0);
  EXPECT_TRUE(refining.calibration_wanted);
  EXPECT_NE(refining.reason.find("refining: the calibration's predicted error 0.120 px (limit 0.080 px)"),
            std::string::npos);
  // A solve of a window no newer than the commit's ends nothing; a later one does.
  core::CalibratorStatus same_window = confirmation(3, 4.0);
  policy.noteRefinement(same_window);
  EXPECT_TRUE(policy.published(report(CalibrationHealth::kGood), 7.0).calibration_wanted);
  policy.noteRefinement(confirmation(3, 8.0));
  EXPECT_FALSE(policy.published(report(CalibrationHealth::kGood), 9.0).calibration_wanted);
}

TEST(CalibrationHealthPolicy, RefinementsInARowAreBoundedUntilTheHealthLeavesGood) {
  Policy policy = makePolicy();  // max_refinements 2
  policy.newCalibration(1, "A");
  policy.published(report(CalibrationHealth::kGood), 1.0);
  for (uint32_t epoch = 2; epoch <= 3; ++epoch) {
    policy.noteRefinement(commit(epoch, epoch, 0.2));
    policy.newCalibration(epoch, "A" + std::to_string(epoch));
    EXPECT_TRUE(policy.published(report(CalibrationHealth::kGood), epoch + 0.5).calibration_wanted) << epoch;
  }
  policy.noteRefinement(commit(4, 4.0, 0.2));
  policy.newCalibration(4, "A4");
  EXPECT_FALSE(policy.published(report(CalibrationHealth::kGood), 4.5).calibration_wanted)
      << "a third refinement in a row";
  // Leaving GOOD (a new change) allows refinements again.
  policy.published(report(CalibrationHealth::kBad), 5.0);
  policy.noteRefinement(commit(5, 5.5, 0.2));
  policy.newCalibration(5, "A5");
  EXPECT_TRUE(policy.published(report(CalibrationHealth::kGood), 6.0).calibration_wanted);
}

TEST(CalibrationHealthPolicy, NoRefinementWhenTheLimitIsZero) {
  core::CalibrationHealthPolicyOptions options;
  options.refine_predicted_px = 0.0;
  Policy policy = makePolicy(options);
  policy.noteRefinement(commit(1, 1.0, 0.5));
  policy.newCalibration(1, "A");
  EXPECT_FALSE(policy.published(report(CalibrationHealth::kGood), 2.0).calibration_wanted);
}

// --- The wait for a solve's boards

TEST(CalibrationHealthPolicy, AVerificationWaitsForTheSolvesBoardsUntilTheyComeOrTheWaitIsOver) {
  Policy policy = makePolicy();  // boards_posed, solve_boards_wait_s 2
  policy.newCalibration(1, "A");
  policy.calibrationSet(false, 100.0);
  ASSERT_TRUE(policy.waitingForBoards());
  EXPECT_FALSE(policy.endWaitIfOver(101.9));
  policy.deferVerification();
  EXPECT_FALSE(policy.endWaitIfOver(101.99));
  EXPECT_TRUE(policy.waitingForBoards());
  EXPECT_TRUE(policy.endWaitIfOver(102.0)) << "the wait is over: the verification kept runs now";
  EXPECT_FALSE(policy.waitingForBoards());
  EXPECT_FALSE(policy.endWaitIfOver(103.0)) << "it ran once";

  policy.newCalibration(2, "B");
  policy.calibrationSet(false, 200.0);
  policy.deferVerification();
  EXPECT_TRUE(policy.solveBoardsUsed()) << "the boards came: the verification kept runs now";
  EXPECT_FALSE(policy.waitingForBoards());

  policy.newCalibration(3, "C");
  policy.calibrationSet(false, 300.0);
  EXPECT_FALSE(policy.solveBoardsUsed()) << "no verification was kept";
  policy.newCalibration(4, "D");
  policy.calibrationSet(true, 400.0);
  EXPECT_FALSE(policy.waitingForBoards()) << "its solve's boards were already known";
}

TEST(CalibrationHealthPolicy, NoWaitForBoardsPosedPerFrameOrAZeroWait) {
  core::CalibrationHealthPolicyOptions per_frame;
  per_frame.boards_posed = false;
  Policy a = makePolicy(per_frame);
  a.newCalibration(1, "A");
  a.calibrationSet(false, 0.0);
  EXPECT_FALSE(a.waitingForBoards());
  core::CalibrationHealthPolicyOptions no_wait;
  no_wait.solve_boards_wait_s = 0.0;
  Policy b = makePolicy(no_wait);
  b.newCalibration(1, "A");
  b.calibrationSet(false, 0.0);
  EXPECT_FALSE(b.waitingForBoards());
}

TEST(CalibrationHealthPolicy, ANewCalibrationDropsTheWaitAndTheVerificationKept) {
  Policy policy = makePolicy();
  policy.newCalibration(1, "A");
  policy.calibrationSet(false, 0.0);
  policy.deferVerification();
  policy.newCalibration(2, "B");
  EXPECT_FALSE(policy.waitingForBoards());
  EXPECT_FALSE(policy.solveBoardsUsed()) << "the verification of epoch 1 must not run against epoch 2";
}

// --- The report the health publishes

TEST(CalibrationHealthPolicy, AnImplausibleCalibrationIsBadAndACollapseOfDepthAtLeastDegraded) {
  Policy policy = makePolicy();
  policy.newCalibration(1, "A");
  const core::CoverageCollapse collapse{0.03, 0.6};
  const core::HealthReport good = report(CalibrationHealth::kGood, 0.0, "fine");
  EXPECT_EQ(policy.effectiveReport(good, std::nullopt).state, CalibrationHealth::kGood);
  const core::HealthReport collapsed = policy.effectiveReport(good, collapse);
  EXPECT_EQ(collapsed.state, CalibrationHealth::kDegraded);
  EXPECT_EQ(collapsed.reason, "fine; " + collapse.text());
  EXPECT_EQ(policy.effectiveReport(report(CalibrationHealth::kBad), collapse).state, CalibrationHealth::kBad);
  policy.setImplausible("focal lengths far from the nominal ones");
  const core::HealthReport implausible = policy.effectiveReport(good, collapse);
  EXPECT_EQ(implausible.state, CalibrationHealth::kBad);
  EXPECT_EQ(implausible.reason, "focal lengths far from the nominal ones");
  policy.newCalibration(2, "B");
  EXPECT_EQ(policy.effectiveReport(good, std::nullopt).state, CalibrationHealth::kGood) << "plausible again";
}

TEST(CalibrationHealthPolicy, SeverityIsTheLargestMeasuredSignalInUnitsOfItsDegradedThreshold) {
  const Policy policy = makePolicy();  // 0.08, 0.08, 0.35 px
  core::HealthReport r;
  r.misalignment_px = 0.4;
  r.disparity_bias_px = 0.16;
  r.board_residual_px = 1.05;
  EXPECT_DOUBLE_EQ(policy.severity(r), 0.0) << "nothing measured";
  r.board_age_s = 1.0;
  EXPECT_DOUBLE_EQ(policy.severity(r), 3.0) << "the corner residual, 3 times its threshold";
  r.board_residual_px = 0.35;
  EXPECT_DOUBLE_EQ(policy.severity(r), 2.0) << "the disparity bias, twice its threshold";
  r.board_residual_px = 1.05;
  r.epipolar_age_s = 0.5;
  EXPECT_DOUBLE_EQ(policy.severity(r), 5.0);
}

TEST(CalibrationHealthPolicy, AnUnusableCalibrationSaysWhyUntilTheNextOne) {
  Policy policy = makePolicy();
  policy.newCalibration(1, "A");
  policy.setUnusable("calibration of epoch 1 not usable: zero baseline");
  EXPECT_EQ(policy.reason(report(CalibrationHealth::kUnknown, 0.0, "no calibration")),
            "calibration of epoch 1 not usable: zero baseline");
  policy.newCalibration(2, "B");
  EXPECT_TRUE(policy.problem().empty());
}

}  // namespace
