// What became of a solve, as a value (core::CalibrationOutcome): the gate's decision, a dry run
// and the commit target decide it; which outcomes count as accepted and as a successful request.
#include <gtest/gtest.h>

#include "embedded_calibration_stereo/core/calibration/calibration_outcome.h"

namespace core = embedded_calibration_stereo::core;

namespace embedded_calibration_stereo::core {
namespace {

GateDecision decided(GateOutcome outcome) {
  GateDecision d;
  d.setOutcome(outcome);
  return d;
}

TEST(CalibrationOutcome, TheGatesDecisionADryRunAndTheCommitTargetDecide) {
  using O = CalibrationOutcome;
  for (const GateOutcome accepted : {GateOutcome::kAccepted, GateOutcome::kRefinement}) {
    EXPECT_EQ(judgedOutcome(true, decided(accepted), false, true), O::kCommitted);
    EXPECT_EQ(judgedOutcome(true, decided(accepted), false, false), O::kAcceptedNotCommitted);
    EXPECT_EQ(judgedOutcome(true, decided(accepted), true, true), O::kDryRunAcceptable);
    EXPECT_EQ(judgedOutcome(true, decided(accepted), true, false), O::kDryRunAcceptable);
  }
  for (const GateOutcome confirmed : {GateOutcome::kInForceConfirmed, GateOutcome::kChangeTooSmall})
    for (const bool dry_run : {false, true}) EXPECT_EQ(judgedOutcome(true, decided(confirmed), dry_run, true), O::kInForceConfirmed);
  EXPECT_EQ(judgedOutcome(true, decided(GateOutcome::kRejected), false, true), O::kRejected);
  EXPECT_EQ(judgedOutcome(true, decided(GateOutcome::kRejected), true, true), O::kRejected);
  // No solution: whatever the (default) decision says.
  EXPECT_EQ(judgedOutcome(false, GateDecision{}, false, true), O::kSolveFailed);
  EXPECT_EQ(judgedOutcome(false, decided(GateOutcome::kAccepted), false, true), O::kSolveFailed);
}

TEST(CalibrationOutcome, AcceptedAndRequestSuccessFollowFromTheOutcome) {
  using O = CalibrationOutcome;
  for (const O o : {O::kCommitted, O::kAcceptedNotCommitted, O::kDryRunAcceptable}) {
    EXPECT_TRUE(outcomeAccepted(o)) << static_cast<int>(o);
    EXPECT_TRUE(requestSucceeded(o)) << static_cast<int>(o);
  }
  EXPECT_FALSE(outcomeAccepted(O::kInForceConfirmed));
  EXPECT_TRUE(requestSucceeded(O::kInForceConfirmed));  // nothing needed changing
  for (const O o : {O::kUnspecified, O::kRejected, O::kSolveFailed, O::kNotPlausible, O::kCommitFailed,
                    O::kMissingInputs, O::kNotSolved, O::kRolledBack}) {
    EXPECT_FALSE(outcomeAccepted(o)) << static_cast<int>(o);
    EXPECT_FALSE(requestSucceeded(o)) << static_cast<int>(o);
  }
}

TEST(GateDecision, TheFlagsFollowTheOutcome) {
  const GateDecision accepted = decided(GateOutcome::kAccepted);
  EXPECT_TRUE(accepted.accepted && !accepted.refinement && !accepted.in_force_confirmed && !accepted.change_too_small);
  const GateDecision refinement = decided(GateOutcome::kRefinement);
  EXPECT_TRUE(refinement.accepted && refinement.refinement && !refinement.in_force_confirmed);
  const GateDecision confirmed = decided(GateOutcome::kInForceConfirmed);
  EXPECT_TRUE(!confirmed.accepted && confirmed.in_force_confirmed && !confirmed.change_too_small);
  const GateDecision small = decided(GateOutcome::kChangeTooSmall);
  EXPECT_TRUE(!small.accepted && small.in_force_confirmed && small.change_too_small);
  const GateDecision rejected = decided(GateOutcome::kRejected);
  EXPECT_TRUE(!rejected.accepted && !rejected.in_force_confirmed && !rejected.change_too_small && !rejected.refinement);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
