#include "board_geometry.h"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>

namespace embedded_calibration_stereo::core {
namespace tracker {

cv::Matx33d homographyFromOuter(const BoardPrior& board, const std::vector<cv::Point2f>& outer) {
  const cv::Mat h = cv::getPerspectiveTransform(board.outerGridPoints(), outer);
  return cv::Matx33d(h);
}

bool fitHomographyLeastSquares(const std::vector<cv::Point2f>& grid, const std::vector<cv::Point2f>& image,
                               cv::Matx33d* h) {
  const size_t n = grid.size();
  if (n < 4 || image.size() != n) return false;
  double mx = 0, my = 0;
  for (const cv::Point2f& p : image) mx += p.x, my += p.y;
  mx /= n, my /= n;
  double spread = 0;
  for (const cv::Point2f& p : image) spread += std::hypot(p.x - mx, p.y - my);
  const double scale = spread > 0 ? n / spread : 1.0;
  // u = (h0 x + h1 y + h2) / (h6 x + h7 y + 1), v likewise with h3..h5, in normalised u, v.
  Eigen::Matrix<double, 8, 8> ata = Eigen::Matrix<double, 8, 8>::Zero();
  Eigen::Matrix<double, 8, 1> atb = Eigen::Matrix<double, 8, 1>::Zero();
  for (size_t k = 0; k < n; ++k) {
    const double x = grid[k].x, y = grid[k].y;
    const double u = (image[k].x - mx) * scale, v = (image[k].y - my) * scale;
    Eigen::Matrix<double, 8, 1> ru, rv;
    ru << x, y, 1, 0, 0, 0, -u * x, -u * y;
    rv << 0, 0, 0, x, y, 1, -v * x, -v * y;
    ata.noalias() += ru * ru.transpose() + rv * rv.transpose();
    atb += ru * u + rv * v;
  }
  const Eigen::LDLT<Eigen::Matrix<double, 8, 8>> ldlt(ata);
  if (ldlt.info() != Eigen::Success) return false;
  const Eigen::Matrix<double, 8, 1> x = ldlt.solve(atb);
  if (!x.allFinite()) return false;
  // Undo the normalisation: image = T^-1 * Hn, T = [s 0 -s mx; 0 s -s my; 0 0 1].
  const cv::Matx33d hn(x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], 1.0);
  const cv::Matx33d t_inv(1.0 / scale, 0, mx, 0, 1.0 / scale, my, 0, 0, 1);
  *h = t_inv * hn;
  return true;
}

void gridAxes(const cv::Matx33d& h, double col, double row, cv::Point2f* along_col, cv::Point2f* along_row) {
  // Central differences: exact enough for the small perspective of a board.
  *along_col = applyHomography(h, col + 0.5, row) - applyHomography(h, col - 0.5, row);
  *along_row = applyHomography(h, col, row + 0.5) - applyHomography(h, col, row - 0.5);
}

BoxSampler::BoxSampler(const cv::Mat& gray, cv::Rect region, int radius)
    : region_(region & cv::Rect(0, 0, gray.cols, gray.rows)),
      radius_(std::max(radius, 0)),
      inv_area_(1.0f / static_cast<float>((2 * radius_ + 1) * (2 * radius_ + 1))) {
  if (region_.area() > 0) cv::integral(gray(region_), integral_, CV_32S);
}

bool BoxSampler::contains(cv::Point2f p) const {
  if (integral_.empty()) return false;
  const int x = cvRound(p.x) - region_.x, y = cvRound(p.y) - region_.y;
  return x - radius_ >= 0 && y - radius_ >= 0 && x + radius_ < region_.width && y + radius_ < region_.height;
}

bool BoxSampler::mean(cv::Point2f p, float* value) const {
  if (!(std::isfinite(p.x) && std::isfinite(p.y)) || !contains(p)) return false;
  const int x0 = cvRound(p.x) - region_.x - radius_, y0 = cvRound(p.y) - region_.y - radius_;
  const int x1 = x0 + 2 * radius_ + 1, y1 = y0 + 2 * radius_ + 1;
  const int* top = integral_.ptr<int>(y0);
  const int* bottom = integral_.ptr<int>(y1);
  *value = static_cast<float>(bottom[x1] - bottom[x0] - top[x1] + top[x0]) * inv_area_;
  return true;
}

float saddleContrast(const BoxSampler& sampler, cv::Point2f p, cv::Point2f along_col, cv::Point2f along_row,
                     int bright) {
  const float k = 0.3f;
  float pp, mm, pm, mp;  // quadrant (+col,+row), (-,-), (+,-), (-,+)
  if (!sampler.mean(p + k * (along_col + along_row), &pp) ||
      !sampler.mean(p - k * (along_col + along_row), &mm) ||
      !sampler.mean(p + k * (along_col - along_row), &pm) ||
      !sampler.mean(p - k * (along_col - along_row), &mp))
    return -std::numeric_limits<float>::infinity();
  if (bright > 0) return std::min(pp, mm) - std::max(pm, mp);
  return std::min(pm, mp) - std::max(pp, mm);
}

}  // namespace tracker
}  // namespace embedded_calibration_stereo::core
