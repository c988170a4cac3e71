// Photometric alignment of one whole board (see board_alignment.h).
#include "board_alignment.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "board_geometry.h"

namespace ecs {
namespace tracker {

namespace {

// Offsets (lens distortion) between corners: bilinear over the grid, extrapolated linearly
// beyond it (the distortion keeps changing across the margin).
cv::Point2f offsetAt(const BoardPrior& board, double gx, double gy) {
  const int c0 = std::min(std::max(static_cast<int>(std::floor(gx)), 0), board.cols - 2);
  const int r0 = std::min(std::max(static_cast<int>(std::floor(gy)), 0), board.rows - 2);
  const float fx = static_cast<float>(gx - c0), fy = static_cast<float>(gy - r0);
  const auto o = [&](int c, int r) { return board.offsets[r * board.cols + c]; };
  return (1 - fy) * ((1 - fx) * o(c0, r0) + fx * o(c0 + 1, r0)) + fy * ((1 - fx) * o(c0, r0 + 1) + fx * o(c0 + 1, r0 + 1));
}

inline double phi(double d, double blur) { return 0.5 * (1.0 + std::erf(d / (blur * M_SQRT2))); }

inline bool bilinear(const cv::Mat& img, float x, float y, float* out) {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  if (x0 < 0 || y0 < 0 || x0 + 1 >= img.cols || y0 + 1 >= img.rows) return false;
  const float fx = x - x0, fy = y - y0;
  if (img.type() == CV_8UC1) {
    const uchar* r0 = img.ptr<uchar>(y0) + x0;
    const uchar* r1 = img.ptr<uchar>(y0 + 1) + x0;
    *out = (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
  } else {
    const float* r0 = img.ptr<float>(y0) + x0;
    const float* r1 = img.ptr<float>(y0 + 1) + x0;
    *out = (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
  }
  return true;
}

}  // namespace

namespace {

// The taught offsets smoothed by a cubic polynomial of the grid coordinates: the lens distortion
// left after removing the board's homography is smooth over one board, while each taught corner
// carries its own refinement error, which the fit averages down. A printed board is not always
// smooth (printing, mounting, a lens beyond the cubic over a large board): when the cubic leaves
// more than kSmoothResidualPx RMS there, its taught corners are kept as they are.
constexpr double kSmoothResidualPx = 0.1;
// Side (px) of the alignment's brightness cells.
constexpr double kCellPx = 3.5;

std::vector<cv::Point2f> smoothOffsets(const BoardPrior& board) {
  const int n = board.cornerCount();
  if (n < 20) return board.offsets;
  const double sx = 2.0 / std::max(1, board.cols - 1), sy = 2.0 / std::max(1, board.rows - 1);
  Eigen::MatrixXd a(n, 10);
  Eigen::MatrixXd rhs(n, 2);
  for (int id = 0; id < n; ++id) {
    const double x = (id % board.cols) * sx - 1.0, y = (id / board.cols) * sy - 1.0;
    a.row(id) << 1, x, y, x * x, x * y, y * y, x * x * x, x * x * y, x * y * y, y * y * y;
    rhs(id, 0) = board.offsets[id].x;
    rhs(id, 1) = board.offsets[id].y;
  }
  const Eigen::MatrixXd coef = a.colPivHouseholderQr().solve(rhs);
  const Eigen::MatrixXd fit = a * coef;
  if (!board.device_pattern && std::sqrt((fit - rhs).squaredNorm() / n) > kSmoothResidualPx) return board.offsets;

  std::vector<cv::Point2f> out(n);
  for (int id = 0; id < n; ++id) out[id] = cv::Point2f(static_cast<float>(fit(id, 0)), static_cast<float>(fit(id, 1)));
  return out;
}

}  // namespace

AlignmentTemplate buildAlignmentTemplate(const BoardPrior& taught_board, double blur_px, int stride) {
  AlignmentTemplate t;
  BoardPrior board = taught_board;
  board.offsets = smoothOffsets(taught_board);
  const cv::Matx33d h0 = homographyFromOuter(board, board.meanOuterCorners());
  const cv::Matx33d h0_inv = h0.inv();
  std::vector<cv::Point2f> taught(board.cornerCount());
  cv::Point2d mean(0, 0);
  for (int id = 0; id < board.cornerCount(); ++id) {
    const cv::Point2f g = gridPoint(id, board.cols);
    taught[id] = applyHomography(h0, g.x, g.y) + board.offsets[id];
    mean += cv::Point2d(taught[id]);
  }
  mean *= 1.0 / board.cornerCount();
  double spread = 0;
  for (const cv::Point2f& p : taught) spread += std::pow(cv::norm(cv::Point2d(p) - mean), 2);
  t.centre = mean;
  t.scale = std::sqrt(spread / board.cornerCount());
  for (const cv::Point2f& p : taught)
    t.corners.emplace_back(static_cast<float>((p.x - mean.x) / t.scale), static_cast<float>((p.y - mean.y) / t.scale));

  // The pattern region used: for the device's boards the squares and the inner half of the white
  // margin (its outer edge against the housing depends on the device); for a printed board the
  // inner corners' lattice and half a square beyond it (printed boards often have cut outer
  // squares and a thin margin).
  const bool margin = board.device_pattern;
  const double beyond = margin ? 1.5 : 0.5;
  const double g_lo = -beyond, gx_hi = board.cols - 1 + beyond, gy_hi = board.rows - 1 + beyond;
  float umin = 1e9f, vmin = 1e9f, umax = -1e9f, vmax = -1e9f;
  for (double gx : {g_lo, gx_hi})
    for (double gy : {g_lo, gy_hi}) {
      const cv::Point2f p = applyHomography(h0, gx, gy) + offsetAt(board, gx, gy);
      umin = std::min(umin, p.x), vmin = std::min(vmin, p.y), umax = std::max(umax, p.x), vmax = std::max(vmax, p.y);
    }
  // Samples within 2.5 blur widths of an edge, on a sparse lattice (every other pixel: a
  // quincunx): the scene's pull is spatially correlated over a few pixels, so the skipped pixels
  // would add little but time.
  const double reach = 2.5 * blur_px;
  // Cells: squares of about kCellPx on a side, inside one square each (their borders lie on the
  // squares' edges). One level per square leaves the scene's variation inside a square to pull
  // the edges; a cell's level takes out the scene's mean there, so small cells leave less of the
  // scene's texture to correlate with the edges. Much smaller, a cell would hold only the samples
  // of one edge's profile, and its level would take that profile (and the position) out.
  const int split = std::min(8, std::max(1, static_cast<int>(std::lround(board.square_px / kCellPx))));
  const int ncx = (board.cols + 3) * split, ncy = (board.rows + 3) * split;
  t.cells = ncx * ncy;
  const auto gridOf = [&](double u, double v) {
    cv::Point2f g = applyHomography(h0_inv, u, v);
    for (int k = 0; k < 3; ++k) {
      const cv::Point2f o = offsetAt(board, g.x, g.y);
      g = applyHomography(h0_inv, u - o.x, v - o.y);
    }
    return g;
  };
  const auto cellOf = [&](double u, double v) {
    const cv::Point2f g = gridOf(u, v);
    const int cx = std::min(std::max(static_cast<int>(std::floor((g.x + 2) * split)), 0), ncx - 1);
    const int cy = std::min(std::max(static_cast<int>(std::floor((g.y + 2) * split)), 0), ncy - 1);
    return cy * ncx + cx;
  };
  // T at taught pixel (u, v); false outside the pattern region or (near_edge) too far from an edge.
  int nearest_corner = 0;
  const auto valueAt = [&](double u, double v, bool near_edge, double* value) {
    const cv::Point2f g = gridOf(u, v);
    if (near_edge && (g.x < g_lo || g.y < g_lo || g.x > gx_hi || g.y > gy_hi)) return false;
    // Pixels per square along each grid axis here.
    const double sx = cv::norm(applyHomography(h0, g.x + 0.5, g.y) - applyHomography(h0, g.x - 0.5, g.y));
    const double sy = cv::norm(applyHomography(h0, g.x, g.y + 0.5) - applyHomography(h0, g.x, g.y - 0.5));
    const int kx = std::min(std::max(static_cast<int>(std::lround(g.x)), 0), board.cols - 1);
    const int ky = std::min(std::max(static_cast<int>(std::lround(g.y)), 0), board.rows - 1);
    const double dx = (g.x - kx) * sx, dy = (g.y - ky) * sy;  // to the nearest inner edges
    const double bx = std::min(g.x + 1.0, board.cols - static_cast<double>(g.x)) * sx;  // inside: > 0
    const double by = std::min(g.y + 1.0, board.rows - static_cast<double>(g.y)) * sy;
    const double to_outer = margin ? std::min(std::abs(bx), std::abs(by)) : 1e9;
    if (near_edge && std::min({std::abs(dx), std::abs(dy), to_outer}) > reach) return false;
    nearest_corner = ky * board.cols + kx;
    const double cx = ((kx & 1) ? -1.0 : 1.0) * (2.0 * phi(dx, blur_px) - 1.0);
    const double cy = ((ky & 1) ? -1.0 : 1.0) * (2.0 * phi(dy, blur_px) - 1.0);
    const double inside = margin ? phi(bx, blur_px) * phi(by, blur_px) : 1.0;
    *value = inside * board.sign * cx * cy + (1.0 - inside);
    return true;
  };
  for (int v = static_cast<int>(std::floor(vmin)) - 2; v <= static_cast<int>(std::ceil(vmax)) + 2; ++v) {
    for (int u = static_cast<int>(std::floor(umin)) - 2; u <= static_cast<int>(std::ceil(umax)) + 2; ++u) {
      if (stride > 1 && (stride == 2 ? ((u + v) & 1) != 0 : (u % stride != 0 || v % stride != 0))) continue;
      double value = 0.0;
      if (!valueAt(u, v, true, &value)) continue;
      t.corner.push_back(nearest_corner);
      double vx0, vx1, vy0, vy1;  // template gradient by central differences (half a pixel)
      valueAt(u - 0.5, v, false, &vx0), valueAt(u + 0.5, v, false, &vx1);
      valueAt(u, v - 0.5, false, &vy0), valueAt(u, v + 0.5, false, &vy1);
      t.grad.emplace_back(static_cast<float>((vx1 - vx0) * t.scale), static_cast<float>((vy1 - vy0) * t.scale));
      t.ref.emplace_back(static_cast<float>((u - mean.x) / t.scale), static_cast<float>((v - mean.y) / t.scale));
      t.value.push_back(static_cast<float>(value));
      t.cell.push_back(cellOf(u, v));
    }
  }
  // Number the cells that hold samples 0..cells-1 (the solver's work and memory follow them).
  std::vector<int> used = t.cell;
  std::sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  for (int& c : t.cell) c = static_cast<int>(std::lower_bound(used.begin(), used.end(), c) - used.begin());
  t.cells = static_cast<int>(used.size());
  // Samples in cell order: the solver's per-cell sums are then written in sequence (the cells
  // are small and numbered along the grid, so the image is still read locally).
  std::vector<size_t> order(t.ref.size());
  for (size_t k = 0; k < order.size(); ++k) order[k] = k;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return t.cell[a] < t.cell[b]; });
  AlignmentTemplate sorted = t;
  for (size_t k = 0; k < order.size(); ++k) {
    sorted.ref[k] = t.ref[order[k]];
    sorted.value[k] = t.value[order[k]];
    sorted.grad[k] = t.grad[order[k]];
    sorted.cell[k] = t.cell[order[k]];
    sorted.corner[k] = t.corner[order[k]];
  }
  t = std::move(sorted);
  return t;
}

bool fitAlignmentStart(const AlignmentTemplate& t, const std::vector<int>& ids,
                       const std::vector<cv::Point2f>& pixels, cv::Matx33d* a) {
  std::vector<cv::Point2f> from;
  for (int id : ids) from.push_back(t.corners.at(id));
  return fitHomographyLeastSquares(from, pixels, a);
}

AlignmentResult alignBoard(const AlignmentTemplate& t, const cv::Mat& gray, const AlignmentResult& start,
                           bool warm, int max_steps) {
  // Parameters: the 8 of the homography and the contrast b; each cell's own brightness a_c is
  // eliminated (Schur complement), which is cheap since a sample belongs to one cell.
  constexpr int kP = 9;
  using Vec = Eigen::Matrix<double, kP, 1>;
  using Mat = Eigen::Matrix<double, kP, kP>;
  AlignmentResult result;
  const cv::Matx33d a_norm = start.a * (1.0 / start.a(2, 2));
  double h[8] = {a_norm(0, 0), a_norm(0, 1), a_norm(0, 2), a_norm(1, 0),
                 a_norm(1, 1), a_norm(1, 2), a_norm(2, 0), a_norm(2, 1)};
  double b = warm ? start.contrast : 0.0;
  std::vector<double> level(t.cells, 0.0);  // a_c (solved with the first step whatever they start at)
  struct CellSums {
    double w, wr, wj[kP];
  };
  std::vector<CellSums> sums(t.cells);
  const size_t n = t.ref.size();
  std::vector<float> absres;
  absres.reserve(n);
  Eigen::Matrix<double, Eigen::Dynamic, kP> rows;
  Eigen::VectorXd rhs;
  // The image at each sample in the last pass (NaN outside it).
  std::vector<float> vals(n);
  double huber = warm ? start.huber : 1e30;
  for (int it = warm ? 1 : 0; it <= max_steps; ++it) {
    // Pass 0 fits only the photometric terms (the start map is close): parameters first..8.
    const bool geometric = it > 0;
    const int first = geometric ? 0 : kP - 1;
    // Weighted Jacobian rows (sqrt(w) j) and residuals, multiplied out below in one product.
    rows.resize(static_cast<Eigen::Index>(n), kP);
    rhs.resize(static_cast<Eigen::Index>(n));
    std::memset(sums.data(), 0, sums.size() * sizeof(CellSums));
    absres.clear();
    std::fill(vals.begin(), vals.end(), std::numeric_limits<float>::quiet_NaN());
    int used = 0;
    double j[kP] = {};
    for (size_t k = 0; k < n; ++k) {
      const double u = t.ref[k].x, v = t.ref[k].y;
      const double iw = 1.0 / (h[6] * u + h[7] * v + 1.0);
      const double px = (h[0] * u + h[1] * v + h[2]) * iw, py = (h[3] * u + h[4] * v + h[5]) * iw;
      float val;
      if (!bilinear(gray, static_cast<float>(px), static_cast<float>(py), &val)) continue;
      const double tv = t.value[k];
      const int c = t.cell[k];
      const double r = val - (level[c] + b * tv);
      vals[k] = val;
      const double ar = std::abs(r);
      absres.push_back(static_cast<float>(ar));
      const double wr = ar <= huber ? 1.0 : huber / ar;
      if (geometric) {
        // The gradient of the fitted pattern, not of the image: the scene's own texture then
        // enters only through the residual, weighted by the pattern's edges (a matched filter).
        const double j00 = (h[0] - px * h[6]) * iw, j01 = (h[1] - px * h[7]) * iw;
        const double j10 = (h[3] - py * h[6]) * iw, j11 = (h[4] - py * h[7]) * iw;
        const double bdet = b / (j00 * j11 - j01 * j10);
        const double tu = t.grad[k].x, tw = t.grad[k].y;
        const double gx = bdet * (j11 * tu - j10 * tw), gy = bdet * (-j01 * tu + j00 * tw);
        const double gp = -(gx * px + gy * py) * iw;
        j[0] = gx * u * iw, j[1] = gx * v * iw, j[2] = gx * iw;
        j[3] = gy * u * iw, j[4] = gy * v * iw, j[5] = gy * iw;
        j[6] = gp * u, j[7] = gp * v;
      }
      j[8] = -tv;
      CellSums& cs = sums[c];
      cs.w += wr;
      cs.wr += wr * r;
      const double sw = std::sqrt(wr);
      for (int p = 0; p < kP; ++p) {
        rows(used, p) = sw * j[p];
        cs.wj[p] += wr * j[p];
      }
      rhs(used) = sw * r;
      ++used;
    }
    if (used < 50) return result;
    // Robust scale from this pass's residuals (normal: MAD * 1.4826), Huber at 1.345 sigma.
    std::nth_element(absres.begin(), absres.begin() + absres.size() / 2, absres.end());
    huber = std::max(1.0, 1.345 * 1.4826 * absres[absres.size() / 2]);
    Mat full = Mat::Identity();
    Vec g = Vec::Zero();
    const auto top = rows.topRows(used);
    const Mat hs = top.transpose() * top;
    const Vec gs = top.transpose() * rhs.head(used);
    for (int p = first; p < kP; ++p) {
      g[p] = gs[p];
      for (int q = first; q < kP; ++q) full(p, q) = hs(p, q);
    }
    // Eliminate the cell levels (their Jacobian is -1): H -= wj wj^T / w, g -= wj wr / w.
    for (const CellSums& cs : sums) {
      if (cs.w <= 0) continue;
      for (int p = first; p < kP; ++p) {
        for (int q = first; q < kP; ++q) full(p, q) -= cs.wj[p] * cs.wj[q] / cs.w;
        g[p] -= cs.wj[p] * cs.wr / cs.w;
      }
    }
    const Vec delta = full.ldlt().solve(-g);
    if (!delta.allFinite()) return result;
    for (int p = first; p < 8; ++p) h[p] += delta[p];
    b += delta[8];
    ++result.passes;
    // Back-substitute each level: w da = wr - wj . delta (its Jacobian is -1).
    for (int c = 0; c < t.cells; ++c) {
      const CellSums& cs = sums[c];
      if (cs.w <= 0) continue;
      double dot = 0;
      for (int p = first; p < kP; ++p) dot += cs.wj[p] * delta[p];
      level[c] += (cs.wr + dot) / cs.w;
    }
    result.samples = used;
    if (geometric) {
      // Corner motion of this step (at the outer corners; the map is projective).
      const cv::Matx33d moved(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
      const cv::Matx33d before = moved - cv::Matx33d(delta[0], delta[1], delta[2], delta[3], delta[4], delta[5],
                                                     delta[6], delta[7], 0.0);
      double shift = 0;
      for (size_t id : {size_t(0), t.corners.size() - 1}) {
        const cv::Point2f c = t.corners[id];
        shift = std::max(shift, cv::norm(applyHomography(moved, c.x, c.y) - applyHomography(before, c.x, c.y)));
      }
      // Near-linear within the edge blur: after a step this small the next one would be ~100
      // times smaller.
      if (shift < 0.03) {
        result.converged = true;
        break;
      }
    }
  }
  result.huber = huber;
  result.a = cv::Matx33d(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
  result.contrast = b;
  // Each corner's own contrast: sum T r / sum T^2 over its samples, r the image minus its cell's
  // level (the image as the last pass sampled it: one step from the result, too small to matter).
  std::vector<double> tr(t.corners.size(), 0.0), tt(t.corners.size(), 0.0);
  for (size_t k = 0; k < n; ++k) {
    if (std::isnan(vals[k])) continue;
    const double tv = t.value[k];
    tr[t.corner[k]] += tv * (vals[k] - level[t.cell[k]]);
    tt[t.corner[k]] += tv * tv;
  }
  result.corner_contrast.assign(t.corners.size(), std::numeric_limits<float>::quiet_NaN());
  for (size_t id = 0; id < t.corners.size(); ++id)
    if (tt[id] > 0 && b > 0) result.corner_contrast[id] = static_cast<float>(tr[id] / tt[id] / b);
  result.ok = std::isfinite(b) && b > 0;
  return result;
}

}  // namespace tracker
}  // namespace ecs
