#pragma once
// Stereo bundle adjustment over the virtual calibration boards (Ceres), in the shape of
// COLMAP's BundleAdjuster: Options (solver behaviour, with a validator), Config (which parameter
// blocks are estimated and which are held), Solve(), Summary.
//
// Estimated: per camera fx, fy, cx, cy (skew fixed at zero) and the configured plumb_bob terms
// (k1, k2 by default; p1, p2 and k3 optional), right_from_left, and the board poses. Metric
// scale comes from the known square size. Residuals are corner reprojection errors (px) under
// a robust loss (Cauchy by default: it resists corners that are consistently mis-localised in
// every frame far better than Huber; on clean data both give the least-squares solution).
//
// Board poses (BoardPoseMode): the embedded device is fixed to the left camera, so every
// frame sees the same virtual boards and only the noise differs.
// - kDeviceModel: the rigid device model. One rig_from_device for all frames, each board's
//   placement in it (Chessboard::device_from_board) and the mirror planes of each copy
//   (MirrorPlane), all refined by default: a virtual corner is a corner of its board's grid,
//   placed by the board's placement and the device pose and reflected by its copy's chain of
//   planes (device_model_cost.h). Needs CalibrationInput::device. Initialised from a
//   kSharedAcrossFrames solve, to whose virtual boards the nominal device is aligned first
//   (device_model_adjustment.h).
// - kSharedAcrossFrames: ONE free pose per virtual board for all frames. The corners are
//   grouped into tracks across frames and each track is one residual on its mean weighted by
//   its length (corner_tracks.h) - exactly the least-squares problem over all observations at
//   the cost of a single frame (the robust loss then acts on track means; transient outliers
//   go by the track median test). The device model uses the same tracks.
// - kPerFrame: a pose per board and frame (Zhang's maximum-likelihood formulation), one
//   residual per corner observation. With the same boards in every frame it carries the same
//   information on the cameras as kSharedAcrossFrames (the Schur complements coincide) at ten
//   times the cost for ten frames.
// - kAuto (default): kDeviceModel when a device is given, otherwise kSharedAcrossFrames.
// The device model is the more accurate, hence the default (bench_calibrator --rig
// config/sim_rig.yaml prints both modes' errors and reported standard deviations;
// docs/figures.md).
// Six free virtual boards leave focal length and board distance nearly interchangeable; the
// rigid three-board copies do not. The extrinsics gain less: all the boards are about the same
// distance away, so the right camera's translation trades against its rotation whatever the
// board model.
// Cost: the device model runs a free shared-pose solve first (its start), so it costs more
// than shared poses alone (bench_calibrator prints the solve times).
//
// Scene constraints (StereoObservation::scene of the frames): correspondences of the scene
// between the two cameras at one instant (scene_matches.h), each an epipolar constraint on both
// cameras and the extrinsics (scene_epipolar_cost.h). The boards all lie about 1.2 m away, where a small
// turn of the right camera and a shift of it look alike; the scene's points at every depth tell
// them apart, which is what the vertical misalignment of a depth user depends on. Their noise
// (matching on scene texture) differs from the corners': a solve without them comes first, the
// matches' robust spread at its solution weighs them against the corners' residual variance
// (and drops those beyond max_scene_residual_sigmas), and after the joint solve the weight is
// set from both spreads again (once more solved when it moved by more than a tenth), so that
// the covariance counts each kind of observation at its own noise.
//
// Solve() runs in named stages (bundle_adjuster.cpp): validate the inputs, initial cameras,
// parameter blocks, residuals, held blocks and manifolds, Ceres, residual statistics and
// outliers, covariance. Its result depends on the input alone, to the last bit: the block order
// that Ceres takes from the blocks' addresses is fixed (test_bundle_adjuster_repeatability).
//
// Threading: a BundleAdjuster is immutable after construction and Solve() keeps its state on
// the stack, so one instance may be used from several threads; it is meant to run on the
// calibrator's worker thread, never on an image callback.
#include <Eigen/Geometry>
#include <array>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/scene_comparison.h"
#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

enum class BoardPoseMode { kAuto, kDeviceModel, kSharedAcrossFrames, kPerFrame };
enum class RobustLoss { kNone, kHuber, kCauchy };
// The boards' placement in the device (device model only): held at the device's values, refined
// from the corners, or tested: solved both ways, refined only when the held placements fit
// clearly worse than chance allows (a likelihood-ratio test: the corners' cost difference over
// their residual variance against chi-square with the refined parameters' count).
enum class BoardPlacement { kHeld, kRefined, kTested };
enum class InitializationMode {
  kAuto,         // the calibration in force when given, otherwise Zhang
  kFromInForce,  // requires the calibration in force
  kZhang,        // closed form from the observations alone
};

