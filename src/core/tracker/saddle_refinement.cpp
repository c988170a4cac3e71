#include "embedded_calibration_stereo/core/tracker/saddle_refinement.h"

#include <ceres/ceres.h>

#include <cmath>
#include <memory>
#include <vector>

namespace embedded_calibration_stereo::core {

namespace {

// Parameters: cx, cy (offset from the window centre), theta1, theta2 (edge normals' angles), a,
// gx, gy, b, log(s). (A gradient of the contrast b, for vignetting, was tried: on the simulated
// head it cost more in noise than it removed in bias.)
constexpr int kParams = 9;

// The model's residuals and, when asked, their derivatives. With u_k = n_k . d / (sqrt(2) s) and
// d = offset - c: dm/du_k = b e_j 2/sqrt(pi) exp(-u_k^2); du_k/dc = -n_k / (sqrt(2) s),
// du_k/dtheta_k = n_k' . d / (sqrt(2) s) (n_k' = (-sin, cos)), du_k/dlog(s) = -u_k.
class SaddleCost : public ceres::CostFunction {
 public:
  SaddleCost(const std::vector<float>* values, const std::vector<cv::Point2f>* offsets)
      : values_(values), offsets_(offsets) {
    set_num_residuals(static_cast<int>(values->size()));
    mutable_parameter_block_sizes()->push_back(kParams);
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const double* p = parameters[0];
    const double n1x = std::cos(p[2]), n1y = std::sin(p[2]);
    const double n2x = std::cos(p[3]), n2y = std::sin(p[3]);
    const double scale = 1.0 / (M_SQRT2 * std::exp(p[8]));
    double* J = jacobians ? jacobians[0] : nullptr;
    constexpr double kErfSlope = 1.1283791670955126;  // 2 / sqrt(pi)
    for (size_t i = 0; i < values_->size(); ++i) {
      const double dx = (*offsets_)[i].x - p[0], dy = (*offsets_)[i].y - p[1];
      const double u1 = (n1x * dx + n1y * dy) * scale, u2 = (n2x * dx + n2y * dy) * scale;
      const double e1 = std::erf(u1), e2 = std::erf(u2);
      residuals[i] = p[4] + p[5] * dx + p[6] * dy + p[7] * e1 * e2 - (*values_)[i];
      if (!J) continue;
      const double d1 = p[7] * e2 * kErfSlope * std::exp(-u1 * u1);  // dm/du1
      const double d2 = p[7] * e1 * kErfSlope * std::exp(-u2 * u2);  // dm/du2
      double* row = J + i * kParams;
      row[0] = -p[5] - (d1 * n1x + d2 * n2x) * scale;
      row[1] = -p[6] - (d1 * n1y + d2 * n2y) * scale;
      row[2] = d1 * (n1x * dy - n1y * dx) * scale;
      row[3] = d2 * (n2x * dy - n2y * dx) * scale;
      row[4] = 1.0;
      row[5] = dx;
      row[6] = dy;
      row[7] = e1 * e2;
      row[8] = -(d1 * u1 + d2 * u2);
    }
    return true;
  }

 private:
  const std::vector<float>* values_;
  const std::vector<cv::Point2f>* offsets_;
};

}  // namespace

bool fitSaddle(const cv::Mat& gray, cv::Point2f start, cv::Point2f along_col, cv::Point2f along_row,
               const SaddleFitOptions& options, SaddleFit* fit) {
  CV_Assert(gray.type() == CV_8UC1 || gray.type() == CV_32FC1);
  const int r = std::max(2, options.radius_px);
  const int cx = static_cast<int>(std::lround(start.x)), cy = static_cast<int>(std::lround(start.y));
  if (cx - r < 0 || cy - r < 0 || cx + r >= gray.cols || cy + r >= gray.rows) return false;
  if (cv::norm(along_col) < 1e-6 || cv::norm(along_row) < 1e-6) return false;
  std::vector<float> values;
  std::vector<cv::Point2f> offsets;
  values.reserve((2 * r + 1) * (2 * r + 1));
  offsets.reserve(values.capacity());
  for (int y = cy - r; y <= cy + r; ++y)
    for (int x = cx - r; x <= cx + r; ++x) {
      values.push_back(gray.type() == CV_8UC1 ? gray.at<uchar>(y, x) : gray.at<float>(y, x));
      offsets.emplace_back(static_cast<float>(x - cx), static_cast<float>(y - cy));
    }
  double p[kParams];
  p[0] = start.x - cx;
  p[1] = start.y - cy;
  // An edge along along_col has its normal perpendicular to it.
  p[2] = std::atan2(along_col.x, -along_col.y);
  p[3] = std::atan2(along_row.x, -along_row.y);
  p[8] = std::log(std::max(0.3, options.initial_blur_px));
  // a and b by linear least squares at the starting geometry (gradient 0).
  {
    double s1 = 0, s2 = 0, s11 = 0, sv = 0, s2v = 0;
    const double n1x = std::cos(p[2]), n1y = std::sin(p[2]), n2x = std::cos(p[3]), n2y = std::sin(p[3]);
    const double scale = 1.0 / (M_SQRT2 * std::exp(p[8]));
    for (size_t i = 0; i < values.size(); ++i) {
      const double dx = offsets[i].x - p[0], dy = offsets[i].y - p[1];
      const double e = std::erf((n1x * dx + n1y * dy) * scale) * std::erf((n2x * dx + n2y * dy) * scale);
      s1 += 1;
      s2 += e;
      s11 += e * e;
      sv += values[i];
      s2v += e * values[i];
    }
    const double det = s1 * s11 - s2 * s2;
    if (!(std::abs(det) > 1e-9)) return false;
    p[4] = (s11 * sv - s2 * s2v) / det;
    p[7] = (s1 * s2v - s2 * sv) / det;
  }
  p[5] = p[6] = 0.0;
  ceres::Problem problem;
  problem.AddResidualBlock(makeSaddleCost(&values, &offsets).release(), nullptr, p);
  problem.SetParameterLowerBound(p, 8, std::log(0.2));
  problem.SetParameterUpperBound(p, 8, std::log(4.0));
  ceres::Solver::Options solver;
  solver.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
  solver.max_num_iterations = options.max_iterations;
  solver.num_threads = 1;
  solver.logging_type = ceres::SILENT;
  solver.function_tolerance = 1e-10;
  solver.parameter_tolerance = 1e-10;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);
  if (!summary.IsSolutionUsable()) return false;
  const cv::Point2d corner(cx + p[0], cy + p[1]);
  if (cv::norm(corner - cv::Point2d(start)) > options.max_shift_px) return false;
  if (!(std::abs(p[7]) >= options.min_contrast)) return false;
  fit->corner = corner;
  fit->contrast = p[7];
  fit->blur_px = std::exp(p[8]);
  fit->rms_residual = std::sqrt(2.0 * summary.final_cost / values.size());
  return true;
}

std::unique_ptr<ceres::CostFunction> makeSaddleCost(const std::vector<float>* values,
                                                    const std::vector<cv::Point2f>* offsets) {
  return std::make_unique<SaddleCost>(values, offsets);
}

}  // namespace embedded_calibration_stereo::core
