#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"

#include <ceres/ceres.h>
#include <ceres/covariance.h>
#include <ceres/manifold.h>
#include <ceres/product_manifold.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <set>

#include "embedded_calibration_stereo/core/calibration/calibration_filter.h"
#include "embedded_calibration_stereo/core/calibration/calibration_initializer.h"
#include "embedded_calibration_stereo/core/calibration/corner_tracks.h"
#include "embedded_calibration_stereo/core/calibration/device_model_adjustment.h"
#include "embedded_calibration_stereo/core/calibration/device_model_cost.h"
#include "embedded_calibration_stereo/core/calibration/epipolar_error.h"
#include "embedded_calibration_stereo/core/calibration/observation_validator.h"
#include "embedded_calibration_stereo/core/calibration/reprojection_cost.h"
#include "embedded_calibration_stereo/core/calibration/rig_prior_cost.h"
#include "embedded_calibration_stereo/core/calibration/scene_epipolar_cost.h"

namespace embedded_calibration_stereo::core {

std::string BundleAdjustmentOptions::validate() const {
  if (!(loss_scale_px > 0)) return "loss_scale_px must be > 0";
  if (max_iterations <= 0) return "max_iterations must be > 0";
  if (!(function_tolerance >= 0) || !(gradient_tolerance >= 0) || !(parameter_tolerance >= 0))
    return "tolerances must be >= 0";
  if (num_threads <= 0) return "num_threads must be > 0";
  if (min_corners_per_board < 4) return "min_corners_per_board must be >= 4 (a pose needs 4)";
  if (!(max_outside_image_px >= 0)) return "max_outside_image_px must be >= 0";
  if (!(outlier_threshold_px > 0)) return "outlier_threshold_px must be > 0";
  if (!(max_track_deviation_px > 0)) return "max_track_deviation_px must be > 0";
  if (!(device_prior_angle_deg > 0) || !(device_prior_position_m > 0))
    return "device prior tolerances must be > 0";
  if (!(placement_test_probability > 0 && placement_test_probability < 1))
    return "placement_test_probability must be in (0, 1)";
  if (min_scene_matches < 1) return "min_scene_matches must be >= 1";
  if (!(max_scene_residual_sigmas > 0) || !(scene_loss_sigmas > 0) || !(min_scene_sigma_px > 0))
    return "max_scene_residual_sigmas, scene_loss_sigmas and min_scene_sigma_px must be > 0";
  return "";
}

int RigPrior::activeCount() const { return static_cast<int>(std::count(active.begin(), active.end(), true)); }

RigParameters rigParameters(const StereoRig& rig) {
  RigParameters p;
  const PinholeCamera* cameras[2] = {&rig.left, &rig.right};
  for (int c = 0; c < 2; ++c) {
    const PinholeCamera& cam = *cameras[c];
    p.segment<9>(9 * c) << cam.fx, cam.fy, cam.cx, cam.cy, cam.dist[0], cam.dist[1], cam.dist[2],
        cam.dist[3], cam.dist[4];
  }
  // The rotation vector as the bundle adjuster's extrinsics block holds it.
  p.segment<3>(18) = rotationVector(rig.right_from_left.linear());
  p.segment<3>(21) = rig.right_from_left.translation();
  return p;
}

StereoRig rigFromParameters(const RigParameters& p, const StereoRig& like) {
  StereoRig rig = like;
  PinholeCamera* cameras[2] = {&rig.left, &rig.right};
  for (int c = 0; c < 2; ++c) {
    PinholeCamera& cam = *cameras[c];
    const auto b = p.segment<9>(9 * c);
    cam.fx = b[0], cam.fy = b[1], cam.cx = b[2], cam.cy = b[3];
    for (int k = 0; k < 5; ++k) cam.dist[k] = b[4 + k];
  }
  rig.right_from_left = Eigen::Isometry3d::Identity();
  rig.right_from_left.linear() = rotationFromVector(p.segment<3>(18));
  rig.right_from_left.translation() = p.segment<3>(21);
  return rig;
}

std::string BundleAdjustmentConfig::validate() const {
  if (constant_board_poses && !board_poses_from_layout)
    return "constant_board_poses requires board_poses_from_layout";
  if (estimate_k3 && !estimate_k2) return "estimate_k3 requires estimate_k2";
  return "";
}

namespace {

using Clock = std::chrono::steady_clock;
using Intrinsics = std::array<double, kIntrinsicsSize>;
using BoardPose = std::array<double, kBoardPoseSize>;
using PoseKey = std::pair<int, int>;  // (frame or -1 when shared, board index)

Intrinsics toBlock(const PinholeCamera& c) {
  return {{c.fx, c.fy, c.cx, c.cy, c.dist[0], c.dist[1], c.dist[2], c.dist[3], c.dist[4]}};
}

PinholeCamera fromBlock(const Intrinsics& b, int width, int height) {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = b[kFx];
  c.fy = b[kFy];
  c.cx = b[kCx];
  c.cy = b[kCy];
  c.dist = {{b[kK1], b[kK2], b[kP1], b[kP2], b[kK3]}};
  return c;
}

std::array<double, kExtrinsicsSize> toBlock(const Eigen::Isometry3d& t) {
  const Eigen::Vector3d r = rotationVector(t.linear());
  return {{r.x(), r.y(), r.z(), t.translation().x(), t.translation().y(), t.translation().z()}};
}

Eigen::Isometry3d extrinsicsFromBlock(const std::array<double, kExtrinsicsSize>& b) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = rotationFromVector(Eigen::Vector3d(b[0], b[1], b[2]));
  t.translation() = Eigen::Vector3d(b[3], b[4], b[5]);
  return t;
}

BoardPose poseToBlock(const Eigen::Isometry3d& t) {
  const Eigen::Quaterniond q(t.linear());
  return {
      {q.x(), q.y(), q.z(), q.w(), t.translation().x(), t.translation().y(), t.translation().z()}};
}

Eigen::Isometry3d poseFromBlock(const BoardPose& b) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = Eigen::Quaterniond(b[3], b[0], b[1], b[2]).normalized().toRotationMatrix();
  t.translation() = Eigen::Vector3d(b[4], b[5], b[6]);
  return t;
}

