#include "embedded_calibration_stereo/ros/calibration_session.h"

#include <sensor_msgs/SetCameraInfo.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <cstdio>
#include <stdexcept>
#include <tuple>
#include <utility>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/calibration/observation_validator.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/service_call.h"
#include "embedded_calibration_stereo/ros/stamp_guard.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {
namespace {

void appendIntrinsics(const core::PinholeCamera& camera, const core::CameraStddev& sd, std::vector<double>* values,
                      std::vector<double>* stddevs) {
  *values = {camera.fx, camera.fy, camera.cx, camera.cy};
  values->insert(values->end(), camera.dist.begin(), camera.dist.end());
  *stddevs = {sd.fx, sd.fy, sd.cx, sd.cy};
  stddevs->insert(stddevs->end(), sd.dist.begin(), sd.dist.end());
}

// The predicted depth accuracy of a solve with a covariance; zeros otherwise (also for a rig
// that cannot be rectified: such a one is never committed).
void fillPredictedAccuracy(const core::BundleAdjustmentSummary& summary, const core::RectificationOptions& rectification,
                           CalibrationStatus* status) {
  core::StereoAccuracyOptions options;
  options.rectification = rectification;
  options.depths_m = {1.0, 2.0, 5.0, 10.0, std::numeric_limits<double>::infinity()};
  for (size_t i = 0; i < status->predicted_depths_m.size(); ++i) status->predicted_depths_m[i] = options.depths_m[i];
  if (!summary.success || !summary.covariance_ok) return;
  core::StereoAccuracy predicted;
  try {
    predicted = core::predictStereoAccuracy(summary.rig, summary.rig_covariance, options);
  } catch (const std::invalid_argument&) {
    return;
  }
  status->predicted_misalignment_rms_px = predicted.misalignment_px.rms;
  status->predicted_disparity_bias_rms_px = predicted.disparity_bias_px.rms;
  for (size_t i = 0; i < status->predicted_depth_error_pct.size(); ++i)
    status->predicted_depth_error_pct[i] = predicted.at_depth[i].depth_error_pct.rms;
}

}  // namespace

CommitTarget parseCommitTarget(const std::string& name) {
  if (name == "driver") return CommitTarget::kDriver;
  if (name == "none") return CommitTarget::kNone;
  throw core::ConfigError("commit", "must be 'driver' or 'none', got '" + name + "'");
}

