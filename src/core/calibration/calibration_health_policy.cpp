#include "embedded_calibration_stereo/core/calibration/calibration_health_policy.h"

#include <algorithm>
#include <cstdio>

namespace embedded_calibration_stereo::core {

namespace {

void append(std::string* text, const std::string& part) { *text += (text->empty() ? "" : "; ") + part; }

}  // namespace

CalibrationHealthDecisions::CalibrationHealthDecisions(CalibrationHealthPolicyOptions options) : options_(options) {}

void CalibrationHealthDecisions::startEpoch(uint32_t epoch, bool is_restore) {
  if (is_restore) restored_epoch_ = epoch;  // the reason says why until it has a verdict
  epoch_ = epoch;
  implausible_.clear();
  problem_.clear();
  confirmed_severity_.reset();
  left_good_at_s_.reset();
  waiting_until_s_.reset();
  deferred_ = false;
}

void CalibrationHealthDecisions::calibrationSet(bool solve_boards_found, double wall_now_s) {
  waiting_until_s_.reset();
  // A solve's calibration is verified against its solve's boards: already here, or soon (its
  // status follows the driver's first frames with it).
  if (options_.boards_posed && !solve_boards_found && options_.solve_boards_wait_s > 0.0)
    waiting_until_s_ = wall_now_s + options_.solve_boards_wait_s;
}

bool CalibrationHealthDecisions::endWaitIfOver(double wall_now_s) {
  if (!waiting_until_s_ || wall_now_s < *waiting_until_s_) return false;
  return solveBoardsUsed();  // over: device_config's boards
}

bool CalibrationHealthDecisions::solveBoardsUsed() {
  waiting_until_s_.reset();
  const bool run = deferred_;
  deferred_ = false;
  return run;
}

HealthReport CalibrationHealthDecisions::effectiveReport(HealthReport report,
                                                         const std::optional<CoverageCollapse>& collapse) const {
  if (!implausible_.empty()) {
    report.state = CalibrationHealth::kBad;
    report.reason = implausible_;
  } else if (collapse) {
    if (healthRank(report.state) < 1) report.state = CalibrationHealth::kDegraded;
    append(&report.reason, collapse->text());
  }
  return report;
}

double CalibrationHealthDecisions::severity(const HealthReport& report) const {
  double worst = 0.0;
  if (report.epipolar_age_s >= 0.0) worst = std::max(worst, report.misalignment_px / options_.misalignment_degraded_px);
  if (report.board_age_s >= 0.0) {
    worst = std::max(worst, report.disparity_bias_px / options_.disparity_bias_degraded_px);
    worst = std::max(worst, report.board_residual_px / options_.board_residual_degraded_px);
  }
  return worst;
}

void CalibrationHealthDecisions::noteRefinement(const CalibratorStatus& status) {
  if (options_.refine_predicted_px <= 0.0) return;
  const double predicted = std::max(status.predicted_misalignment_px, status.predicted_disparity_bias_px);
  if (status.accepted && predicted > options_.refine_predicted_px && refinements_ < options_.max_refinements) {
    refine_ = Refinement{status.epoch, status.newest_frame_s, predicted};
    ++refinements_;
  } else if (refine_ && status.newest_frame_s > refine_->after_s) {
    refine_.reset();
  }
}

bool CalibrationHealthDecisions::confirmsInForce(const CalibratorStatus& status, bool has_calibration) const {
  if (status.accepted || !status.in_force_confirmed) return false;
  if (!epoch_ || status.epoch != *epoch_ || !has_calibration) return false;
  // A window taken before the health left GOOD confirms nothing about what it sees now.
  return !(left_good_at_s_ && status.newest_frame_s < *left_good_at_s_);
}

void CalibrationHealthDecisions::confirmedInForce(const HealthReport& report) {
  if (healthRank(report.state) <= 0) return;
  confirmed_severity_ = severity(report);
}

std::string CalibrationHealthDecisions::reasonOf(const HealthReport& report, bool testing, bool restore_pending) const {
  std::string reason = problem_.empty() ? report.reason : problem_;
  if (testing) append(&reason, "new calibration awaiting its verification");
  // Until the restored calibration has a verdict of its own.
  const bool restoring = restore_pending || (epoch_ == restored_epoch_ && report.state == CalibrationHealth::kUnknown);
  if (!last_restore_.empty() && restoring) append(&reason, last_restore_);
  return reason;
}

HealthVerdict CalibrationHealthDecisions::verdictOf(const HealthReport& report, double stamp_s, bool testing,
                                                    bool restore_pending) {
  HealthVerdict verdict;
  verdict.reason = reasonOf(report, testing, restore_pending);
  const int level = healthRank(report.state);
  if (level == 0) {  // GOOD again: a later change wants a window again
    confirmed_severity_.reset();
    left_good_at_s_.reset();
  }
  if (level > 0 && !left_good_at_s_) {
    left_good_at_s_ = stamp_s;
    refinements_ = 0;  // a new change: its commits may be refined again
  }
  // BAD: always (depth cannot be trusted). DEGRADED: until the calibrator confirms the
  // calibration in force as its best, and again once a signal doubles since.
  verdict.calibration_wanted =
      level == 2 || (level == 1 && !(confirmed_severity_ && severity(report) < kRearmFactor * *confirmed_severity_));
  if (level == 1 && !verdict.calibration_wanted)
    verdict.reason += "; the calibrator found nothing better: no calibration window until a signal doubles";
  if (refine_ && epoch_ && refine_->epoch == *epoch_ && level >= 0 && !verdict.calibration_wanted) {
    verdict.calibration_wanted = true;
    char text[120];
    std::snprintf(text, sizeof(text), "; refining: the calibration's predicted error %.3f px (limit %.3f px)",
                  refine_->predicted_px, options_.refine_predicted_px);
    verdict.reason += text;
  }
  return verdict;
}

void CalibrationHealthDecisions::restoreStarted(std::string text) {
  last_restore_ = std::move(text);
  restore_failed_ = false;
  restore_running_ = true;
}

bool CalibrationHealthDecisions::restoreEnded(const std::string& error) {
  restore_running_ = false;
  ++restores_;
  if (error.empty()) {
    last_restore_ += "; restored";
    return true;
  }
  last_restore_ += "; restore failed: " + error;
  restore_failed_ = true;
  return false;
}

std::string CalibrationHealthDecisions::keptText(uint32_t epoch, const HealthReport& report) {
  return "the calibration of epoch " + std::to_string(epoch) + " verified " + toString(report.state) +
         (report.reason.empty() ? "" : ": ") + report.reason;
}

std::string CalibrationHealthDecisions::rollbackText(uint32_t epoch, const HealthReport& report,
                                                     uint32_t reference_epoch, bool earlier_run,
                                                     CalibrationHealth reference_state) {
  const std::string previous = earlier_run ? std::string("the one verified before the restart")
                                           : "the previous one (epoch " + std::to_string(reference_epoch) + ")";
  char text[400];
  std::snprintf(text, sizeof(text),
                "the calibration of epoch %u verified %s (%s) where %s was %s: restoring the previous one", epoch,
                toString(report.state), report.reason.c_str(), previous.c_str(), toString(reference_state));
  return text;
}

}  // namespace embedded_calibration_stereo::core