// Indices of the intrinsics held at their initial value.
std::vector<int> heldIntrinsics(const BundleAdjustmentConfig& c) {
  std::vector<int> held;
  if (!c.estimate_k1) held.push_back(kK1);
  if (!c.estimate_k2) held.push_back(kK2);
  if (!c.estimate_tangential) held.insert(held.end(), {kP1, kP2});
  if (!c.estimate_k3) held.push_back(kK3);
  return held;
}

std::unique_ptr<ceres::LossFunction> makeLoss(const BundleAdjustmentOptions& o) {
  // Ceres losses act on the squared residual norm; `scale` is in pixels.
  switch (o.loss) {
    case RobustLoss::kHuber:
      return std::make_unique<ceres::HuberLoss>(o.loss_scale_px);
    case RobustLoss::kCauchy:
      return std::make_unique<ceres::CauchyLoss>(o.loss_scale_px);
    case RobustLoss::kNone:
      break;
  }
  return nullptr;
}

// One corner residual and where its parameters live, for statistics after the solve.
struct CornerResidual {
  ceres::CostFunction* cost = nullptr;  // owned by the problem
  CameraSide camera = CameraSide::kLeft;
  std::vector<double*> blocks;         // its parameter blocks, in the cost's order
  const CornerTrack* track = nullptr;  // the observations this residual stands for
};

// kAuto resolved: the device model when the device is given, otherwise shared free poses.
BoardPoseMode resolvedMode(BoardPoseMode mode, const CalibrationInput& input) {
  if (mode != BoardPoseMode::kAuto) return mode;
  return input.device ? BoardPoseMode::kDeviceModel : BoardPoseMode::kSharedAcrossFrames;
}

// One Solve() call, in the stages of COLMAP's bundle adjuster: check the inputs, start the
// cameras, set up the parameter blocks, add the residuals, hold blocks and set manifolds, run
// Ceres, then the residual statistics (robust loss, outliers), the covariance and the summary.
// Each stage reads what the earlier ones left in the members. Lives on Solve()'s stack; Ceres
// keeps pointers into the blocks, so it is neither copied nor moved.
class AdjustmentRun {
 public:
  // `free_start` (device model): the free shared-pose solve of another run of the same input
  // (the held and refined board placements start alike), instead of solving it again.
  AdjustmentRun(const BundleAdjustmentOptions& options, const BundleAdjustmentConfig& config,
                const CalibrationInput& input, const BundleAdjustmentSummary* free_start = nullptr)
      : options_(options), config_(config), input_(input), free_start_(free_start), problem_(problemOptions()) {}
  AdjustmentRun(const AdjustmentRun&) = delete;
  AdjustmentRun& operator=(const AdjustmentRun&) = delete;

  BundleAdjustmentSummary run() {
    if (!validateInputs() || !prepareWeights() || !initializeCameras() || !buildParameterBlocks()) return out_;
    addResiduals();
    holdBlocksAndSetManifolds();
    if (!runSolver()) return out_;
    residualStatistics();
    if (reweight()) {
      if (!runSolver()) return out_;
      residualStatistics();
    }
    computeCovariance();
    if (!scene_.empty() && input_.in_force)
      out_.scene_vs_in_force = compareOnScene(scene_, out_.rig, *input_.in_force, out_.scene_sigma_px,
                                              options_.max_scene_residual_sigmas);
    out_.success = true;
    out_.solve_ms = msSince(start_);
    return out_;
  }
  // The device model's free shared-pose start, once run() has made it (null otherwise).
  const BundleAdjustmentSummary* freeStart() const { return free_solve_ ? &*free_solve_ : nullptr; }

 private:
  static ceres::Problem::Options problemOptions() {
    ceres::Problem::Options o;
    o.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    o.manifold_ownership = ceres::TAKE_OWNERSHIP;
    return o;
  }
  static double msSince(Clock::time_point t) {
    return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
  }
  // Records why the solve failed; returns false for `return fail(...)` in the stages.
  bool fail(const std::string& why) {
    out_.success = false;
    out_.message = why;
    out_.solve_ms = msSince(start_);
    return false;
  }

