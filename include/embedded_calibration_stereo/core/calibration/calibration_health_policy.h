#pragma once
// What the CalibrationHealth nodelet decides around the monitor's verdicts (ROS-free): which
// calibration is in force and whether a new one is under test, when it is rolled back and to
// what (rollback_policy.h), whether a verification waits for the boards of the solve that made
// the calibration, which calibrator statuses count, and when a calibration is wanted
// (calibration_wanted). The owner measures (CalibrationMonitor, DepthCoverageWatch), matches
// ROS messages and makes the calls; this class keeps the bookkeeping and says what to do.
// Definitions: docs/health.md (rollback, on-demand calibration, which boards), docs/nodelets.md.
//
// Stamps are seconds (double): frame stamps for the verdicts and statuses, wall time for the
// wait for a solve's boards.
//
// Threading: not thread-safe; the owner calls every method from one queue.
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>

#include "embedded_calibration_stereo/core/calibration/calibration_monitor.h"
#include "embedded_calibration_stereo/core/calibration/depth_coverage_watch.h"
#include "embedded_calibration_stereo/core/calibration/rollback_policy.h"

namespace embedded_calibration_stereo::core {

struct CalibrationHealthPolicyOptions {
  bool rollback = true;              // a new calibration that verifies worse is restored to its reference
  bool boards_posed = true;          // boards at their poses: a new calibration waits for its solve's
  double solve_boards_wait_s = 2.0;  // that wait (wall s); 0: never waits
  // A commit predicted worse than this (px) wants one more burst, at most max_refinements in a
  // row (counted until the health next leaves GOOD); 0: never.
  double refine_predicted_px = 0.08;
  int max_refinements = 2;
  // DEGRADED thresholds: the units of severity() (CalibrationMonitorOptions').
  double misalignment_degraded_px = 0.08;
  double disparity_bias_degraded_px = 0.08;
  double board_residual_degraded_px = 0.35;
};

// What the health learns from a calibrator's status (CalibrationStatus).
struct CalibratorStatus {
  uint32_t epoch = 0;
  bool accepted = false;
  bool in_force_confirmed = false;  // not accepted: the calibration in force is the best found
  double newest_frame_s = 0.0;      // stamp of the newest frame solved; 0 when none
  double predicted_misalignment_px = 0.0, predicted_disparity_bias_px = 0.0;
};

// What the health publishes with a verdict.
struct HealthVerdict {
  std::string reason;
  bool calibration_wanted = false;
};

// The decisions that do not depend on the calibration's type (calibration_health_policy.cpp);
// CalibrationHealthPolicy adds the calibrations themselves.
class CalibrationHealthDecisions {
 public:
  // A ratio of severity() to the one at a confirmation that wants a calibration again.
  static constexpr double kRearmFactor = 2.0;

  explicit CalibrationHealthDecisions(CalibrationHealthPolicyOptions options);
  const CalibrationHealthPolicyOptions& options() const { return options_; }

  /// The epoch in force, if any calibration came.
  std::optional<uint32_t> epoch() const { return epoch_; }
  /// Why the calibration in force is not plausible (it is then BAD); "" when plausible.
  void setImplausible(std::string why) { implausible_ = std::move(why); }
  /// The calibration in force cannot be used (the monitor has none): the health says why.
  void setUnusable(std::string problem) { problem_ = std::move(problem); }
  /// Why the calibration in force cannot be used, or "".
  const std::string& problem() const { return problem_; }

  /// The monitor took the calibration in force; `solve_boards_found`: with its solve's boards.
  /// Without them (and boards_posed), verifications wait for them until wall_now_s +
  /// solve_boards_wait_s.
  void calibrationSet(bool solve_boards_found, double wall_now_s);
  /// Whether a verification is to wait for the solve's boards.
  bool waitingForBoards() const { return waiting_until_s_.has_value(); }
  /// A verification was kept back while waiting (the owner keeps it; a newer one replaces it).
  void deferVerification() { deferred_ = true; }
  /// Ends a wait that is over at wall_now_s; true when a kept verification is to run now.
  bool endWaitIfOver(double wall_now_s);
  /// The solve's boards were found and set: the wait ends; true when a kept verification is to
  /// run now.
  bool solveBoardsUsed();

