#include "embedded_calibration_stereo/core/calibration/calibration_outcome.h"

namespace embedded_calibration_stereo::core {

CalibrationOutcome judgedOutcome(bool solved, const GateDecision& decision, bool dry_run, bool commit_to_driver) {
  if (!solved) return CalibrationOutcome::kSolveFailed;
  if (decision.in_force_confirmed) return CalibrationOutcome::kInForceConfirmed;
  if (!decision.accepted) return CalibrationOutcome::kRejected;
  if (dry_run) return CalibrationOutcome::kDryRunAcceptable;
  return commit_to_driver ? CalibrationOutcome::kCommitted : CalibrationOutcome::kAcceptedNotCommitted;
}

bool outcomeAccepted(CalibrationOutcome outcome) {
  return outcome == CalibrationOutcome::kCommitted || outcome == CalibrationOutcome::kAcceptedNotCommitted ||
         outcome == CalibrationOutcome::kDryRunAcceptable;
}

bool requestSucceeded(CalibrationOutcome outcome) {
  return outcomeAccepted(outcome) || outcome == CalibrationOutcome::kInForceConfirmed;
}

}  // namespace embedded_calibration_stereo::core