  // Options, config, board pose mode and layout, image size, then the observations (1).
  bool validateInputs() {
    std::string problem_text = options_.validate();
    if (!problem_text.empty()) return fail("invalid options: " + problem_text);
    problem_text = config_.validate();
    if (!problem_text.empty()) return fail("invalid config: " + problem_text);
    if (!input_.frames || (!input_.boards && !input_.device))
      return fail("no observations or no board layout given");
    mode_ = resolvedMode(options_.board_pose_mode, input_);
    device_mode_ = mode_ == BoardPoseMode::kDeviceModel;
    shared_ = mode_ != BoardPoseMode::kPerFrame;
    if (device_mode_ && !input_.device) return fail("the device model needs the device");
    if (input_.device) {
      const std::string device_problem = input_.device->validate();
      if (!device_problem.empty()) return fail("invalid device: " + device_problem);
      device_layout_ = input_.device->virtualBoards();
    }
    // The device model takes its layout from the device, the free modes the given one.
    layout_ = (device_mode_ || !input_.boards) ? &device_layout_ : input_.boards;
    out_.board_poses = device_mode_                        ? "device model"
                       : mode_ == BoardPoseMode::kPerFrame ? "per-frame free poses"
                                                           : "shared free poses";

    if (!resolveImageSize()) return false;
    ObservationValidationOptions vo;
    vo.image_width = width_;
    vo.image_height = height_;
    vo.min_corners_per_board = options_.min_corners_per_board;
    vo.max_outside_image_px = options_.max_outside_image_px;
    valid_ = validateObservations(*input_.frames, *layout_, vo);
    out_.dropped = std::move(valid_.dropped);
    if (valid_.views.empty()) return fail("no usable board observation");
    return true;
  }

  // Image size: given, or that of the calibration in force; both must agree.
  bool resolveImageSize() {
    width_ = input_.image_width, height_ = input_.image_height;
    if (input_.in_force) {
      const StereoRig& f = *input_.in_force;
      const std::string rig_problem = f.validate();
      if (!rig_problem.empty()) return fail("calibration in force is invalid: " + rig_problem);
      if (f.left.width != f.right.width || f.left.height != f.right.height)
        return fail("left and right image sizes of the calibration in force differ");
      if (width_ <= 0 && height_ <= 0) width_ = f.left.width, height_ = f.left.height;
      if (width_ != f.left.width || height_ != f.left.height)
        return fail("image size " + std::to_string(width_) + "x" + std::to_string(height_) +
                    " differs from the calibration in force (" + std::to_string(f.left.width) +
                    "x" + std::to_string(f.left.height) + ")");
    }
    if (width_ <= 0 || height_ <= 0) return fail("image size unknown or invalid");
    return true;
  }

  // Scene constraints and rig prior (1b): their weights against the corners need the corners'
  // residual variance, so the boards are solved alone first. At that solution, the scene
  // matches' robust spread about their epipolar lines, the wrong matches dropped, and their
  // weight (both spreads). Too few matches: boards only.
  bool prepareWeights() {
    std::vector<SceneMatch> all;
    if (options_.use_scene_matches)
      for (const StereoObservation& f : *input_.frames) all.insert(all.end(), f.scene.begin(), f.scene.end());
    const bool scene = static_cast<int>(all.size()) >= options_.min_scene_matches;
    const bool prior = input_.rig_prior && input_.rig_prior->activeCount() > 0;
    if (!scene && !prior) return true;
    const BundleAdjustmentSummary* reference = input_.weights_from;
    BundleAdjustmentSummary boards_only;
    if (!reference || !reference->success) {
      BundleAdjustmentOptions boards_options = options_;
      boards_options.compute_covariance = false;
      boards_options.use_scene_matches = false;
      CalibrationInput boards_input = input_;
      boards_input.rig_prior.reset();
      boards_input.weights_from = nullptr;
      boards_only = BundleAdjuster(boards_options, config_).Solve(boards_input);
      if (!boards_only.success) return fail(boards_only.message);
      reference = &boards_only;
    }
    const double corner_sigma = std::max(reference->residual_sigma_px, 1e-4);
    prior_weight_ = corner_sigma;
    if (!scene) return true;
    scene_focal_px_ = reference->rig.right.fy;
    const std::vector<double> distances = sceneEpipolarDistances(all, reference->rig, scene_focal_px_);
    const double sigma = std::max(options_.min_scene_sigma_px, robustSpread(distances));
    for (size_t i = 0; i < distances.size(); ++i)
      if (distances[i] <= options_.max_scene_residual_sigmas * sigma) scene_.push_back(all[i]);
    out_.scene_matches_dropped = static_cast<int>(all.size() - scene_.size());
    if (static_cast<int>(scene_.size()) < options_.min_scene_matches) {
      scene_.clear();
      return true;
    }
    scene_weight_ = corner_sigma / sigma;
    scene_loss_ = std::make_unique<ceres::CauchyLoss>(options_.scene_loss_sigmas * corner_sigma);
    return true;
  }

  // 1.4826 times the median of |values| (the standard deviation for Gaussian values); 0 if none.
  static double robustSpread(std::vector<double> values) {
    if (values.empty()) return 0.0;
    const size_t mid = values.size() / 2;
    std::nth_element(values.begin(), values.begin() + mid, values.end());
    return 1.4826 * values[mid];
  }

  // The initial cameras (2): the calibration in force, Zhang's closed form, or - for the device
  // model - a free shared-pose solve, whose virtual boards the nominal device is aligned to next.
  bool initializeCameras() {
    if (device_mode_) {
      BundleAdjustmentOptions free_options = options_;
      free_options.board_pose_mode = BoardPoseMode::kSharedAcrossFrames;
      free_options.compute_covariance = false;
      free_options.use_scene_matches = false;  // a start: the boards alone are quick and enough
      CalibrationInput free_input = input_;
      free_input.rig_prior.reset();  // a start, as above
      free_input.weights_from = nullptr;
      free_input.boards = layout_;
      free_input.device = nullptr;
      free_input.image_width = width_;
      free_input.image_height = height_;
      free_solve_ = free_start_ ? *free_start_ : BundleAdjuster(free_options, config_).Solve(free_input);
      if (!free_solve_->success)
        return fail("device model: the free-pose solve that starts it failed: " +
                    free_solve_->message);
    }
    const bool use_in_force =
        options_.initialization == InitializationMode::kFromInForce ||
        (options_.initialization == InitializationMode::kAuto && input_.in_force.has_value());
    if (device_mode_) {
      initial_ = free_solve_->rig;
      out_.initialization = free_solve_->initialization;
    } else if (use_in_force) {
      if (!input_.in_force)
        return fail("initialisation from the calibration in force, but none given");
      initial_ = *input_.in_force;
      out_.initialization = "in force";
    } else {
      ZhangInitialization zhang = initializeWithZhang(valid_.views, *layout_, width_, height_);
      if (!zhang.ok) return fail(zhang.message);
      initial_ = zhang.rig;
      out_.initialization = "zhang";
    }
    return true;
  }