CalibratorParams loadCalibratorParams(const ros::NodeHandle& pnh, const std::string& default_device_config) {
  CalibratorParams p;
  const ParameterReader read(pnh);
  // Thresholds, scales and times: none may be negative.
  const auto non_negative = [&read](const std::string& name, double* value) {
    *value = read.atLeast(name, *value, 0.0);
  };
  p.device_config = read.get("device_config", default_device_config);
  p.left_frame_id = read.get("left_frame_id", p.left_frame_id);
  p.right_frame_id = read.get("right_frame_id", p.right_frame_id);
  p.auto_calibrate = read.get("auto_calibrate", p.auto_calibrate);
  p.window_observations = read.get("window_observations", p.window_observations);
  p.min_frames = read.atLeast("min_frames", p.min_frames, 1);
  p.max_frames = read.atLeast("max_frames", p.max_frames, p.min_frames);
  non_negative("service_timeout_s", &p.service_timeout_s);
  p.max_request_timeout_s = read.atLeast("max_request_timeout_s", p.max_request_timeout_s, 0.1);
  p.window_timeout_s = read.atLeast("window_timeout_s", p.window_timeout_s, 0.1);
  p.stamp_tolerance_s = readStampTolerance(pnh);
  non_negative("commit_retry_s", &p.commit_retry_s);
  non_negative("min_solve_interval_s", &p.solve_pacing.min_interval_s);
  p.solve_pacing.capacity = read.atLeast("solve_queue_size", static_cast<int>(p.solve_pacing.capacity), 1);
  p.commit = parseCommitTarget(read.get("commit", "driver"));
  p.rectification_alpha = read.get("rectification_alpha", p.rectification_alpha);
  if (!(p.rectification_alpha == -1.0 || (p.rectification_alpha >= 0.0 && p.rectification_alpha <= 1.0)))
    throw core::ConfigError("rectification_alpha", "must be in [0, 1], or -1 for OpenCV's default scaling");
  p.terms.estimate_tangential = read.get("estimate_tangential", p.terms.estimate_tangential);
  p.terms.estimate_k3 = read.get("estimate_k3", p.terms.estimate_k3);
  non_negative("loss_scale_px", &p.adjustment.loss_scale_px);
  const std::string placement = read.get("board_placement", std::string("tested"));
  if (placement == "held") p.adjustment.board_placement = core::BoardPlacement::kHeld;
  else if (placement == "refined") p.adjustment.board_placement = core::BoardPlacement::kRefined;
  else if (placement == "tested") p.adjustment.board_placement = core::BoardPlacement::kTested;
  else throw core::ConfigError("board_placement", "must be held, refined or tested, got '" + placement + "'");
  p.adjustment.use_scene_matches = read.get("scene_constraints", p.adjustment.use_scene_matches);
  p.prior_from_earlier_windows = read.get("prior_from_earlier_windows", p.prior_from_earlier_windows);
  p.filter.change_probability = read.get("change_probability", p.filter.change_probability);
  p.gate.refine_ratio = read.inRange("refine_ratio", 0.85, 0.0, 0.99);
  p.gate.scene_test_probability = read.inRange("scene_test_probability", 0.001, 0.0, 0.5);
  if (const std::string e = p.filter.validate(); !e.empty()) throw core::ConfigError("change_probability", e);
  non_negative("max_rms_px", &p.gate.max_rms_px);
  non_negative("max_epipolar_rms_px", &p.gate.max_epipolar_rms_px);
  non_negative("max_outlier_fraction", &p.gate.max_outlier_fraction);
  p.gate.min_boards_per_camera = read.atLeast("min_boards_per_camera", p.gate.min_boards_per_camera, 1);
  non_negative("max_focal_stddev_rel", &p.gate.max_focal_stddev_rel);
  non_negative("max_principal_point_stddev_px", &p.gate.max_principal_point_stddev_px);
  non_negative("max_distortion_stddev", &p.gate.max_distortion_stddev);
  non_negative("max_baseline_stddev_rel", &p.gate.max_baseline_stddev_rel);
  non_negative("max_rotation_stddev_deg", &p.gate.max_rotation_stddev_deg);
  non_negative("min_rms_improvement_rel", &p.gate.min_rms_improvement_rel);
  non_negative("min_change_in_predicted", &p.gate.min_change_in_predicted);
  non_negative("in_force_max_rms_px", &p.gate.in_force_max_rms_px);
  if (const std::string e = p.adjustment.validate(); !e.empty()) throw core::ConfigError("loss_scale_px", e);
  if (const std::string e = p.gate.validate(); !e.empty()) throw core::ConfigError("quality gate", e);
  return p;
}

BoundedRequest boundRecalibrateRequest(uint32_t frames, double timeout_s, const CalibratorParams& params) {
  BoundedRequest r;
  char text[200];
  if (!std::isfinite(timeout_s)) {
    std::snprintf(text, sizeof(text), "refused: timeout_s must be a finite number of seconds, got %g (at most %g s)",
                  timeout_s, params.max_request_timeout_s);
    r.refusal = text;
    return r;
  }
  // By default a whole burst when bursts are tracked as a whole (the window observation is
  // solved), else the fewest frames a window is solved with.
  r.frames = frames > 0 ? frames : static_cast<size_t>(params.window_observations ? params.max_frames : params.min_frames);
  r.timeout_s = timeout_s > 0.0 ? timeout_s : std::min(kDefaultRequestTimeoutS, params.max_request_timeout_s);
  const auto add_note = [&r](const std::string& note) { r.note += (r.note.empty() ? "" : ", ") + note; };
  if (r.frames > static_cast<size_t>(params.max_frames)) {
    std::snprintf(text, sizeof(text), "frames %u limited to %d (max_frames)", frames, params.max_frames);
    add_note(text);
    r.frames = static_cast<size_t>(params.max_frames);
  }
  if (r.timeout_s > params.max_request_timeout_s) {
    std::snprintf(text, sizeof(text), "timeout_s %g limited to %g s (max_request_timeout_s)", timeout_s,
                  params.max_request_timeout_s);
    add_note(text);
    r.timeout_s = params.max_request_timeout_s;
  }
  return r;
}

std::vector<std::string> observationDefects(const core::StereoObservation& observation,
                                            const std::vector<core::VirtualBoard>& boards) {
  core::ObservationValidationOptions options;
  // Size and corner count are judged at solve time against the calibration in force; here only
  // defects of the message itself count.
  options.image_width = options.image_height = 1 << 20;
  options.max_outside_image_px = 1 << 20;
  options.min_corners_per_board = 0;
  std::vector<std::string> defects = core::validateObservations({observation}, boards, options).dropped;
  // "frame 0 left board 3: ..." -> "left board 3: ..." (there is only one frame here).
  for (std::string& d : defects)
    if (d.rfind("frame 0 ", 0) == 0) d.erase(0, 8);
  return defects;
}