struct BundleAdjustmentOptions {
  BoardPoseMode board_pose_mode = BoardPoseMode::kAuto;
  InitializationMode initialization = InitializationMode::kAuto;
  RobustLoss loss = RobustLoss::kCauchy;
  double loss_scale_px = 1.0;  // residual norm (px) where the loss leaves the quadratic
  int max_iterations = 100;
  double function_tolerance = 1e-10;
  double gradient_tolerance = 1e-12;
  double parameter_tolerance = 1e-10;
  int num_threads = 1;
  bool compute_covariance = true;
  // Observation checks (see observation_validator.h).
  int min_corners_per_board = 6;
  double max_outside_image_px = 2.0;
  // Residual norm (px) above which a corner counts as an outlier in the summary.
  double outlier_threshold_px = 3.0;
  // Shared poses: observations further than this from the median of the same corner over the
  // frames are dropped before averaging (see corner_tracks.h).
  double max_track_deviation_px = 2.0;
  // Device model: refine the mirror planes (otherwise held at the device's values; only the
  // device pose is then estimated, which is right only when the planes are known exactly).
  bool refine_mirror_planes = true;
  // Device model: weak prior of the device pose and planes around the given device, only to
  // fix the gauge freedoms (see device_model_adjustment.h). Its default is a hundred times
  // looser than the manufacturing tolerances (~1 mm, ~0.5 deg) so that it does not inform the
  // cameras (the reported standard deviations are then those of the data alone). A prior at
  // the real tolerances narrows fx noticeably (bench_calibrator --prior-deg / --prior-m), but
  // only while the device is within them (a knock may move it further): set it knowingly.
  double device_prior_angle_deg = 50.0;
  double device_prior_position_m = 0.1;
  // Device model: each board's placement in the device (Chessboard::device_from_board). A
  // device description from CAD is off by the housing's tolerance, which held placements turn
  // into corner residuals no camera explains (device_model_adjustment.h); refined placements
  // widen the cameras' uncertainty a little (more parameters). kTested takes the refined solve
  // only when the held one fits worse beyond placement_test_probability of chance, at twice the
  // cost of one solve.
  BoardPlacement board_placement = BoardPlacement::kTested;
  double placement_test_probability = 1e-3;
  // Scene constraints (the frames' StereoObservation::scene), used unless use_scene_matches is
  // false. Fewer usable matches than min_scene_matches: not used. Matches further from their
  // epipolar line than max_scene_residual_sigmas robust spreads at the solve without them are
  // dropped (wrong matches: repeated texture); the rest are under a Cauchy loss at
  // scene_loss_sigmas spreads. The spread is taken as at least min_scene_sigma_px (px).
  bool use_scene_matches = true;
  int min_scene_matches = 50;
  double max_scene_residual_sigmas = 5.0;
  double scene_loss_sigmas = 3.0;
  double min_scene_sigma_px = 0.02;

  // Empty when usable, otherwise what is wrong.
  std::string validate() const;
};

// Which terms are estimated. Terms not estimated are held at their initial value (zero after
// Zhang, the value in force otherwise).
struct BundleAdjustmentConfig {
  bool estimate_k1 = true;
  bool estimate_k2 = true;
  bool estimate_tangential = false;  // p1, p2
  bool estimate_k3 = false;
  bool constant_left_intrinsics = false;
  bool constant_right_intrinsics = false;
  bool constant_extrinsics = false;
  // Start the board poses from VirtualBoard::rig_from_board instead of a PnP estimate (device
  // model: the device pose and planes from the given device instead of aligning them to a
  // free-pose solve), and optionally hold them there (only sensible when the device geometry
  // is known exactly).
  bool board_poses_from_layout = false;
  bool constant_board_poses = false;

  std::string validate() const;
};

// The parameter vector of a rig in the bundle adjuster's order, that of
// BundleAdjustmentSummary::rig_covariance (its camera and extrinsics blocks): left fx, fy, cx,
// cy, k1, k2, p1, p2, k3; the same of the right camera; right_from_left rotation vector (rad)
// then translation (m).
constexpr int kRigParameterCount = 24;
using RigParameters = Eigen::Matrix<double, kRigParameterCount, 1>;
using RigCovariance = Eigen::Matrix<double, kRigParameterCount, kRigParameterCount>;
RigParameters rigParameters(const StereoRig& rig);
// The rig of a parameter vector; image sizes (and skew) come from `like`.
StereoRig rigFromParameters(const RigParameters& parameters, const StereoRig& like);

// A Gaussian prior on some of the rig's parameters (rigParameters() order): what earlier
// windows taught about the parameters this one is not known to have changed
// (calibration_filter.h). The solve adds it as a residual (its cost is not in the residual
// variance), weighed so that the covariance counts it at its own covariance; parameters the
// solve holds are left out of it.
struct RigPrior {
  RigParameters mean = RigParameters::Zero();
  // Of the active parameters (the marginal over them); the other rows and columns are ignored.
  RigCovariance covariance = RigCovariance::Zero();
  std::array<bool, kRigParameterCount> active{};
  int activeCount() const;
};

struct BundleAdjustmentSummary;