  // The parameter blocks (3): cameras, extrinsics, and the board poses (PnP, or the layout's)
  // or the device pose and planes (aligned to the free solve, or the given device's). Views
  // whose board gets no initial pose are dropped here.
  bool buildParameterBlocks() {
    intrinsics_ = {{toBlock(initial_.left), toBlock(initial_.right)}};
    extrinsics_ = toBlock(initial_.right_from_left);
    priors_.angle_tolerance_rad = options_.device_prior_angle_deg * M_PI / 180.0;
    priors_.position_tolerance_m = options_.device_prior_position_m;
    priors_.refine_planes = options_.refine_mirror_planes;
    priors_.refine_placement = options_.board_placement == BoardPlacement::kRefined;
    out_.board_placement_refined = device_mode_ && priors_.refine_placement;
    const std::vector<VirtualBoard>& layout = *layout_;
    std::vector<BoardView>& views = valid_.views;
    if (device_mode_) {
      device_blocks_ = std::make_unique<DeviceModelBlocks>(*input_.device);
      if (!config_.board_poses_from_layout &&
          device_blocks_->alignTo(layout, free_solve_->rig_from_board, priors_) < 0)
        return fail("device model: no virtual board to align the device to");
      return true;
    }
    std::set<PoseKey> failed;
    const std::map<PoseKey, Eigen::Isometry3d> initial_poses = initialBoardPoses(
        initial_, views, layout, shared_, config_.board_poses_from_layout, &failed);
    pose_blocks_.reserve(initial_poses.size());  // never reallocated: Ceres keeps pointers
    for (const auto& [key, pose] : initial_poses) {
      pose_keys_.push_back(key);
      pose_index_[key] = pose_blocks_.size();
      pose_blocks_.push_back(poseToBlock(pose));
    }
    if (failed.empty()) return true;
    std::vector<BoardView> kept;
    for (BoardView& v : views) {
      if (failed.count({shared_ ? -1 : v.frame, v.board})) {
        out_.dropped.push_back("frame " + std::to_string(v.frame) + " board " +
                               std::to_string(layout[v.board].virtual_id) +
                               ": no initial pose (degenerate corners), dropped");
      } else {
        kept.push_back(std::move(v));
      }
    }
    views = std::move(kept);
    if (views.empty()) return fail("no board observation with a usable initial pose");
    return true;
  }

  // The robust loss of a track of n observations: n * rho(|p - mean|^2) stands for the n
  // observations (one ScaledLoss per n, shared by the tracks of that length).
  ceres::LossFunction* lossFor(size_t n) {
    if (n == 1) return loss_.get();
    auto& l = track_losses_[n];
    if (!l)
      l = std::make_unique<ceres::ScaledLoss>(loss_.get(), static_cast<double>(n),
                                              ceres::DO_NOT_TAKE_OWNERSHIP);
    return l.get();
  }

  // The residuals (4): one block per corner track (per corner observation in kPerFrame mode;
  // per corner over all frames, on the track mean weighted by its length, when shared).
  void addResiduals() {
    const std::vector<VirtualBoard>& layout = *layout_;
    tracks_ = buildCornerTracks(valid_.views, shared_, options_.max_track_deviation_px);
    if (tracks_.rejected > 0)
      out_.dropped.push_back(std::to_string(tracks_.rejected) +
                             " corner observation(s) further than " +
                             std::to_string(options_.max_track_deviation_px) +
                             " px from the median of their track across frames, dropped");
    loss_ = makeLoss(options_);
    std::set<int> boards_seen[2];
    for (const CornerTrack& t : tracks_.tracks) {
      const VirtualBoard& board = layout[t.board];
      boards_seen[static_cast<int>(t.camera)].insert(board.virtual_id);
      CornerResidual r;
      r.camera = t.camera;
      r.track = &t;
      const bool right = t.camera == CameraSide::kRight;
      double* camera = intrinsics_[right ? 1 : 0].data();
      if (device_mode_) {
        r.blocks = device_blocks_->residualBlocks(board, camera, right ? extrinsics_.data() : nullptr);
        r.cost = DeviceCornerReprojectionCost::Create(
            device_blocks_->cornerInBoard(board.board_index, t.corner_id), t.mean, right,
            device_blocks_->planeCount(board.copy_index));
      } else {
        double* pose = pose_blocks_[pose_index_.at({t.frame, t.board})].data();
        const Eigen::Vector3d corner = board.cornerInBoard(t.corner_id);
        r.blocks = {camera, pose};
        if (right) r.blocks.push_back(extrinsics_.data());
        r.cost = right ? RightCornerReprojectionCost::Create(corner, t.mean)
                       : LeftCornerReprojectionCost::Create(corner, t.mean);
      }
      problem_.AddResidualBlock(r.cost, lossFor(t.observations.size()), r.blocks);
      scatter_sq_ += t.scatter_sq;
      residuals_.push_back(r);
    }
    for (const SceneMatch& m : scene_)
      scene_ids_.push_back(problem_.AddResidualBlock(
          SceneEpipolarCost::Create(m, scene_focal_px_, &scene_weight_), scene_loss_.get(),
          intrinsics_[0].data(), intrinsics_[1].data(), extrinsics_.data()));
    out_.scene_matches_used = static_cast<int>(scene_.size());
    addRigPrior();
    out_.frames_used = valid_.frames_used;
    out_.boards_left = static_cast<int>(boards_seen[0].size());
    out_.boards_right = static_cast<int>(boards_seen[1].size());
  }