  /// The monitor's report worsened by what it cannot see: an implausible calibration (BAD) and a
  /// collapse of depth's valid fraction (at least DEGRADED).
  HealthReport effectiveReport(HealthReport report, const std::optional<CoverageCollapse>& collapse) const;
  /// The largest signal in units of its DEGRADED threshold (signals not measured count 0).
  double severity(const HealthReport& report) const;

  /// Any status: a commit predicted worse than refine_predicted_px is to be refined while it is
  /// in force; a solve of a later window ends that.
  void noteRefinement(const CalibratorStatus& status);
  /// Whether `status` confirms the calibration in force as the best the calibrator can do, for
  /// what the health sees now: not for another epoch, nor from a window older than the first
  /// verdict below GOOD. `has_calibration`: the monitor has the calibration in force.
  bool confirmsInForce(const CalibratorStatus& status, bool has_calibration) const;
  /// After a confirmation (confirmsInForce): while below GOOD, no calibration is wanted until a
  /// signal reaches kRearmFactor times its severity now.
  void confirmedInForce(const HealthReport& report);

  /// Whether the last restore failed (lastRestore() says why).
  bool restoreFailed() const { return restore_failed_; }
  /// The last rollback and its outcome, or "".
  const std::string& lastRestore() const { return last_restore_; }
  /// Restores finished.
  uint64_t restores() const { return restores_; }
  /// A restore was started and has not finished.
  bool restoreRunning() const { return restore_running_; }

 protected:
  // Bookkeeping of a new epoch; `is_restore`: it brings back the calibration restored.
  void startEpoch(uint32_t epoch, bool is_restore);
  // The reason published with `report`; `testing`: the calibration in force is under test;
  // `restore_pending`: a restored pair was sent and not seen in force yet.
  std::string reasonOf(const HealthReport& report, bool testing, bool restore_pending) const;
  // Bookkeeping of a verdict published at stamp_s, and whether a calibration is wanted.
  HealthVerdict verdictOf(const HealthReport& report, double stamp_s, bool testing, bool restore_pending);
  void restoreStarted(std::string text);
  // Returns false when it failed.
  bool restoreEnded(const std::string& error);

  // Log texts of a verification's outcome for a calibration under test.
  static std::string keptText(uint32_t epoch, const HealthReport& report);
  static std::string rollbackText(uint32_t epoch, const HealthReport& report, uint32_t reference_epoch,
                                  bool earlier_run, CalibrationHealth reference_state);

  std::optional<uint32_t> epoch_;
  std::optional<uint32_t> restored_epoch_;  // the epoch that brought a restored calibration back

 private:
  struct Refinement {
    uint32_t epoch;
    double after_s;  // the newest frame of its solve
    double predicted_px;
  };

  CalibrationHealthPolicyOptions options_;
  std::string implausible_, problem_;
  std::optional<double> waiting_until_s_;  // a new calibration waits for its solve's boards until then
  bool deferred_ = false;                  // a verification waits with it
  std::optional<double> left_good_at_s_;   // stamp of the first verdict below GOOD since the last GOOD
  std::optional<Refinement> refine_;
  int refinements_ = 0;                       // refinements asked since the health last left GOOD
  std::optional<double> confirmed_severity_;  // severity() when the calibrator confirmed the calibration
  std::string last_restore_;
  bool restore_failed_ = false, restore_running_ = false;
  uint64_t restores_ = 0;
};

// `Calibration`: what the driver takes back (a left/right CameraInfo pair in the nodelet).
template <class Calibration>
class CalibrationHealthPolicy : public CalibrationHealthDecisions {
 public:
  using Rollback = RollbackPolicy<Calibration>;
  // Whether the calibration in force (first) carries `other` (second): the driver publishes what
  // it was given.
  using Same = std::function<bool(const Calibration& in_force, const Calibration& other)>;