// The message's constants are the core's outcomes.
static_assert(CalibrationStatus::OUTCOME_UNSPECIFIED == static_cast<uint8_t>(core::CalibrationOutcome::kUnspecified) &&
                  CalibrationStatus::OUTCOME_COMMITTED == static_cast<uint8_t>(core::CalibrationOutcome::kCommitted) &&
                  CalibrationStatus::OUTCOME_ACCEPTED_NOT_COMMITTED ==
                      static_cast<uint8_t>(core::CalibrationOutcome::kAcceptedNotCommitted) &&
                  CalibrationStatus::OUTCOME_DRY_RUN_ACCEPTABLE ==
                      static_cast<uint8_t>(core::CalibrationOutcome::kDryRunAcceptable) &&
                  CalibrationStatus::OUTCOME_IN_FORCE_CONFIRMED ==
                      static_cast<uint8_t>(core::CalibrationOutcome::kInForceConfirmed) &&
                  CalibrationStatus::OUTCOME_REJECTED == static_cast<uint8_t>(core::CalibrationOutcome::kRejected) &&
                  CalibrationStatus::OUTCOME_SOLVE_FAILED == static_cast<uint8_t>(core::CalibrationOutcome::kSolveFailed) &&
                  CalibrationStatus::OUTCOME_NOT_PLAUSIBLE ==
                      static_cast<uint8_t>(core::CalibrationOutcome::kNotPlausible) &&
                  CalibrationStatus::OUTCOME_COMMIT_FAILED ==
                      static_cast<uint8_t>(core::CalibrationOutcome::kCommitFailed) &&
                  CalibrationStatus::OUTCOME_MISSING_INPUTS ==
                      static_cast<uint8_t>(core::CalibrationOutcome::kMissingInputs) &&
                  CalibrationStatus::OUTCOME_NOT_SOLVED == static_cast<uint8_t>(core::CalibrationOutcome::kNotSolved) &&
                  CalibrationStatus::OUTCOME_ROLLED_BACK == static_cast<uint8_t>(core::CalibrationOutcome::kRolledBack),
              "CalibrationStatus.msg's OUTCOME_ constants must be core::CalibrationOutcome's values");

void setOutcome(CalibrationStatus* status, core::CalibrationOutcome outcome) {
  status->outcome = static_cast<uint8_t>(outcome);
  status->accepted = core::outcomeAccepted(outcome);
  status->in_force_confirmed = outcome == core::CalibrationOutcome::kInForceConfirmed;
}

CalibrationStatus statusWithoutSolve(const std::string& reason, uint32_t epoch, core::CalibrationOutcome outcome) {
  CalibrationStatus status;
  status.header.stamp = ros::Time::now();
  status.epoch = epoch;
  status.reason = reason;
  setOutcome(&status, outcome);
  return status;
}

std::string recalibrateMessage(const CalibrationStatus& status) {
  // A committed status has a reason only when its epoch could not be read back.
  return status.outcome == CalibrationStatus::OUTCOME_COMMITTED && status.reason.empty() ? "committed" : status.reason;
}

CalibrationStatus makeStatus(const core::BundleAdjustmentSummary& summary, const core::GateDecision& decision,
                             const core::RectificationOptions& rectification) {
  CalibrationStatus status;
  status.header.stamp = ros::Time::now();
  setOutcome(&status, core::judgedOutcome(true, decision, false, true));
  status.reason = decision.accepted ? "" : decision.reason;
  status.frames_used = static_cast<uint32_t>(summary.frames_used);
  status.corners_used = static_cast<uint32_t>(summary.corners_used);
  status.scene_matches_used = static_cast<uint32_t>(summary.scene_matches_used);
  status.scene_sigma_px = summary.scene_sigma_px;
  status.rms_left_px = summary.rms_left_px;
  status.rms_right_px = summary.rms_right_px;
  status.epipolar_rms_px = summary.epipolar_rms_px;
  appendIntrinsics(summary.rig.left, summary.left_stddev, &status.left_intrinsics, &status.left_intrinsics_stddev);
  appendIntrinsics(summary.rig.right, summary.right_stddev, &status.right_intrinsics, &status.right_intrinsics_stddev);
  status.baseline_m = summary.rig.baseline();
  status.baseline_stddev_m = summary.baseline_stddev_m;
  status.rotation_stddev_deg = summary.rotation_stddev_deg;
  status.solve_ms = summary.solve_ms;
  fillPredictedAccuracy(summary, rectification, &status);
  if (summary.success)
    for (const auto& [id, rig_from_board] : summary.rig_from_board) {
      status.board_ids.push_back(static_cast<uint16_t>(id));
      status.board_poses.push_back(toPoseMsg(rig_from_board));
    }
  return status;
}