  // The rig prior over the parameters it has that this solve estimates (its marginal over them).
  void addRigPrior() {
    if (!input_.rig_prior || !problem_.HasParameterBlock(intrinsics_[0].data()) ||
        !problem_.HasParameterBlock(intrinsics_[1].data()) || !problem_.HasParameterBlock(extrinsics_.data()))
      return;
    const RigPrior& prior = *input_.rig_prior;
    const std::vector<int> held = heldIntrinsics(config_);
    const bool constant[3] = {config_.constant_left_intrinsics, config_.constant_right_intrinsics,
                              config_.constant_extrinsics};
    std::vector<int> index;
    for (int i = 0; i < kRigParameterCount; ++i) {
      const int block = i < kIntrinsicsSize ? 0 : i < 2 * kIntrinsicsSize ? 1 : 2;
      const bool held_term = block < 2 && std::count(held.begin(), held.end(), i % kIntrinsicsSize) > 0;
      if (prior.active[i] && !constant[block] && !held_term) index.push_back(i);
    }
    if (index.empty()) return;
    const int n = static_cast<int>(index.size());
    Eigen::VectorXd mean(n);
    Eigen::MatrixXd covariance(n, n);
    for (int a = 0; a < n; ++a) {
      mean[a] = prior.mean[index[a]];
      for (int b = 0; b < n; ++b) covariance(a, b) = prior.covariance(index[a], index[b]);
    }
    prior_ids_.push_back(problem_.AddResidualBlock(new RigPriorCost(index, mean, covariance, &prior_weight_), nullptr,
                                                   intrinsics_[0].data(), intrinsics_[1].data(), extrinsics_.data()));
    out_.prior_parameters = n;
  }

  // What the config holds (constant blocks, held distortion terms as a subset manifold), the
  // device model's manifolds and priors, and the unit-quaternion manifold of the board poses.
  void holdBlocksAndSetManifolds() {
    const std::vector<int> held = heldIntrinsics(config_);
    const bool constant_intrinsics[2] = {config_.constant_left_intrinsics,
                                         config_.constant_right_intrinsics};
    for (int c = 0; c < 2; ++c) {
      double* block = intrinsics_[c].data();
      if (!problem_.HasParameterBlock(block)) continue;
      camera_blocks_.push_back(block);
      if (constant_intrinsics[c])
        problem_.SetParameterBlockConstant(block);
      else if (!held.empty())
        problem_.SetManifold(block, new ceres::SubsetManifold(kIntrinsicsSize, held));
    }
    if (problem_.HasParameterBlock(extrinsics_.data())) {
      camera_blocks_.push_back(extrinsics_.data());
      if (config_.constant_extrinsics) problem_.SetParameterBlockConstant(extrinsics_.data());
    }
    if (device_mode_) {
      const std::vector<ceres::ResidualBlockId> device_priors =
          device_blocks_->configure(&problem_, priors_, config_.constant_board_poses);
      prior_ids_.insert(prior_ids_.end(), device_priors.begin(), device_priors.end());
    }
    for (BoardPose& pose : pose_blocks_) {
      if (!problem_.HasParameterBlock(pose.data())) continue;
      problem_.SetManifold(
          pose.data(),
          new ceres::ProductManifold<ceres::EigenQuaternionManifold, ceres::EuclideanManifold<3>>());
      if (config_.constant_board_poses) problem_.SetParameterBlockConstant(pose.data());
    }
    for (double* b : camera_blocks_) any_free_camera_block_ |= !problem_.IsParameterBlockConstant(b);
  }

  // The solve (5) and the solution into the summary. With free poses each residual touches one
  // board pose, so the poses are eliminated (Schur) and the reduced system has only the camera
  // blocks (at most 24 unknowns). The device model has a few dozen unknowns in all, each
  // touched by many residuals: dense QR.
  bool runSolver() {
    ceres::Solver::Options solver_options;
    solver_options.max_num_iterations = options_.max_iterations;
    solver_options.function_tolerance = options_.function_tolerance;
    solver_options.gradient_tolerance = options_.gradient_tolerance;
    solver_options.parameter_tolerance = options_.parameter_tolerance;
    solver_options.num_threads = options_.num_threads;
    solver_options.logging_type = ceres::SILENT;
    if (device_mode_) {
      solver_options.linear_solver_type = ceres::DENSE_QR;
    } else if (any_free_camera_block_ && !config_.constant_board_poses) {
      auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
      for (BoardPose& pose : pose_blocks_)
        if (problem_.HasParameterBlock(pose.data())) ordering->AddElementToGroup(pose.data(), 0);
      for (double* b : camera_blocks_) ordering->AddElementToGroup(b, 1);
      solver_options.linear_solver_ordering = ordering;
      solver_options.linear_solver_type = ceres::DENSE_SCHUR;
    } else {
      solver_options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    }
    const auto ceres_start = Clock::now();
    ceres::Solve(solver_options, &problem_, &ceres_summary_);
    out_.ceres_ms = msSince(ceres_start);
    out_.iterations = static_cast<int>(ceres_summary_.iterations.size()) - 1;
    out_.initial_cost = ceres_summary_.initial_cost;
    out_.final_cost = ceres_summary_.final_cost;
    out_.converged = ceres_summary_.termination_type == ceres::CONVERGENCE;
    out_.message = ceres_summary_.message;
    if (!ceres_summary_.IsSolutionUsable()) return fail("Ceres: " + ceres_summary_.message);

    out_.rig.left = fromBlock(intrinsics_[0], width_, height_);
    out_.rig.right = fromBlock(intrinsics_[1], width_, height_);
    out_.rig.right_from_left = extrinsicsFromBlock(extrinsics_);
    if (device_mode_) {
      out_.device = device_blocks_->device();
      for (const VirtualBoard& b : out_.device->virtualBoards())
        out_.rig_from_board[b.virtual_id] = b.rig_from_board;
    } else if (shared_) {
      for (size_t i = 0; i < pose_blocks_.size(); ++i)
        out_.rig_from_board[(*layout_)[pose_keys_[i].second].virtual_id] =
            poseFromBlock(pose_blocks_[i]);
    }
    return true;
  }

