#pragma once
// Ceres cost of the bundle adjuster's rig prior (bundle_adjuster.h, RigPrior): r = w L (theta -
// mean) over the prior's parameters, L the upper Cholesky factor of the inverse of their
// covariance (L^T L = C^-1), w a weight read at every evaluation (the residual variance's
// square root, so that the covariance, scaled by that variance, counts the prior at C). Linear
// in the parameters: the Jacobian is analytic.
//
// Parameter blocks: intrinsics[9] of the left and of the right camera, extrinsics[6]
// (reprojection_cost.h), in rigParameters() order.
//
// Threading: immutable after construction except the weight, which the owner changes only
// between solves.
#include <ceres/cost_function.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/reprojection_cost.h"

namespace embedded_calibration_stereo::core {

class RigPriorCost : public ceres::CostFunction {
 public:
  // index: the parameters (rigParameters() order, 0..23) with a prior; mean, covariance: theirs.
  RigPriorCost(std::vector<int> index, const Eigen::VectorXd& mean, const Eigen::MatrixXd& covariance,
               const double* weight)
      : index_(std::move(index)), mean_(mean), weight_(weight) {
    // C^-1 from the eigen-decomposition, its eigenvalues kept above 1e-12 of the largest so
    // that a parameter known (nearly) exactly stays finite.
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(0.5 * (covariance + covariance.transpose()));
    const Eigen::VectorXd values = eig.eigenvalues().cwiseMax(1e-12 * eig.eigenvalues().maxCoeff());
    const Eigen::MatrixXd information = eig.eigenvectors() * values.cwiseInverse().asDiagonal() *
                                        eig.eigenvectors().transpose();
    sqrt_information_ = information.llt().matrixU();
    set_num_residuals(static_cast<int>(index_.size()));
    mutable_parameter_block_sizes()->assign({kIntrinsicsSize, kIntrinsicsSize, kExtrinsicsSize});
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const int n = static_cast<int>(index_.size());
    Eigen::VectorXd difference(n);
    for (int k = 0; k < n; ++k) difference[k] = parameters[block(index_[k])][offset(index_[k])] - mean_[k];
    Eigen::Map<Eigen::VectorXd>(residuals, n) = *weight_ * (sqrt_information_ * difference);
    if (!jacobians) return true;
    const int sizes[3] = {kIntrinsicsSize, kIntrinsicsSize, kExtrinsicsSize};
    for (int b = 0; b < 3; ++b) {
      if (!jacobians[b]) continue;
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> J(jacobians[b], n, sizes[b]);
      J.setZero();
      for (int k = 0; k < n; ++k)
        if (block(index_[k]) == b) J.col(offset(index_[k])) = *weight_ * sqrt_information_.col(k);
    }
    return true;
  }

 private:
  static int block(int i) { return i < kIntrinsicsSize ? 0 : i < 2 * kIntrinsicsSize ? 1 : 2; }
  static int offset(int i) { return i < 2 * kIntrinsicsSize ? i % kIntrinsicsSize : i - 2 * kIntrinsicsSize; }

  std::vector<int> index_;
  Eigen::VectorXd mean_;
  Eigen::MatrixXd sqrt_information_;
  const double* weight_;
};

}  // namespace embedded_calibration_stereo::core