bool carriesCalibration(const sensor_msgs::CameraInfo& published, const sensor_msgs::CameraInfo& committed) {
  const auto near = [](double a, double b) { return std::abs(a - b) <= 1e-6 * std::max(1.0, std::abs(b)); };
  const auto same = [&](const auto& a, const auto& b) {
    return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), near);
  };
  return published.width == committed.width && published.height == committed.height &&
         published.distortion_model == committed.distortion_model && same(published.D, committed.D) &&
         same(published.K, committed.K) && same(published.R, committed.R) && same(published.P, committed.P);
}

CalibrationSession::CalibrationSession(ros::NodeHandle nh, CalibratorParams params, core::CalibrationDevice device,
                                       std::optional<core::StereoRig> nominal)
    : nh_(std::move(nh)),
      params_(std::move(params)),
      device_(std::move(device)),
      nominal_(std::move(nominal)),
      boards_(device_.virtualBoards()),
      adjuster_(params_.adjustment, params_.terms),
      gate_(params_.gate),
      filter_(params_.filter) {}

SolveResult CalibrationSession::solve(const SolveRequest& request) {
  const std::vector<core::StereoObservation>& frames = request.frames;
  const uint32_t epoch = request.epoch;
  const bool dry_run = request.dry_run;
  SolveResult result;
  if (!request.left_info || !request.right_info) {
    result.status = statusWithoutSolve("no left/right camera_info received: image size and calibration in force unknown",
                                       epoch, core::CalibrationOutcome::kMissingInputs);
    return result;
  }
  const sensor_msgs::CameraInfo* left_info = request.left_info.get();
  const sensor_msgs::CameraInfo* right_info = request.right_info.get();
  core::StereoRig in_force;
  std::string error;
  const bool have_in_force = fromStereoCameraInfo(*left_info, *right_info, &in_force, &error);
  // What earlier windows taught holds only under the calibration it was learned with.
  if (filter_in_force_ && !(carriesCalibration(*left_info, filter_in_force_->first) &&
                            carriesCalibration(*right_info, filter_in_force_->second))) {
    filter_.reset();
    filter_in_force_.reset();
    in_force_predicted_px_.reset();
  }
  const core::BundleAdjustmentSummary candidate =
      solveWindow(frames, *left_info, have_in_force ? &in_force : nullptr, request.health_problem_s);
  // An implausible calibration in force (an outside driver's) is never confirmed: the solve is
  // judged on its own, as for an uncalibrated head.
  const bool judge_in_force = have_in_force && implausibleCandidate({*left_info, *right_info}).empty();
  core::BundleAdjustmentSummary in_force_fit;
  if (judge_in_force && candidate.success)
    in_force_fit = core::evaluateFixedCalibration(in_force, frames, boards_, params_.adjustment, &device_);
  core::GateDecision decision;
  if (!candidate.success) {
    decision.reason = "solve failed: " + candidate.message;
  } else {
    decision = gate_.evaluate(candidate, judge_in_force ? &in_force_fit : nullptr, in_force_predicted_px_);
    if (decision.outcome == core::GateOutcome::kRefinement) prior_note_ += (prior_note_.empty() ? "" : "; ") + decision.detail;
  }
  const core::CalibrationOutcome outcome =
      core::judgedOutcome(candidate.success, decision, dry_run, params_.commit == CommitTarget::kDriver);
  CalibrationStatus& status = result.status;
  status = statusOf(candidate, decision, in_force_fit, epoch, frames);
  setOutcome(&status, outcome);
  // A solve the gate found sound is what the next window learns from, committed or not (a
  // calibration in force confirmed is still measured better by the solve that confirmed it).
  const bool learn = !dry_run && candidate.covariance_ok && (decision.accepted || decision.in_force_confirmed);
  if (learn) {
    filter_.setState(candidate.rig, candidate.rig_covariance, frames.empty() ? 0.0 : frames.back().stamp);
    filter_in_force_.emplace(*left_info, *right_info);
  }
  if (outcome == core::CalibrationOutcome::kDryRunAcceptable) status.reason = "dry run: acceptable, not committed";
  if (outcome == core::CalibrationOutcome::kCommitted || outcome == core::CalibrationOutcome::kAcceptedNotCommitted)
    commitAccepted(candidate, learn, *left_info, *right_info, &result);
  return result;
}