  // Residual statistics at the solution (6), per observation (plain squared pixel errors, not
  // the robust cost): RMS per camera, outliers (the median test's rejections plus residuals
  // over the threshold), epipolar RMS; then the residual variance: the robust cost of the track
  // means plus the within-track scatter, over the degrees of freedom of the per-observation
  // problem. Weighting a track mean by its length assumes its frames' errors independent; when
  // the track means scatter about the solution clearly more than that predicts (errors common
  // to a window's frames: on a moving scene the tracker's corners of fixed boards share most of
  // their error), the variance is raised to what the track means show, as if each track were one
  // observation, so the covariance (and the predicted accuracy) stays honest.
  void residualStatistics() {
    double sum_sq[2] = {0, 0};
    int count[2] = {0, 0};
    double weighted_mean_sq = 0.0;  // sum over tracks of length * |mean - model|^2
    out_.outliers = tracks_.rejected;
    const double outlier_sq = options_.outlier_threshold_px * options_.outlier_threshold_px;
    for (const CornerResidual& r : residuals_) {
      const int side = static_cast<int>(r.camera);
      Eigen::Vector2d e;
      if (!r.cost->Evaluate(r.blocks.data(), e.data(), nullptr)) continue;
      const Eigen::Vector2d predicted = r.track->mean + e;
      weighted_mean_sq += static_cast<double>(r.track->observations.size()) * e.squaredNorm();
      for (const Eigen::Vector2d& o : r.track->observations) {
        const double sq = (predicted - o).squaredNorm();
        sum_sq[side] += sq;
        ++count[side];
        if (sq > outlier_sq) ++out_.outliers;
      }
    }
    out_.corners_left = count[0];
    out_.corners_right = count[1];
    out_.corners_used = count[0] + count[1];
    out_.rms_left_px = count[0] ? std::sqrt(sum_sq[0] / count[0]) : 0.0;
    out_.rms_right_px = count[1] ? std::sqrt(sum_sq[1] / count[1]) : 0.0;
    out_.epipolar_rms_px = epipolarRms(out_.rig, valid_.views);

    std::vector<double*> blocks;
    problem_.GetParameterBlocks(&blocks);
    free_parameters_ = 0;
    for (double* b : blocks)
      if (!problem_.IsParameterBlockConstant(b))
        free_parameters_ += problem_.ParameterBlockTangentSize(b);
    dof_ = 2 * out_.corners_used - free_parameters_;
    double prior_cost = 0.0;  // the priors are no observations: not in the residual variance
    for (ceres::ResidualBlockId id : prior_ids_) {
      double cost = 0.0;
      problem_.EvaluateResidualBlock(id, false, &cost, nullptr, nullptr);
      prior_cost += cost;
    }
    // The scene's matches have their own noise (weighed against the corners' by scene_weight_):
    // not in the corners' residual variance either.
    double scene_cost = 0.0;
    std::vector<double> scene_distances;
    for (ceres::ResidualBlockId id : scene_ids_) {
      double cost = 0.0, r = 0.0;
      problem_.EvaluateResidualBlock(id, true, &cost, &r, nullptr);
      scene_cost += cost;
      scene_distances.push_back(std::abs(r) / scene_weight_);
    }
    if (!scene_ids_.empty()) {
      out_.scene_sigma_px = std::max(options_.min_scene_sigma_px, robustSpread(scene_distances));
      out_.scene_outliers = static_cast<int>(std::count_if(scene_distances.begin(), scene_distances.end(),
                                                           [&](double d) { return d > 3.0 * out_.scene_sigma_px; }));
    }
    const double data_cost = std::max(0.0, ceres_summary_.final_cost - prior_cost - scene_cost);
    sigma2_ = dof_ > 0 ? (2.0 * data_cost + scatter_sq_) / dof_ : 0.0;
    out_.corner_sq_px2 = 2.0 * data_cost + scatter_sq_;
    out_.residual_dof = dof_;
    out_.residual_sigma_px = std::sqrt(sigma2_);
    const int tracks = static_cast<int>(residuals_.size());
    const int mean_dof = 2 * tracks - free_parameters_;
    if (shared_ && mean_dof > 0 && dof_ > 0 && sigma2_ > 0.0) {
      // A track mean's variance is sigma2 / length if the frames' errors are independent, so
      // length * |mean - model|^2 estimates sigma2 per track (plain squares on both sides: the
      // robust loss would pass outliers off as over-dispersion).
      const double plain_sigma2 = (weighted_mean_sq + scatter_sq_) / dof_;
      const double ratio = (weighted_mean_sq / mean_dof) / plain_sigma2;
      // Chi-square over mean_dof: beyond 3 of its standard deviations, not chance.
      if (ratio > 1.0 + 3.0 * std::sqrt(2.0 / mean_dof)) sigma2_ *= ratio;
    }
  }