struct CalibrationInput {
  const std::vector<StereoObservation>* frames = nullptr;
  // Layout of the virtual boards (CalibrationDevice::virtualBoards()): ids, cols, rows, square,
  // mirrored flags; their rig_from_board is only a guess unless the config says otherwise.
  // May be null when `device` is given (its virtualBoards() are used).
  const std::vector<VirtualBoard>* boards = nullptr;
  // The nominal device (layout held, pose and planes as starting values and prior): required
  // by kDeviceModel, selects it under kAuto.
  const CalibrationDevice* device = nullptr;
  int image_width = 0, image_height = 0;  // must match the cameras of the calibration in force
  std::optional<StereoRig> in_force;
  // Optional prior on the rig's parameters (see RigPrior).
  std::optional<RigPrior> rig_prior;
  // Optional: a solve of the same frames (e.g. without the prior) whose corner residual sigma,
  // scene spread and solution weigh the scene and the prior, instead of a solve of the boards
  // alone first.
  const BundleAdjustmentSummary* weights_from = nullptr;
};

// One standard deviation per reported parameter; zero for parameters held constant.
struct CameraStddev {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  std::array<double, 5> dist{{0, 0, 0, 0, 0}};  // k1, k2, p1, p2, k3
};

struct BundleAdjustmentSummary {
  bool success = false;        // a solution was computed (false: see message)
  bool converged = false;      // Ceres reported convergence
  std::string message;         // why it failed, or the Ceres termination message
  std::string initialization;  // "zhang" or "in force"
  std::string board_poses;     // "device model", "shared free poses" or "per-frame free poses"
  int iterations = 0;
  double initial_cost = 0, final_cost = 0;
  double rms_left_px = 0, rms_right_px = 0;
  double epipolar_rms_px = 0;    // right corners to the epipolar lines of the left ones
  double residual_sigma_px = 0;  // sqrt(2 cost / (residuals - parameters))
  // The corners' squared residuals (the robust cost's, px^2, within-track scatter included) and
  // their degrees of freedom (residuals - parameters): what nested solves are compared by.
  double corner_sq_px2 = 0;
  int residual_dof = 0;
  // Device model: the boards' placements were refined; with BoardPlacement::kTested, the test's
  // statistic (the held solve's extra cost over the residual variance) and its limit.
  bool board_placement_refined = false;
  double placement_test_statistic = 0, placement_test_limit = 0;
  int frames_used = 0;
  int corners_used = 0;  // left + right
  int corners_left = 0, corners_right = 0;
  int boards_left = 0, boards_right = 0;  // distinct virtual boards used per camera
  int outliers = 0;
  double solve_ms = 0;                     // validation, initialisation, solve and covariance
  double ceres_ms = 0, covariance_ms = 0;  // parts of solve_ms
  StereoRig rig;
  bool covariance_ok = false;
  CameraStddev left_stddev, right_stddev;
  double baseline_stddev_m = 0;
  double rotation_stddev_deg = 0;  // sqrt of the largest eigenvalue, rotation vector
  // The joint covariance of the rig's parameters (rigParameters() order), scaled by the
  // residual variance like the standard deviations above (their squares are its diagonal);
  // rows and columns of held parameters are zero. Zero unless covariance_ok. Propagated to
  // depth accuracy by predictStereoAccuracy() (stereo_accuracy.h).
  RigCovariance rig_covariance = RigCovariance::Zero();
  // Estimated rig_from_board by virtual board id (shared or device mode) - the device as seen
  // now.
  std::map<int, Eigen::Isometry3d> rig_from_board;
  // Device model: the estimated device (given layout, estimated pose and planes).
  std::optional<CalibrationDevice> device;
  std::vector<std::string> dropped;  // observations dropped by validation, with the reason
  // Scene constraints: matches used (after the wrong ones were dropped), their robust spread
  // about their epipolar lines (px; the Sampson distance) at the solution, and how many of the
  // used ones lie beyond 3 spreads.
  int scene_matches_used = 0;
  int scene_matches_dropped = 0;
  int prior_parameters = 0;  // parameters the rig prior informed (estimated and active)
  double scene_sigma_px = 0.0;
  int scene_outliers = 0;
  // The used scene matches under this solution and under the calibration in force (when the
  // input has one), at scene_sigma_px, clipped at max_scene_residual_sigmas (scene_comparison.h):
  // what the quality gate consults when the corners fit both alike.
  SceneComparison scene_vs_in_force;
};

class BundleAdjuster {
 public:
  BundleAdjuster(BundleAdjustmentOptions options, BundleAdjustmentConfig config);
  BundleAdjustmentSummary Solve(const CalibrationInput& input) const;

  const BundleAdjustmentOptions& options() const { return options_; }
  const BundleAdjustmentConfig& config() const { return config_; }

 private:
  BundleAdjustmentOptions options_;
  BundleAdjustmentConfig config_;
};

// How well a fixed calibration explains the observations: only the board poses (or the device
// pose and planes, when a device is given and the mode allows) are adjusted, same loss and
// validation, so the RMS is comparable with a full solve's in the same mode. Used by the
// quality gate to judge the calibration in force on fresh observations.
BundleAdjustmentSummary evaluateFixedCalibration(const StereoRig& rig,
                                                 const std::vector<StereoObservation>& frames,
                                                 const std::vector<VirtualBoard>& boards,
                                                 BundleAdjustmentOptions options = {},
                                                 const CalibrationDevice* device = nullptr);

}  // namespace embedded_calibration_stereo::core
