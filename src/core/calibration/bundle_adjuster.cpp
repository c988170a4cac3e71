#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"

#include <ceres/ceres.h>
#include <ceres/covariance.h>
#include <ceres/manifold.h>
#include <ceres/product_manifold.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <set>

#include "embedded_calibration_stereo/core/calibration/calibration_initializer.h"
#include "embedded_calibration_stereo/core/calibration/corner_tracks.h"
#include "embedded_calibration_stereo/core/calibration/device_model_adjustment.h"
#include "embedded_calibration_stereo/core/calibration/device_model_cost.h"
#include "embedded_calibration_stereo/core/calibration/epipolar_error.h"
#include "embedded_calibration_stereo/core/calibration/observation_validator.h"
#include "embedded_calibration_stereo/core/calibration/reprojection_cost.h"

namespace ecs {

std::string BundleAdjustmentOptions::Check() const {
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
  return "";
}

std::string BundleAdjustmentConfig::Check() const {
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
  const Eigen::AngleAxisd aa(t.linear());
  const Eigen::Vector3d r = aa.angle() * aa.axis();
  return {{r.x(), r.y(), r.z(), t.translation().x(), t.translation().y(), t.translation().z()}};
}

Eigen::Isometry3d extrinsicsFromBlock(const std::array<double, kExtrinsicsSize>& b) {
  const Eigen::Vector3d r(b[0], b[1], b[2]);
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  if (r.norm() > 0) t.linear() = Eigen::AngleAxisd(r.norm(), r.normalized()).toRotationMatrix();
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

}  // namespace

BundleAdjuster::BundleAdjuster(BundleAdjustmentOptions options, BundleAdjustmentConfig config)
    : options_(std::move(options)), config_(std::move(config)) {}

BundleAdjustmentSummary BundleAdjuster::Solve(const CalibrationInput& input) const {
  const auto start = Clock::now();
  BundleAdjustmentSummary out;
  const auto fail = [&](const std::string& why) {
    out.success = false;
    out.message = why;
    out.solve_ms = std::chrono::duration<double, std::milli>(Clock::now() - start).count();
    return out;
  };
  std::string problem_text = options_.Check();
  if (!problem_text.empty()) return fail("invalid options: " + problem_text);
  problem_text = config_.Check();
  if (!problem_text.empty()) return fail("invalid config: " + problem_text);
  if (!input.frames || (!input.boards && !input.device))
    return fail("no observations or no board layout given");
  BoardPoseMode mode = options_.board_pose_mode;
  if (mode == BoardPoseMode::kAuto)
    mode = input.device ? BoardPoseMode::kDeviceModel : BoardPoseMode::kSharedAcrossFrames;
  const bool device_mode = mode == BoardPoseMode::kDeviceModel;
  if (device_mode && !input.device) return fail("the device model needs the device");
  std::vector<VirtualBoard> device_layout;
  if (input.device) {
    const std::string device_problem = input.device->validate();
    if (!device_problem.empty()) return fail("invalid device: " + device_problem);
    device_layout = input.device->virtualBoards();
  }
  // The device model takes its layout from the device, the free modes the given one.
  const std::vector<VirtualBoard>& layout =
      (device_mode || !input.boards) ? device_layout : *input.boards;
  out.board_poses = device_mode                        ? "device model"
                    : mode == BoardPoseMode::kPerFrame ? "per-frame free poses"
                                                       : "shared free poses";

  // Image size: given, or that of the calibration in force; both must agree.
  int width = input.image_width, height = input.image_height;
  if (input.in_force) {
    const StereoRig& f = *input.in_force;
    const std::string rig_problem = f.validate();
    if (!rig_problem.empty()) return fail("calibration in force is invalid: " + rig_problem);
    if (f.left.width != f.right.width || f.left.height != f.right.height)
      return fail("left and right image sizes of the calibration in force differ");
    if (width <= 0 && height <= 0) width = f.left.width, height = f.left.height;
    if (width != f.left.width || height != f.left.height)
      return fail("image size " + std::to_string(width) + "x" + std::to_string(height) +
                  " differs from the calibration in force (" + std::to_string(f.left.width) + "x" +
                  std::to_string(f.left.height) + ")");
  }
  if (width <= 0 || height <= 0) return fail("image size unknown or invalid");

  // 1. Validation.
  ObservationValidationOptions vo;
  vo.image_width = width;
  vo.image_height = height;
  vo.min_corners_per_board = options_.min_corners_per_board;
  vo.max_outside_image_px = options_.max_outside_image_px;
  ValidatedObservations valid = validateObservations(*input.frames, layout, vo);
  out.dropped = std::move(valid.dropped);
  std::vector<BoardView>& views = valid.views;
  if (views.empty()) return fail("no usable board observation");

  // The device model starts from a free shared-pose solve: its cameras, and its virtual boards
  // to which the nominal device is aligned.
  std::optional<BundleAdjustmentSummary> free_solve;
  if (device_mode) {
    BundleAdjustmentOptions free_options = options_;
    free_options.board_pose_mode = BoardPoseMode::kSharedAcrossFrames;
    free_options.compute_covariance = false;
    CalibrationInput free_input = input;
    free_input.boards = &layout;
    free_input.device = nullptr;
    free_input.image_width = width;
    free_input.image_height = height;
    free_solve = BundleAdjuster(free_options, config_).Solve(free_input);
    if (!free_solve->success)
      return fail("device model: the free-pose solve that starts it failed: " +
                  free_solve->message);
  }

  // 2. Initial cameras.
  const bool use_in_force =
      options_.initialization == InitializationMode::kFromInForce ||
      (options_.initialization == InitializationMode::kAuto && input.in_force.has_value());
  StereoRig initial;
  if (device_mode) {
    initial = free_solve->rig;
    out.initialization = free_solve->initialization;
  } else if (use_in_force) {
    if (!input.in_force)
      return fail("initialisation from the calibration in force, but none given");
    initial = *input.in_force;
    out.initialization = "in force";
  } else {
    ZhangInitialization zhang = initializeWithZhang(views, layout, width, height);
    if (!zhang.ok) return fail(zhang.message);
    initial = zhang.rig;
    out.initialization = "zhang";
  }

  // 3. Parameter blocks. std::map nodes never move, so Ceres may keep pointers into them.
  const bool shared = mode != BoardPoseMode::kPerFrame;
  std::array<Intrinsics, 2> intrinsics{{toBlock(initial.left), toBlock(initial.right)}};
  std::array<double, kExtrinsicsSize> extrinsics = toBlock(initial.right_from_left);
  std::map<PoseKey, BoardPose> poses;
  DeviceModelPriors priors;
  priors.angle_tolerance_rad = options_.device_prior_angle_deg * M_PI / 180.0;
  priors.position_tolerance_m = options_.device_prior_position_m;
  priors.refine_planes = options_.refine_mirror_planes;
  std::unique_ptr<DeviceModelBlocks> device_blocks;
  if (device_mode) {
    device_blocks = std::make_unique<DeviceModelBlocks>(*input.device);
    if (!config_.board_poses_from_layout &&
        device_blocks->alignTo(layout, free_solve->rig_from_board, priors) < 0)
      return fail("device model: no virtual board to align the device to");
  } else {
    std::set<PoseKey> failed;
    for (const auto& [key, pose] : initialBoardPoses(initial, views, layout, shared,
                                                     config_.board_poses_from_layout, &failed))
      poses[key] = poseToBlock(pose);
    if (!failed.empty()) {
      std::vector<BoardView> kept;
      for (BoardView& v : views) {
        if (failed.count({shared ? -1 : v.frame, v.board})) {
          out.dropped.push_back("frame " + std::to_string(v.frame) + " board " +
                                std::to_string(layout[v.board].virtual_id) +
                                ": no initial pose (degenerate corners), dropped");
        } else {
          kept.push_back(std::move(v));
        }
      }
      views = std::move(kept);
      if (views.empty()) return fail("no board observation with a usable initial pose");
    }
  }

  // 4. Problem: one residual block per corner track (per corner observation in kPerFrame
  // mode; per corner over all frames, on the track mean weighted by its length, when shared).
  const CornerTracks tracks = buildCornerTracks(views, shared, options_.max_track_deviation_px);
  if (tracks.rejected > 0)
    out.dropped.push_back(std::to_string(tracks.rejected) + " corner observation(s) further than " +
                          std::to_string(options_.max_track_deviation_px) +
                          " px from the median of their track across frames, dropped");
  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.manifold_ownership = ceres::TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  const std::unique_ptr<ceres::LossFunction> loss = makeLoss(options_);
  // n * rho(|p - mean|^2) stands for the n observations of a track (one ScaledLoss per n).
  std::map<size_t, std::unique_ptr<ceres::LossFunction>> track_losses;
  const auto lossFor = [&](size_t n) -> ceres::LossFunction* {
    if (n == 1) return loss.get();
    auto& l = track_losses[n];
    if (!l)
      l = std::make_unique<ceres::ScaledLoss>(loss.get(), static_cast<double>(n),
                                              ceres::DO_NOT_TAKE_OWNERSHIP);
    return l.get();
  };
  std::vector<CornerResidual> residuals;
  std::set<int> boards_seen[2];
  double scatter_sq = 0.0;  // within-track part of the squared error, constant in the solve
  for (const CornerTrack& t : tracks.tracks) {
    const VirtualBoard& board = layout[t.board];
    boards_seen[static_cast<int>(t.camera)].insert(board.virtual_id);
    CornerResidual r;
    r.camera = t.camera;
    r.track = &t;
    const bool right = t.camera == CameraSide::kRight;
    double* camera = intrinsics[right ? 1 : 0].data();
    if (device_mode) {
      r.blocks = device_blocks->residualBlocks(board.copy_index, camera,
                                               right ? extrinsics.data() : nullptr);
      r.cost = DeviceCornerReprojectionCost::Create(
          device_blocks->cornerInDevice(board.board_index, t.corner_id), t.mean, right,
          device_blocks->planeCount(board.copy_index));
    } else {
      double* pose = poses.at({t.frame, t.board}).data();
      const Eigen::Vector3d corner = board.cornerInBoard(t.corner_id);
      r.blocks = {camera, pose};
      if (right) r.blocks.push_back(extrinsics.data());
      r.cost = right ? RightCornerReprojectionCost::Create(corner, t.mean)
                     : LeftCornerReprojectionCost::Create(corner, t.mean);
    }
    problem.AddResidualBlock(r.cost, lossFor(t.observations.size()), r.blocks);
    scatter_sq += t.scatter_sq;
    residuals.push_back(r);
  }
  out.frames_used = valid.frames_used;
  out.boards_left = static_cast<int>(boards_seen[0].size());
  out.boards_right = static_cast<int>(boards_seen[1].size());

  const std::vector<int> held = heldIntrinsics(config_);
  const bool constant_intrinsics[2] = {config_.constant_left_intrinsics,
                                       config_.constant_right_intrinsics};
  std::vector<double*> camera_blocks;
  for (int c = 0; c < 2; ++c) {
    double* block = intrinsics[c].data();
    if (!problem.HasParameterBlock(block)) continue;
    camera_blocks.push_back(block);
    if (constant_intrinsics[c])
      problem.SetParameterBlockConstant(block);
    else if (!held.empty())
      problem.SetManifold(block, new ceres::SubsetManifold(kIntrinsicsSize, held));
  }
  if (problem.HasParameterBlock(extrinsics.data())) {
    camera_blocks.push_back(extrinsics.data());
    if (config_.constant_extrinsics) problem.SetParameterBlockConstant(extrinsics.data());
  }
  std::vector<ceres::ResidualBlockId> prior_ids;
  if (device_mode)
    prior_ids = device_blocks->configure(&problem, priors, config_.constant_board_poses);
  for (auto& [key, pose] : poses) {
    if (!problem.HasParameterBlock(pose.data())) continue;
    problem.SetManifold(
        pose.data(),
        new ceres::ProductManifold<ceres::EigenQuaternionManifold, ceres::EuclideanManifold<3>>());
    if (config_.constant_board_poses) problem.SetParameterBlockConstant(pose.data());
  }

  // 5. Solve. With free poses each residual touches one board pose, so the poses are eliminated
  // (Schur) and the reduced system has only the camera blocks (at most 24 unknowns). The device
  // model has a few dozen unknowns in all, each touched by many residuals: dense QR.
  ceres::Solver::Options solver_options;
  solver_options.max_num_iterations = options_.max_iterations;
  solver_options.function_tolerance = options_.function_tolerance;
  solver_options.gradient_tolerance = options_.gradient_tolerance;
  solver_options.parameter_tolerance = options_.parameter_tolerance;
  solver_options.num_threads = options_.num_threads;
  solver_options.logging_type = ceres::SILENT;
  bool any_free_camera_block = false;
  for (double* b : camera_blocks) any_free_camera_block |= !problem.IsParameterBlockConstant(b);
  if (device_mode) {
    solver_options.linear_solver_type = ceres::DENSE_QR;
  } else if (any_free_camera_block && !config_.constant_board_poses) {
    auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
    for (auto& [key, pose] : poses)
      if (problem.HasParameterBlock(pose.data())) ordering->AddElementToGroup(pose.data(), 0);
    for (double* b : camera_blocks) ordering->AddElementToGroup(b, 1);
    solver_options.linear_solver_ordering = ordering;
    solver_options.linear_solver_type = ceres::DENSE_SCHUR;
  } else {
    solver_options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  }
  ceres::Solver::Summary ceres_summary;
  const auto ceres_start = Clock::now();
  ceres::Solve(solver_options, &problem, &ceres_summary);
  out.ceres_ms = std::chrono::duration<double, std::milli>(Clock::now() - ceres_start).count();
  out.iterations = static_cast<int>(ceres_summary.iterations.size()) - 1;
  out.initial_cost = ceres_summary.initial_cost;
  out.final_cost = ceres_summary.final_cost;
  out.converged = ceres_summary.termination_type == ceres::CONVERGENCE;
  out.message = ceres_summary.message;
  if (!ceres_summary.IsSolutionUsable()) return fail("Ceres: " + ceres_summary.message);

  out.rig.left = fromBlock(intrinsics[0], width, height);
  out.rig.right = fromBlock(intrinsics[1], width, height);
  out.rig.right_from_left = extrinsicsFromBlock(extrinsics);
  if (device_mode) {
    out.device = device_blocks->device();
    for (const VirtualBoard& b : out.device->virtualBoards())
      out.rig_from_board[b.virtual_id] = b.rig_from_board;
  } else if (shared) {
    for (const auto& [key, pose] : poses)
      out.rig_from_board[layout[key.second].virtual_id] = poseFromBlock(pose);
  }

  // 6. Residual statistics at the solution, per observation (plain squared pixel errors).
  double sum_sq[2] = {0, 0};
  int count[2] = {0, 0};
  out.outliers = tracks.rejected;
  const double outlier_sq = options_.outlier_threshold_px * options_.outlier_threshold_px;
  for (const CornerResidual& r : residuals) {
    const int side = static_cast<int>(r.camera);
    Eigen::Vector2d e;
    if (!r.cost->Evaluate(r.blocks.data(), e.data(), nullptr)) continue;
    const Eigen::Vector2d predicted = r.track->mean + e;
    for (const Eigen::Vector2d& o : r.track->observations) {
      const double sq = (predicted - o).squaredNorm();
      sum_sq[side] += sq;
      ++count[side];
      if (sq > outlier_sq) ++out.outliers;
    }
  }
  out.corners_left = count[0];
  out.corners_right = count[1];
  out.corners_used = count[0] + count[1];
  out.rms_left_px = count[0] ? std::sqrt(sum_sq[0] / count[0]) : 0.0;
  out.rms_right_px = count[1] ? std::sqrt(sum_sq[1] / count[1]) : 0.0;
  out.epipolar_rms_px = epipolarRms(out.rig, views);

  // Residual variance: robust cost of the track means plus the within-track scatter, over the
  // degrees of freedom of the per-observation problem.
  int free_parameters = 0;
  std::vector<double*> blocks;
  problem.GetParameterBlocks(&blocks);
  for (double* b : blocks)
    if (!problem.IsParameterBlockConstant(b))
      free_parameters += problem.ParameterBlockTangentSize(b);
  const int dof = 2 * out.corners_used - free_parameters;
  double prior_cost = 0.0;  // the device prior is no observation: not in the residual variance
  for (ceres::ResidualBlockId id : prior_ids) {
    double cost = 0.0;
    problem.EvaluateResidualBlock(id, false, &cost, nullptr, nullptr);
    prior_cost += cost;
  }
  const double data_cost = std::max(0.0, ceres_summary.final_cost - prior_cost);
  const double sigma2 = dof > 0 ? (2.0 * data_cost + scatter_sq) / dof : 0.0;
  out.residual_sigma_px = std::sqrt(sigma2);

  // 7. Covariance of the camera blocks, scaled by the residual variance estimate.
  const auto covariance_start = Clock::now();
  if (options_.compute_covariance && dof > 0 && any_free_camera_block) {
    ceres::Covariance::Options co;
    co.num_threads = options_.num_threads;
    // Dense SVD is exact and cheap for small problems; sparse QR scales with per-frame poses.
    co.algorithm_type = free_parameters <= 300 ? ceres::DENSE_SVD : ceres::SPARSE_QR;
    ceres::Covariance covariance(co);
    std::vector<std::pair<const double*, const double*>> pairs;
    for (double* b : camera_blocks) pairs.emplace_back(b, b);
    if (covariance.Compute(pairs, &problem)) {
      out.covariance_ok = true;
      CameraStddev* stddev[2] = {&out.left_stddev, &out.right_stddev};
      for (int c = 0; c < 2; ++c) {
        if (!problem.HasParameterBlock(intrinsics[c].data())) continue;
        Eigen::Matrix<double, kIntrinsicsSize, kIntrinsicsSize, Eigen::RowMajor> cov;
        covariance.GetCovarianceBlock(intrinsics[c].data(), intrinsics[c].data(), cov.data());
        const Eigen::VectorXd sd = (cov.diagonal() * sigma2).cwiseMax(0.0).cwiseSqrt();
        *stddev[c] = CameraStddev{
            sd[kFx], sd[kFy], sd[kCx], sd[kCy], {{sd[kK1], sd[kK2], sd[kP1], sd[kP2], sd[kK3]}}};
      }
      if (problem.HasParameterBlock(extrinsics.data())) {
        Eigen::Matrix<double, kExtrinsicsSize, kExtrinsicsSize, Eigen::RowMajor> cov;
        covariance.GetCovarianceBlock(extrinsics.data(), extrinsics.data(), cov.data());
        const Eigen::Matrix<double, 6, 6> scaled = cov * sigma2;
        const Eigen::Vector3d t(extrinsics[3], extrinsics[4], extrinsics[5]);
        const Eigen::Vector3d dir = t.normalized();
        out.baseline_stddev_m = std::sqrt(std::max(0.0, dir.dot(scaled.block<3, 3>(3, 3) * dir)));
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(scaled.block<3, 3>(0, 0));
        out.rotation_stddev_deg =
            std::sqrt(std::max(0.0, eig.eigenvalues().maxCoeff())) * 180.0 / M_PI;
      }
    }
  }
  out.covariance_ms =
      std::chrono::duration<double, std::milli>(Clock::now() - covariance_start).count();
  out.success = true;
  out.solve_ms = std::chrono::duration<double, std::milli>(Clock::now() - start).count();
  return out;
}

BundleAdjustmentSummary evaluateFixedCalibration(const StereoRig& rig,
                                                 const std::vector<StereoObservation>& frames,
                                                 const std::vector<VirtualBoard>& boards,
                                                 BundleAdjustmentOptions options,
                                                 const CalibrationDevice* device) {
  options.initialization = InitializationMode::kFromInForce;
  options.compute_covariance = false;
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

}  // namespace ecs