  // The scene's and the rig prior's weights from the joint solution's spreads (6b), once: true
  // when one moved by more than a tenth, so that the solve is worth repeating.
  bool reweight() {
    if ((scene_ids_.empty() && out_.prior_parameters == 0) || reweighted_) return false;
    reweighted_ = true;
    const double corner_sigma = std::sqrt(std::max(sigma2_, 1e-8));
    bool moved = std::abs(corner_sigma / prior_weight_ - 1.0) > 0.1;
    prior_weight_ = corner_sigma;
    if (!scene_ids_.empty()) {
      const double weight = corner_sigma / out_.scene_sigma_px;
      moved |= std::abs(weight / scene_weight_ - 1.0) > 0.1;
      scene_weight_ = weight;
    }
    return moved;
  }

  // Covariance of the camera blocks (7), scaled by the residual variance estimate.
  void computeCovariance() {
    const auto covariance_start = Clock::now();
    if (options_.compute_covariance && dof_ > 0 && any_free_camera_block_) {
      ceres::Covariance::Options co;
      co.num_threads = options_.num_threads;
      // Dense SVD is exact and cheap for small problems; sparse QR scales with per-frame poses.
      co.algorithm_type = free_parameters_ <= 300 ? ceres::DENSE_SVD : ceres::SPARSE_QR;
      ceres::Covariance covariance(co);
      // Every pair of camera blocks: the cross terms carry the joint covariance of the rig.
      std::vector<std::pair<const double*, const double*>> pairs;
      for (size_t a = 0; a < camera_blocks_.size(); ++a)
        for (size_t b = a; b < camera_blocks_.size(); ++b) pairs.emplace_back(camera_blocks_[a], camera_blocks_[b]);
      if (covariance.Compute(pairs, &problem_)) {
        out_.covariance_ok = true;
        fillRigCovariance(covariance);
        CameraStddev* stddev[2] = {&out_.left_stddev, &out_.right_stddev};
        for (int c = 0; c < 2; ++c) {
          if (!problem_.HasParameterBlock(intrinsics_[c].data())) continue;
          Eigen::Matrix<double, kIntrinsicsSize, kIntrinsicsSize, Eigen::RowMajor> cov;
          covariance.GetCovarianceBlock(intrinsics_[c].data(), intrinsics_[c].data(), cov.data());
          const Eigen::VectorXd sd = (cov.diagonal() * sigma2_).cwiseMax(0.0).cwiseSqrt();
          *stddev[c] = CameraStddev{
              sd[kFx], sd[kFy], sd[kCx], sd[kCy], {{sd[kK1], sd[kK2], sd[kP1], sd[kP2], sd[kK3]}}};
        }
        if (problem_.HasParameterBlock(extrinsics_.data())) {
          Eigen::Matrix<double, kExtrinsicsSize, kExtrinsicsSize, Eigen::RowMajor> cov;
          covariance.GetCovarianceBlock(extrinsics_.data(), extrinsics_.data(), cov.data());
          const Eigen::Matrix<double, 6, 6> scaled = cov * sigma2_;
          const Eigen::Vector3d t(extrinsics_[3], extrinsics_[4], extrinsics_[5]);
          const Eigen::Vector3d dir = t.normalized();
          out_.baseline_stddev_m =
              std::sqrt(std::max(0.0, dir.dot(scaled.block<3, 3>(3, 3) * dir)));
          const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(scaled.block<3, 3>(0, 0));
          out_.rotation_stddev_deg =
              std::sqrt(std::max(0.0, eig.eigenvalues().maxCoeff())) * 180.0 / M_PI;
        }
      }
    }
    out_.covariance_ms = msSince(covariance_start);
  }

  // Offset of a camera block in rigParameters() order.
  int rigOffset(const double* block) const {
    if (block == intrinsics_[0].data()) return 0;
    if (block == intrinsics_[1].data()) return kIntrinsicsSize;
    return 2 * kIntrinsicsSize;
  }
  static int blockSize(int offset) { return offset < 2 * kIntrinsicsSize ? kIntrinsicsSize : kExtrinsicsSize; }

  void fillRigCovariance(const ceres::Covariance& covariance) {
    for (size_t a = 0; a < camera_blocks_.size(); ++a)
      for (size_t b = a; b < camera_blocks_.size(); ++b) {
        const int oa = rigOffset(camera_blocks_[a]), ob = rigOffset(camera_blocks_[b]);
        const int na = blockSize(oa), nb = blockSize(ob);
        Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> cov(na, nb);
        covariance.GetCovarianceBlock(camera_blocks_[a], camera_blocks_[b], cov.data());
        out_.rig_covariance.block(oa, ob, na, nb) = cov * sigma2_;
        out_.rig_covariance.block(ob, oa, nb, na) = cov.transpose() * sigma2_;
      }
  }

  const BundleAdjustmentOptions& options_;
  const BundleAdjustmentConfig& config_;
  const CalibrationInput& input_;
  const BundleAdjustmentSummary* free_start_ = nullptr;
  const Clock::time_point start_ = Clock::now();
  BundleAdjustmentSummary out_;

