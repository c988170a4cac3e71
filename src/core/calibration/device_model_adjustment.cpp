#include "embedded_calibration_stereo/core/calibration/device_model_adjustment.h"

#include <ceres/ceres.h>
#include <ceres/manifold.h>
#include <ceres/product_manifold.h>
#include <ceres/sphere_manifold.h>

#include <cmath>

#include "embedded_calibration_stereo/core/calibration/device_model_cost.h"

namespace embedded_calibration_stereo::core {

namespace {

std::array<double, 7> poseBlock(const Eigen::Isometry3d& t) {
  const Eigen::Quaterniond q(t.linear());
  return {
      {q.x(), q.y(), q.z(), q.w(), t.translation().x(), t.translation().y(), t.translation().z()}};
}

Eigen::Isometry3d poseFromBlock(const std::array<double, 7>& b) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = Eigen::Quaterniond(b[3], b[0], b[1], b[2]).normalized().toRotationMatrix();
  t.translation() = Eigen::Vector3d(b[4], b[5], b[6]);
  return t;
}

using PlaneManifold = ceres::ProductManifold<ceres::SphereManifold<3>, ceres::EuclideanManifold<1>>;
using PoseManifold =
    ceres::ProductManifold<ceres::EigenQuaternionManifold, ceres::EuclideanManifold<3>>;

using Planes = std::vector<std::vector<std::array<double, 4>>>;

// A pose block's manifold and weak prior; constant when held.
void addPosePrior(ceres::Problem* problem, std::array<double, 7>* pose,
                  const std::array<double, 7>& nominal, const DeviceModelPriors& priors,
                  bool hold, std::vector<ceres::ResidualBlockId>* ids) {
  problem->SetManifold(pose->data(), new PoseManifold());
  ids->push_back(problem->AddResidualBlock(
      DevicePosePriorCost::Create(poseFromBlock(nominal), priors.angle_tolerance_rad,
                                  priors.position_tolerance_m),
      nullptr, pose->data()));
  if (hold) problem->SetParameterBlockConstant(pose->data());
}

// Manifolds, priors and constant blocks of the device model in `problem`.
std::vector<ceres::ResidualBlockId> addPriors(
    ceres::Problem* problem, std::array<double, 7>* pose, const std::array<double, 7>& nominal_pose,
    std::vector<std::array<double, 7>>* placements,
    const std::vector<std::array<double, 7>>& nominal_placements, Planes* planes,
    const Planes& nominal_planes, const DeviceModelPriors& priors, bool hold) {
  std::vector<ceres::ResidualBlockId> ids;
  if (!problem->HasParameterBlock(pose->data())) return ids;
  addPosePrior(problem, pose, nominal_pose, priors, hold, &ids);
  for (size_t b = 0; b < placements->size(); ++b) {
    std::array<double, 7>* placement = &(*placements)[b];
    if (problem->HasParameterBlock(placement->data()))
      addPosePrior(problem, placement, nominal_placements[b], priors,
                   hold || !priors.refine_placement, &ids);
  }
  for (size_t c = 0; c < planes->size(); ++c)
    for (size_t i = 0; i < (*planes)[c].size(); ++i) {
      double* block = (*planes)[c][i].data();
      if (!problem->HasParameterBlock(block)) continue;
      problem->SetManifold(block, new PlaneManifold());
      const std::array<double, 4>& n = nominal_planes[c][i];
      ids.push_back(problem->AddResidualBlock(
          MirrorPlanePriorCost::Create(Eigen::Vector4d(n[0], n[1], n[2], n[3]),
                                       priors.angle_tolerance_rad, priors.position_tolerance_m),
          nullptr, block));
      if (hold || !priors.refine_planes) problem->SetParameterBlockConstant(block);
    }
  return ids;
}

}  // namespace