  // What to do after a verification.
  struct Verified {
    enum class Outcome { kNone, kKept, kRestore } outcome = Outcome::kNone;
    std::string text;                    // kKept, kRestore: for the log (and the rolled-back status)
    std::optional<Calibration> restore;  // kRestore: send this back to the driver
  };

  CalibrationHealthPolicy(CalibrationHealthPolicyOptions options, Same same)
      : CalibrationHealthDecisions(options), same_(std::move(same)) {}

  /// A new epoch comes into force with `calibration`: tested against its reference (rollback on,
  /// and not the calibration a restore sent back); every per-calibration state starts again.
  void newCalibration(uint32_t epoch, const Calibration& calibration) {
    const bool is_restore = restored_ && same_(calibration, *restored_);
    rollback_.start(epoch, options().rollback && !is_restore);
    if (is_restore) restored_.reset();
    in_force_ = calibration;
    startEpoch(epoch, is_restore);
  }
  /// The calibration in force, if any.
  const std::optional<Calibration>& inForce() const { return in_force_; }
  /// Whether the calibration in force is under test.
  bool testing() const { return epoch_ && rollback_.testing(*epoch_); }

  /// The calibration the driver keeps as verified GOOD (an earlier run's): the reference until
  /// this run has a verdict; a calibration in force without a verdict yet, other than it, is
  /// tested against it.
  void earlierRunVerified(const Calibration& calibration) {
    rollback_.seedEarlierRun(calibration);
    if (!options().rollback || !epoch_ || !in_force_ || testing() || restored_epoch_ == epoch_) return;
    if (rollback_.reference()->epoch != Rollback::kEarlierRun) return;  // this run has verdicts of its own
    if (same_(*in_force_, calibration)) return;
    rollback_.start(*epoch_, true);
  }

  /// A verdict is published at stamp_s (every measurement, every new calibration): it counts for
  /// the references; returns the reason and whether a calibration is wanted.
  HealthVerdict published(const HealthReport& report, double stamp_s) {
    if (epoch_ && in_force_) rollback_.observe(*epoch_, *in_force_, report.state);
    return verdictOf(report, stamp_s, testing(), restored_.has_value());
  }
  /// The reason published with `report` (as published() gives it, without the demand's notes).
  std::string reason(const HealthReport& report) const { return reasonOf(report, testing(), restored_.has_value()); }

  /// After a verification against the boards: a calibration under test is kept or restored
  /// (rollback_policy.h); nothing while a restore runs (the next verification decides).
  Verified afterVerification(const HealthReport& report) {
    Verified verified;
    if (!epoch_ || !in_force_ || !testing() || restoreRunning()) return verified;
    const typename Rollback::Decision decision = rollback_.decide(*epoch_, *in_force_, report.state);
    if (decision.outcome == Rollback::Outcome::kUndecided) return verified;
    const typename Rollback::Reference& reference = *decision.reference;
    if (decision.outcome == Rollback::Outcome::kKept) {
      verified.outcome = Verified::Outcome::kKept;
      verified.text = keptText(*epoch_, report);
      return verified;
    }
    verified.outcome = Verified::Outcome::kRestore;
    verified.text =
        rollbackText(*epoch_, report, reference.epoch, reference.epoch == Rollback::kEarlierRun, reference.state);
    verified.restore = reference.calibration;
    restored_ = reference.calibration;
    restoreStarted(verified.text);
    return verified;
  }
  /// The restore started by afterVerification finished: `error` "" or why it failed. Returns
  /// false when it failed.
  bool restoreFinished(const std::string& error) {
    const bool ok = restoreEnded(error);
    if (!ok) restored_.reset();
    return ok;
  }

 private:
  Same same_;
  Rollback rollback_;
  std::optional<Calibration> in_force_;
  std::optional<Calibration> restored_;  // sent back to the driver, not seen in force yet
};

}  // namespace embedded_calibration_stereo::core