  // validateInputs
  BoardPoseMode mode_ = BoardPoseMode::kAuto;
  // prepareWeights: the matches used, their weight against the corners (read by their costs at
  // every evaluation), the focal length that turns their distances into pixels, their loss.
  std::vector<SceneMatch> scene_;
  double scene_weight_ = 1.0;
  double scene_focal_px_ = 1.0;
  std::unique_ptr<ceres::LossFunction> scene_loss_;
  std::vector<ceres::ResidualBlockId> scene_ids_;
  double prior_weight_ = 1.0;  // the rig prior's (the corners' residual sigma)
  bool reweighted_ = false;
  bool device_mode_ = false;
  bool shared_ = true;  // one pose per virtual board for all frames (not kPerFrame)
  std::vector<VirtualBoard> device_layout_;
  const std::vector<VirtualBoard>* layout_ = nullptr;  // device_layout_ or *input_.boards
  int width_ = 0, height_ = 0;
  ValidatedObservations valid_;  // its views are the ones solved
  // initializeCameras
  std::optional<BundleAdjustmentSummary> free_solve_;
  StereoRig initial_;
  // buildParameterBlocks. Ceres keeps pointers into the blocks and, for the Schur solver and
  // the covariance, orders blocks by address: the board poses sit in one vector in PoseKey
  // order (std::map nodes would land wherever the heap's history put them, and the rounding
  // of the results with them), and the camera blocks in these members' order.
  std::array<Intrinsics, 2> intrinsics_{};
  std::array<double, kExtrinsicsSize> extrinsics_{};
  std::vector<BoardPose> pose_blocks_;
  std::vector<PoseKey> pose_keys_;       // of pose_blocks_[i]
  std::map<PoseKey, size_t> pose_index_;  // PoseKey -> index in pose_blocks_
  DeviceModelPriors priors_;
  std::unique_ptr<DeviceModelBlocks> device_blocks_;
  // addResiduals, holdBlocksAndSetManifolds (the problem references the losses, not owns them)
  CornerTracks tracks_;
  std::unique_ptr<ceres::LossFunction> loss_;
  std::map<size_t, std::unique_ptr<ceres::LossFunction>> track_losses_;
  ceres::Problem problem_;
  std::vector<CornerResidual> residuals_;
  double scatter_sq_ = 0.0;  // within-track part of the squared error, constant in the solve
  std::vector<double*> camera_blocks_;
  std::vector<ceres::ResidualBlockId> prior_ids_;
  bool any_free_camera_block_ = false;
  // runSolver, residualStatistics
  ceres::Solver::Summary ceres_summary_;
  int free_parameters_ = 0;
  int dof_ = 0;
  double sigma2_ = 0.0;  // residual variance (px^2)
};

}  // namespace

BundleAdjuster::BundleAdjuster(BundleAdjustmentOptions options, BundleAdjustmentConfig config)
    : options_(std::move(options)), config_(std::move(config)) {}

BundleAdjustmentSummary BundleAdjuster::Solve(const CalibrationInput& input) const {
  if (options_.board_placement != BoardPlacement::kTested ||
      resolvedMode(options_.board_pose_mode, input) != BoardPoseMode::kDeviceModel)
    return AdjustmentRun(options_, config_, input).run();
  BundleAdjustmentOptions held_options = options_, refined_options = options_;
  held_options.board_placement = BoardPlacement::kHeld;
  refined_options.board_placement = BoardPlacement::kRefined;
  AdjustmentRun held_run(held_options, config_, input);
  BundleAdjustmentSummary held = held_run.run();
  BundleAdjustmentSummary refined = AdjustmentRun(refined_options, config_, input, held_run.freeStart()).run();
  if (!refined.success) return held;
  if (!held.success) return refined;
  // Nested models: with the placements right, the held solve's extra cost over the residual
  // variance is chi-square with the extra parameters' count (the refined solve has more).
  const int extra = held.residual_dof - refined.residual_dof;
  const double variance = refined.residual_dof > 0 ? refined.corner_sq_px2 / refined.residual_dof : 0.0;
  const double statistic = variance > 0 ? (held.corner_sq_px2 - refined.corner_sq_px2) / variance : 0.0;
  const double limit = extra > 0 ? chiSquareQuantile(options_.placement_test_probability, extra) : 0.0;
  BundleAdjustmentSummary& chosen = extra > 0 && statistic > limit ? refined : held;
  chosen.placement_test_statistic = statistic;
  chosen.placement_test_limit = limit;
  chosen.solve_ms = held.solve_ms + refined.solve_ms;
  return std::move(chosen);
}

BundleAdjustmentSummary evaluateFixedCalibration(const StereoRig& rig,
                                                 const std::vector<StereoObservation>& frames,
                                                 const std::vector<VirtualBoard>& boards,
                                                 BundleAdjustmentOptions options,
                                                 const CalibrationDevice* device) {
  options.initialization = InitializationMode::kFromInForce;
  options.compute_covariance = false;
  options.use_scene_matches = false;  // the corners' fit, as the quality gate compares it
  BundleAdjustmentConfig config;
  config.constant_left_intrinsics = true;
  config.constant_right_intrinsics = true;
  config.constant_extrinsics = true;
  CalibrationInput input;
  input.frames = &frames;
  input.boards = &boards;
  input.device = device;
  input.in_force = rig;
  return BundleAdjuster(options, config).Solve(input);
}

}  // namespace embedded_calibration_stereo::core
