#pragma once
// What became of one calibration solve (or of a request that never reached a solve), as a value
// to branch on: the reason text is for people only. The OnlineCalibrator publishes it as
// CalibrationStatus.outcome (the same numbers: msg/CalibrationStatus.msg; the CalibrationHealth
// publishes kRolledBack); docs/nodelets.md, "OnlineCalibrator".
//
// Threading: plain values and pure functions.
#include <cstdint>

#include "embedded_calibration_stereo/core/calibration/quality_gate.h"

namespace embedded_calibration_stereo::core {

enum class CalibrationOutcome : uint8_t {
  kUnspecified = 0,           // not set (a status of another publisher)
  kCommitted = 1,             // accepted and stored by the driver
  kAcceptedNotCommitted = 2,  // accepted; commit "none" (a replay): on /tf_static only
  kDryRunAcceptable = 3,      // a dry run the gate accepted: nothing committed
  kInForceConfirmed = 4,      // the gate keeps the calibration in force: the solve confirms it
  kRejected = 5,              // the gate rejected the solve
  kSolveFailed = 6,           // the solver found no solution
  kNotPlausible = 7,          // accepted by the gate, but no calibration a consumer takes: not committed
  kCommitFailed = 8,          // the driver did not store it (committed again later: commit_retry_s)
  kMissingInputs = 9,         // no calibration in force known (no camera_info pair): nothing solved
  kNotSolved = 10,            // a request that ended before a solve (refused, busy, light, timeout, ...)
  kRolledBack = 11,           // the health restored the calibration before this epoch (worse than it)
};

// The outcome of a solve the gate judged, before any commit: kCommitted means "to be committed"
// (the commit may still end in kNotPlausible or kCommitFailed). `solved`: the solver found a
// solution; `dry_run`: nothing is committed whatever the gate says; `commit_to_driver`: false
// for commit "none".
CalibrationOutcome judgedOutcome(bool solved, const GateDecision& decision, bool dry_run, bool commit_to_driver);

// True for the outcomes of a calibration the gate accepted and nothing then failed
// (CalibrationStatus.accepted): committed, accepted not committed, dry run acceptable.
bool outcomeAccepted(CalibrationOutcome outcome);

// True when a recalibration request with this outcome succeeded: accepted, or the calibration in
// force confirmed (nothing needed changing).
bool requestSucceeded(CalibrationOutcome outcome);

}  // namespace embedded_calibration_stereo::core
