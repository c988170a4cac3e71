#pragma once
// What earlier windows taught about the rig, carried into the next window's solve (ROS-free).
//
// One light window determines the rig only as well as its boards, all about 1.2 m away, and
// its corners' noise allow; most of all the length of the baseline and the disparity offset it
// trades against. Windows taken while nothing changed measure the same rig independently, and
// a change (a zoom, heat, a knock) moves some parameters and not others. The filter keeps the
// last accepted solve and its covariance (the state) and, for a new window, compares the
// window's own solve (without prior) with it, group by group:
//
//   d^2 = delta^T (s (C_window + C_state) + Q dt) ^-1 delta   (delta = window - state)
//
// chi-square with the group's size if nothing changed. A group beyond the change_probability
// quantile is taken as changed. The test is liberal on purpose: a group wrongly taken as
// changed only loses its prior for one window, while a change the test misses is pulled back
// toward the old value by the prior (a 3-sigma change by about a third). s (covariance_scale)
// is how much the solves' covariances understate their errors (on a moving world the tracked
// corners' errors are not quite independent: docs/figures.md), Q a random walk over the time
// since the state. The state's marginal over the groups not taken as changed, with covariance
// s C_state + Q dt, is the window's prior (RigPrior). Solved with it, the window keeps what it measured and adds
// what it could not; accepted, that solve is the new state. Groups: per camera the focal
// lengths (fx, fy), the principal point, the distortion; the stereo rotation; the stereo
// translation. A zoom changes the focal lengths (and often the principal point and distortion a
// little: then those groups too fail the test); heat and knocks the extrinsics.
//
// Heat and most knocks turn the right camera about its own centre: the rotation R of
// right_from_left changes, and its translation t = -R C turns with it while the right camera's
// centre C (in the left camera's frame) stays. The state's translation is therefore carried to
// the window's rotation before it is compared and before it is the prior's (t = -R_window C_state,
// its covariance carried with it): such a turn is a change of the stereo rotation alone, and the
// baseline keeps what earlier windows taught. A move of the camera's centre is still a change of
// the translation.
//
// Threading: not thread-safe; one owner (the calibrator's worker thread).
#include <optional>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"

namespace embedded_calibration_stereo::core {

struct CalibrationFilterOptions {
  // Chance that an unchanged group is taken as changed by one window (the test's level).
  double change_probability = 0.05;
  // How much the solves' covariances understate their errors (variance ratio): 1 for exact
  // corner noise models (synthetic tests), about 2 for the window tracker on a moving world.
  double covariance_scale = 2.0;
  // Random walk per square root of a second: what may drift between windows unseen.
  double focal_walk_rel = 1e-5;          // of fx and fy
  double principal_point_walk_px = 0.005;
  double distortion_walk = 1e-5;          // each term
  double rotation_walk_deg = 5e-4;
  double translation_walk_m = 2e-6;
  // Empty when usable, otherwise what is wrong (names the field).
  std::string validate() const;
};

// The groups' names, for messages: "left focal length", "left principal point", "left
// distortion", the same for the right camera, "stereo rotation", "stereo translation".
const std::vector<std::string>& calibrationGroupNames();

// The groups a turn of the right camera and a zoom move: what the health monitor's change model
// (calibration_monitor.h) sees change.
const std::vector<std::string>& turnAndZoomGroups();

// The x that a chi-square variable with `dof` degrees of freedom exceeds with probability
// `upper_tail` (the innovation test's limit).
double chiSquareQuantile(double upper_tail, int dof);

class CalibrationFilter {
 public:
  // Throws std::invalid_argument when options.validate() fails.
  explicit CalibrationFilter(CalibrationFilterOptions options = {});

  // Forget the state: the next window gets no prior (a calibration set from outside).
  void reset() { state_.reset(); }
  bool hasState() const { return state_.has_value(); }
  // The state: a rig as solved, with its covariance (BundleAdjustmentSummary::rig_covariance;
  // zero rows and columns for parameters held), at time_s (seconds, any clock the caller keeps).
  void setState(const StereoRig& rig, const RigCovariance& covariance, double time_s);
  const StereoRig* stateRig() const { return state_ ? &state_->rig : nullptr; }

  // The prior for a window at time_s whose own solve (no prior, with its covariance) is
  // `window`; `changed` (optional) receives the names of the groups taken as changed. None
  // without a state, without the window's covariance, or when every group changed.
  // `known_changed`: groups another witness saw change (calibrationGroupNames()' names), taken
  // as changed whatever the test says.
  std::optional<RigPrior> priorFor(const BundleAdjustmentSummary& window, double time_s,
                                   std::vector<std::string>* changed = nullptr,
                                   const std::vector<std::string>& known_changed = {}) const;
  double stateTime() const { return state_ ? state_->time_s : 0.0; }

  const CalibrationFilterOptions& options() const { return options_; }

 private:
  struct State {
    StereoRig rig;
    RigCovariance covariance;
    double time_s = 0.0;
  };
  CalibrationFilterOptions options_;
  std::optional<State> state_;
};

}  // namespace embedded_calibration_stereo::core