// The window's solve: on its own, then again with what earlier windows taught about the
// parameter groups it does not contradict (prior_note_ says which).
core::BundleAdjustmentSummary CalibrationSession::solveWindow(const std::vector<core::StereoObservation>& frames,
                                                             const sensor_msgs::CameraInfo& left_info,
                                                             const core::StereoRig* in_force,
                                                             std::optional<double> health_problem_s) {
  core::CalibrationInput input;
  input.frames = &frames;
  input.device = &device_;
  input.image_width = static_cast<int>(left_info.width);
  input.image_height = static_cast<int>(left_info.height);
  if (in_force) input.in_force = *in_force;  // otherwise an uncalibrated head: Zhang start
  core::BundleAdjustmentSummary candidate = adjuster_.Solve(input);
  const double stamp = frames.empty() ? 0.0 : frames.back().stamp;
  prior_note_.clear();
  if (params_.prior_from_earlier_windows && candidate.success && filter_.hasState()) {
    std::vector<std::string> changed, seen_by_health;
    if (health_problem_s && *health_problem_s >= filter_.stateTime()) seen_by_health = core::turnAndZoomGroups();
    if (const std::optional<core::RigPrior> prior = filter_.priorFor(candidate, stamp, &changed, seen_by_health)) {
      input.rig_prior = prior;
      input.weights_from = &candidate;
      core::BundleAdjustmentSummary with_prior = adjuster_.Solve(input);
      input.weights_from = nullptr;
      if (with_prior.success) {
        with_prior.solve_ms += candidate.solve_ms;  // both solves are this window's
        candidate = std::move(with_prior);
        prior_note_ = "prior from earlier windows on " + std::to_string(prior->activeCount()) + " parameters";
      }
    }
    for (size_t i = 0; i < changed.size(); ++i)
      prior_note_ += (i == 0 ? (prior_note_.empty() ? "changed: " : "; changed: ") : ", ") + changed[i];
  }
  if (candidate.board_placement_refined) {
    char note[120];
    std::snprintf(note, sizeof(note), "board placements refined (held, they fit worse: %.0f > %.0f)",
                  candidate.placement_test_statistic, candidate.placement_test_limit);
    prior_note_ += (prior_note_.empty() ? "" : "; ") + std::string(note);
  }
  return candidate;
}

// The status of a judged solve, in the words a user reads.
CalibrationStatus CalibrationSession::statusOf(const core::BundleAdjustmentSummary& candidate,
                                               const core::GateDecision& decision,
                                               const core::BundleAdjustmentSummary& in_force_fit, uint32_t epoch,
                                               const std::vector<core::StereoObservation>& frames) const {
  core::RectificationOptions rectification;  // as toStereoCameraInfo() commits it
  rectification.alpha = params_.rectification_alpha;
  CalibrationStatus status = makeStatus(candidate, decision, rectification);
  status.epoch = epoch;
  if (!frames.empty()) status.newest_frame.fromSec(frames.back().stamp);
  if (status.in_force_confirmed) {
    char rms[96];
    std::snprintf(rms, sizeof(rms), " (RMS %.3f px; the new solve %.3f px, no better)", core::combinedRms(in_force_fit),
                  core::combinedRms(candidate));
    // The gate's words when the new solve fits better but changes too little to trust.
    status.reason = kInForceConfirmedReason +
                    (decision.outcome == core::GateOutcome::kChangeTooSmall ? " (" + decision.detail + ")"
                                                                           : std::string(rms));
  }
  return status;
}