DeviceModelBlocks::DeviceModelBlocks(const CalibrationDevice& nominal) : nominal_(nominal) {
  nominal_pose_ = poseBlock(nominal.rig_from_device);
  pose_ = nominal_pose_;
  for (const Chessboard& b : nominal.boards) nominal_placements_.push_back(poseBlock(b.device_from_board));
  placements_ = nominal_placements_;
  for (const std::vector<MirrorPlane>& chain : nominal.copies) {
    std::vector<std::array<double, 4>> blocks;
    for (const MirrorPlane& m : chain) {
      const double norm = m.normal.norm();  // n . x = d with n not unit: scale both
      const Eigen::Vector3d n = m.normal / norm;
      blocks.push_back({{n.x(), n.y(), n.z(), m.distance / norm}});
    }
    nominal_planes_.push_back(blocks);
  }
  planes_ = nominal_planes_;
}

std::vector<double*> DeviceModelBlocks::residualBlocks(const VirtualBoard& board,
                                                       double* intrinsics, double* extrinsics) {
  std::vector<double*> blocks{intrinsics, pose_.data(), placements_.at(board.board_index).data()};
  if (extrinsics) blocks.push_back(extrinsics);
  for (std::array<double, 4>& p : planes_.at(board.copy_index)) blocks.push_back(p.data());
  return blocks;
}

Eigen::Vector3d DeviceModelBlocks::cornerInBoard(int board_index, int corner_id) const {
  return nominal_.boards.at(board_index).cornerInBoard(corner_id);
}

std::vector<ceres::ResidualBlockId> DeviceModelBlocks::configure(ceres::Problem* problem,
                                                                 const DeviceModelPriors& priors,
                                                                 bool hold) {
  return addPriors(problem, &pose_, nominal_pose_, &placements_, nominal_placements_, &planes_,
                   nominal_planes_, priors, hold);
}

double DeviceModelBlocks::alignTo(const std::vector<VirtualBoard>& layout,
                                  const std::map<int, Eigen::Isometry3d>& rig_from_board,
                                  const DeviceModelPriors& priors) {
  ceres::Problem problem;
  int corners = 0;
  for (const VirtualBoard& board : layout) {
    const auto found = rig_from_board.find(board.virtual_id);
    if (found == rig_from_board.end()) continue;
    std::vector<double*> blocks{pose_.data(), placements_.at(board.board_index).data()};
    for (std::array<double, 4>& p : planes_.at(board.copy_index)) blocks.push_back(p.data());
    for (int id = 0; id < board.cornerCount(); ++id) {
      problem.AddResidualBlock(
          DeviceCornerAlignmentCost::Create(cornerInBoard(board.board_index, id),
                                            found->second * board.cornerInBoard(id),
                                            planeCount(board.copy_index)),
          nullptr, blocks);
      ++corners;
    }
  }
  if (corners == 0) return -1.0;
  const std::vector<ceres::ResidualBlockId> prior_ids =
      addPriors(&problem, &pose_, nominal_pose_, &placements_, nominal_placements_, &planes_,
                nominal_planes_, priors, false);
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = 50;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  double prior_cost = 0.0;
  for (ceres::ResidualBlockId id : prior_ids) {
    double cost = 0.0;
    problem.EvaluateResidualBlock(id, false, &cost, nullptr, nullptr);
    prior_cost += cost;
  }
  const double sum_sq_mm = 2.0 * std::max(0.0, summary.final_cost - prior_cost);
  return 1e-3 * std::sqrt(sum_sq_mm / corners);
}

CalibrationDevice DeviceModelBlocks::device() const {
  CalibrationDevice d = nominal_;
  d.rig_from_device = poseFromBlock(pose_);
  for (size_t b = 0; b < placements_.size(); ++b) d.boards[b].device_from_board = poseFromBlock(placements_[b]);
  for (size_t c = 0; c < planes_.size(); ++c)
    for (size_t i = 0; i < planes_[c].size(); ++i) {
      const std::array<double, 4>& p = planes_[c][i];
      d.copies[c][i].normal = Eigen::Vector3d(p[0], p[1], p[2]);
      d.copies[c][i].distance = p[3];
    }
  return d;
}

}  // namespace embedded_calibration_stereo::core