// An accepted solve to the driver (or, for a replay, to /tf_static only); `status` says what
// became of it.
void CalibrationSession::commitAccepted(const core::BundleAdjustmentSummary& candidate, bool learned,
                                        const sensor_msgs::CameraInfo& left_info,
                                        const sensor_msgs::CameraInfo& right_info, SolveResult* result) {
  CalibrationStatus* status = &result->status;
  if (params_.commit == CommitTarget::kNone) {
    // A replay has no driver to commit to: announce the accepted geometry on /tf_static only,
    // and say in the status that no camera_info changed (the epoch in force stays `epoch`).
    broadcastTransform(candidate.rig);
    status->reason = kAcceptedNotCommittedReason;
    return;
  }
  CommittedCalibration infos;
  try {
    std::tie(infos.left, infos.right) = toStereoCameraInfo(candidate.rig, params_.rectification_alpha);
  } catch (const std::invalid_argument& e) {  // a rig that cannot be rectified is not committed
    setOutcome(status, core::CalibrationOutcome::kNotPlausible);
    status->reason = std::string("not committed: ") + e.what();
    return;
  }
  // What every consumer checks (plausible principal points, P fitting K and R, distortion that
  // does not fold over): a solve that fails it would be refused downstream, or leave depth empty.
  if (const std::string problem = implausibleCandidate(infos); !problem.empty()) {
    setOutcome(status, core::CalibrationOutcome::kNotPlausible);
    status->reason = "not committed: the solve is not a plausible calibration: " + problem;
    return;
  }
  const std::string commit_error = commit(infos, candidate.rig, left_info);
  if (!commit_error.empty()) {
    setOutcome(status, core::CalibrationOutcome::kCommitFailed);
    status->reason = "not committed: " + commit_error;
    result->uncommitted = UncommittedCalibration{infos, candidate.rig, left_info, right_info, *status,
                                                 core::QualityGate::predictedPx(candidate)};
    return;
  }
  // status.epoch stays `epoch`: how far the driver moves its epoch per set_camera_info is the
  // driver's business, so the caller reads the new epoch from the driver's frames.
  if (learned) filter_in_force_.emplace(infos.left, infos.right);
  const double predicted = core::QualityGate::predictedPx(candidate);
  in_force_predicted_px_ = predicted > 0.0 ? std::optional<double>(predicted) : std::nullopt;
  result->committed = std::move(infos);
}

std::string CalibrationSession::implausibleCandidate(const CommittedCalibration& infos) const {
  return checkCalibrationPair(infos.left, "left", infos.right, "right", nominal_);
}

std::string CalibrationSession::commitAgain(const UncommittedCalibration& calibration) {
  const std::string error = commit(calibration.infos, calibration.rig, calibration.left_in_force);
  // The state learned from this calibration's solve now holds under it.
  if (error.empty() && filter_in_force_) filter_in_force_.emplace(calibration.infos.left, calibration.infos.right);
  if (error.empty())
    in_force_predicted_px_ =
        calibration.predicted_px > 0.0 ? std::optional<double>(calibration.predicted_px) : std::nullopt;
  return error;
}

std::string CalibrationSession::commit(const CommittedCalibration& infos, const core::StereoRig& rig,
                                       const sensor_msgs::CameraInfo& left_in_force) {
  std::string error, left_answer;
  if (!callSetCameraInfo("left", infos.left, &error, &left_answer)) return error;
  if (!callSetCameraInfo("right", infos.right, &error)) {
    // Our driver only stages a left calibration that does not match the right one in force, and
    // drops it when the right one is refused: nothing changed, nothing to put back.
    if (isStagedAnswer(left_answer)) return error + "; the driver kept the calibration in force";
    // A driver that stored the left one at once: never leave a half-updated pair, put the left
    // calibration in force back.
    std::string restore_error;
    if (!callSetCameraInfo("left", left_in_force, &restore_error))
      return error + "; restoring the left calibration failed too: " + restore_error;
    return error + "; left calibration restored";
  }
  broadcastTransform(rig);
  return "";
}

void CalibrationSession::broadcastTransform(const core::StereoRig& rig) {
  std::lock_guard<std::mutex> lock(tf_mutex_);
  tf_broadcaster_.sendTransform(
      toTransformStamped(rig.leftFromRight(), params_.left_frame_id, params_.right_frame_id, ros::Time::now()));
}

bool CalibrationSession::callSetCameraInfo(const std::string& side, const sensor_msgs::CameraInfo& info,
                                           std::string* error, std::string* answer) {
  const std::string name = side + "/set_camera_info";
  sensor_msgs::SetCameraInfo srv;
  srv.request.camera_info = info;
  if (!callService(nh_, name, &srv, params_.service_timeout_s, error)) return false;  // bounded
  if (!srv.response.success) {
    *error = nh_.resolveName(name) + " refused: " + srv.response.status_message;
    return false;
  }
  if (answer) *answer = srv.response.status_message;
  return true;
}

}  // namespace embedded_calibration_stereo
