// Photometric alignment of one whole board (see board_alignment.h).
#include "board_alignment.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "board_geometry.h"

namespace embedded_calibration_stereo::core {
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
// Gauss-Newton stops after a step that moved the board's corners by less than this (px): the
// next step (re-weighting, the last of the non-linearity within the edge blur) would be a
// fraction of it, below the frame-to-frame noise of the fit. In steady state one step from last
// frame's alignment then usually suffices.
constexpr double kConvergedPx = 0.05;

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

namespace {

// The taught board the template is built from: its offsets smoothed, the homography of its mean
// outer corners (grid -> taught pixel) and its inverse.
struct TaughtBoard {
  BoardPrior board;
  cv::Matx33d h0, h0_inv;
};

TaughtBoard taughtBoard(const BoardPrior& taught_board) {
  TaughtBoard b;
  b.board = taught_board;
  b.board.offsets = smoothOffsets(taught_board);
  b.h0 = homographyFromOuter(b.board, b.board.meanOuterCorners());
  b.h0_inv = b.h0.inv();
  return b;
}

// The normalisation of taught coordinates (the taught corners' mean and RMS spread) and the
// corners in it.
void normaliseCorners(const TaughtBoard& tb, AlignmentTemplate* t) {
  const BoardPrior& board = tb.board;
  std::vector<cv::Point2f> taught(board.cornerCount());
  cv::Point2d mean(0, 0);
  for (int id = 0; id < board.cornerCount(); ++id) {
    const cv::Point2f g = gridPoint(id, board.cols);
    taught[id] = applyHomography(tb.h0, g.x, g.y) + board.offsets[id];
    mean += cv::Point2d(taught[id]);
  }
  mean *= 1.0 / board.cornerCount();
  double spread = 0;
  for (const cv::Point2f& p : taught) spread += std::pow(cv::norm(cv::Point2d(p) - mean), 2);
  t->centre = mean;
  t->scale = std::sqrt(spread / board.cornerCount());
  for (const cv::Point2f& p : taught)
    t->corners.emplace_back(static_cast<float>((p.x - mean.x) / t->scale), static_cast<float>((p.y - mean.y) / t->scale));
}

// The blurred pattern T in the taught image, its region and its brightness cells.
struct PatternModel {
  const TaughtBoard* tb = nullptr;
  double blur_px = 0.0;
  bool margin = false;  // the device's white margin is part of the pattern
  double g_lo = 0.0, gx_hi = 0.0, gy_hi = 0.0;  // the pattern region, grid coordinates
  float umin = 1e9f, vmin = 1e9f, umax = -1e9f, vmax = -1e9f;  // its bounds, taught pixels
  double reach = 0.0;  // px from an edge a sample may lie
  int split = 1, ncx = 0, ncy = 0;  // cells per square side; cells along each grid axis

  // Grid coordinates of taught pixel (u, v) (the offsets removed by fixed-point iteration).
  cv::Point2f gridOf(double u, double v) const {
    const BoardPrior& board = tb->board;
    cv::Point2f g = applyHomography(tb->h0_inv, u, v);
    for (int k = 0; k < 3; ++k) {
      const cv::Point2f o = offsetAt(board, g.x, g.y);
      g = applyHomography(tb->h0_inv, u - o.x, v - o.y);
    }
    return g;
  }
  int cellOf(double u, double v) const {
    const cv::Point2f g = gridOf(u, v);
    const int cx = std::min(std::max(static_cast<int>(std::floor((g.x + 2) * split)), 0), ncx - 1);
    const int cy = std::min(std::max(static_cast<int>(std::floor((g.y + 2) * split)), 0), ncy - 1);
    return cy * ncx + cx;
  }
  // T at taught pixel (u, v); false outside the pattern region or (near_edge) too far from an edge.
  // nearest_corner (when given): the corner id nearest to (u, v).
  bool valueAt(double u, double v, bool near_edge, double* value, int* nearest_corner = nullptr) const {
    const BoardPrior& board = tb->board;
    const cv::Matx33d& h0 = tb->h0;
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
    if (nearest_corner) *nearest_corner = ky * board.cols + kx;
    const double cx = ((kx & 1) ? -1.0 : 1.0) * (2.0 * phi(dx, blur_px) - 1.0);
    const double cy = ((ky & 1) ? -1.0 : 1.0) * (2.0 * phi(dy, blur_px) - 1.0);
    const double inside = margin ? phi(bx, blur_px) * phi(by, blur_px) : 1.0;
    *value = inside * board.sign * cx * cy + (1.0 - inside);
    return true;
  }
};

PatternModel patternModel(const TaughtBoard& tb, double blur_px) {
  const BoardPrior& board = tb.board;
  PatternModel m;
  m.tb = &tb;
  m.blur_px = blur_px;
  // The pattern region used: for the device's boards the squares and the inner half of the white
  // margin (its outer edge against the housing depends on the device); for a printed board the
  // inner corners' lattice and half a square beyond it (printed boards often have cut outer
  // squares and a thin margin).
  m.margin = board.device_pattern;
  const double beyond = m.margin ? 1.5 : 0.5;
  m.g_lo = -beyond, m.gx_hi = board.cols - 1 + beyond, m.gy_hi = board.rows - 1 + beyond;
  for (double gx : {m.g_lo, m.gx_hi})
    for (double gy : {m.g_lo, m.gy_hi}) {
      const cv::Point2f p = applyHomography(tb.h0, gx, gy) + offsetAt(board, gx, gy);
      m.umin = std::min(m.umin, p.x), m.vmin = std::min(m.vmin, p.y);
      m.umax = std::max(m.umax, p.x), m.vmax = std::max(m.vmax, p.y);
    }
  // Samples within 2.5 blur widths of an edge, on a sparse lattice (every other pixel: a
  // quincunx): the scene's pull is spatially correlated over a few pixels, so the skipped pixels
  // would add little but time.
  m.reach = 2.5 * blur_px;
  // Cells: squares of about kCellPx on a side, inside one square each (their borders lie on the
  // squares' edges). One level per square leaves the scene's variation inside a square to pull
  // the edges; a cell's level takes out the scene's mean there, so small cells leave less of the
  // scene's texture to correlate with the edges. Much smaller, a cell would hold only the samples
  // of one edge's profile, and its level would take that profile (and the position) out.
  m.split = std::min(8, std::max(1, static_cast<int>(std::lround(board.square_px / kCellPx))));
  m.ncx = (board.cols + 3) * m.split, m.ncy = (board.rows + 3) * m.split;
  return m;
}

// The samples: the taught pixels of the pattern region near an edge, on the lattice `stride`
// asks for, each with T, its gradient (central differences, half a pixel), cell and nearest corner.
void sampleTemplate(const PatternModel& m, int stride, AlignmentTemplate* t) {
  const cv::Point2d mean = t->centre;
  for (int v = static_cast<int>(std::floor(m.vmin)) - 2; v <= static_cast<int>(std::ceil(m.vmax)) + 2; ++v) {
    for (int u = static_cast<int>(std::floor(m.umin)) - 2; u <= static_cast<int>(std::ceil(m.umax)) + 2; ++u) {
      if (stride > 1 && (stride == 2 ? ((u + v) & 1) != 0 : (u % stride != 0 || v % stride != 0))) continue;
      double value = 0.0;
      int nearest_corner = 0;
      if (!m.valueAt(u, v, true, &value, &nearest_corner)) continue;
      t->corner.push_back(nearest_corner);
      double vx0, vx1, vy0, vy1;  // template gradient by central differences (half a pixel)
      m.valueAt(u - 0.5, v, false, &vx0), m.valueAt(u + 0.5, v, false, &vx1);
      m.valueAt(u, v - 0.5, false, &vy0), m.valueAt(u, v + 0.5, false, &vy1);
      t->grad.emplace_back(static_cast<float>((vx1 - vx0) * t->scale), static_cast<float>((vy1 - vy0) * t->scale));
      t->ref.emplace_back(static_cast<float>((u - mean.x) / t->scale), static_cast<float>((v - mean.y) / t->scale));
      t->value.push_back(static_cast<float>(value));
      t->cell.push_back(m.cellOf(u, v));
    }
  }
}

// Numbers the cells that hold samples 0..cells-1 (the solver's work and memory follow them).
void numberUsedCells(AlignmentTemplate* t) {
  std::vector<int> used = t->cell;
  std::sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  for (int& c : t->cell) c = static_cast<int>(std::lower_bound(used.begin(), used.end(), c) - used.begin());
  t->cells = static_cast<int>(used.size());
}

// Samples in cell order: the solver takes each cell's samples as one range (the cells
// are small and numbered along the grid, so the image is still read locally).
void sortSamplesByCell(AlignmentTemplate* t) {
  std::vector<size_t> order(t->ref.size());
  for (size_t k = 0; k < order.size(); ++k) order[k] = k;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return t->cell[a] < t->cell[b]; });
  AlignmentTemplate sorted = *t;
  for (size_t k = 0; k < order.size(); ++k) {
    sorted.ref[k] = t->ref[order[k]];
    sorted.value[k] = t->value[order[k]];
    sorted.grad[k] = t->grad[order[k]];
    sorted.cell[k] = t->cell[order[k]];
    sorted.corner[k] = t->corner[order[k]];
  }
  *t = std::move(sorted);
  t->cell_start.assign(t->cells + 1, 0);
  for (int c : t->cell) ++t->cell_start[c + 1];
  for (int c = 0; c < t->cells; ++c) t->cell_start[c + 1] += t->cell_start[c];
}

}  // namespace

AlignmentTemplate buildAlignmentTemplate(const BoardPrior& taught_board, double blur_px, int stride) {
  AlignmentTemplate t;
  const TaughtBoard tb = taughtBoard(taught_board);
  normaliseCorners(tb, &t);
  sampleTemplate(patternModel(tb, blur_px), stride, &t);
  numberUsedCells(&t);
  sortSamplesByCell(&t);
  return t;
}

bool fitAlignmentStart(const AlignmentTemplate& t, const std::vector<int>& ids,
                       const std::vector<cv::Point2f>& pixels, cv::Matx33d* a) {
  std::vector<cv::Point2f> from;
  for (int id : ids) from.push_back(t.corners.at(id));
  return fitHomographyLeastSquares(from, pixels, a);
}

namespace {

// Working memory of alignBoard, kept per thread between calls (each tracker thread aligns one
// board after another), so that a pass allocates nothing.
struct AlignScratch {
  std::vector<double> level;  // a_c
  // Per sample: where it lands (px, py, and 1 / the homography's w), the Jacobian (one column per
  // parameter), the Huber weight, the residual, its absolute value, and the image value of the
  // last pass and whether it was inside the image (1 or 0).
  std::vector<float> px, py, iw;
  Eigen::Matrix<float, Eigen::Dynamic, 9> jac;
  Eigen::VectorXf weight, res, weighted_res;
  Eigen::MatrixXf rows;  // sqrt(w) times the centred Jacobian
  std::vector<float> absres, vals, inside;
  // Per cell: the weighted means of the Jacobian and of the residual (for the back-substitution).
  Eigen::Matrix<double, Eigen::Dynamic, 9> cell_j;
  std::vector<double> cell_r;
  std::vector<char> cell_used;
  std::vector<int> histogram;
  std::vector<float> in_bin;
};

// The element a full std::nth_element would put at index used / 2, of the `used` values >= 0
// among n (the others are negative). A histogram finds the bin that holds it, a selection among
// that bin's values the value itself: a selection over every sample used to be the solver's
// largest single cost.
float upperMedian(const float* values, int n, int used, AlignScratch* s) {
  constexpr int kBins = 1024;
  constexpr float kPerUnit = 16.0f;  // bins per grey level: the last one holds all from 63.9375 up
  s->histogram.assign(kBins, 0);
  // NaN (from a diverged fit) counts, in the last bin.
  const auto counted = [](float v) { return !(v < 0.0f); };
  const auto binOf = [](float v) {
    return v < (kBins - 1) / kPerUnit ? static_cast<int>(v * kPerUnit) : kBins - 1;
  };
  for (int k = 0; k < n; ++k)
    if (counted(values[k])) ++s->histogram[binOf(values[k])];
  int rank = used / 2, bin = 0;
  while (rank >= s->histogram[bin]) rank -= s->histogram[bin++];
  s->in_bin.clear();
  for (int k = 0; k < n; ++k)
    if (counted(values[k]) && binOf(values[k]) == bin) s->in_bin.push_back(values[k]);
  std::nth_element(s->in_bin.begin(), s->in_bin.begin() + rank, s->in_bin.end());
  return s->in_bin[rank];
}

}  // namespace

namespace {

// Parameters: the 8 of the homography and the contrast b; each cell's own brightness a_c is
// eliminated (Schur complement), which is cheap since a sample belongs to one cell.
constexpr int kP = 9;
using Vec = Eigen::Matrix<double, kP, 1>;
using Mat = Eigen::Matrix<double, kP, kP>;

// The fitted parameters between Gauss-Newton steps: the homography (h33 = 1), the contrast b and
// the Huber threshold of the robust weights.
struct AlignParams {
  double h[8];
  double b;
  double huber;
};

AlignParams startParams(const AlignmentResult& start, bool warm) {
  const cv::Matx33d a_norm = start.a * (1.0 / start.a(2, 2));
  return {{a_norm(0, 0), a_norm(0, 1), a_norm(0, 2), a_norm(1, 0), a_norm(1, 1), a_norm(1, 2), a_norm(2, 0),
           a_norm(2, 1)},
          warm ? start.contrast : 0.0,
          warm ? start.huber : 1e30};
}

// Sizes the working memory for t and sets the cell levels to start from.
void prepareScratch(const AlignmentTemplate& t, const AlignmentResult& start, bool warm, AlignScratch* s) {
  const int n = static_cast<int>(t.ref.size());
  // a_c: last frame's when warm, so that the first pass's residuals (and with them its Huber
  // weights and robust scale) are the fitted ones, not the image's grey levels; the step re-solves
  // them in any case.
  if (warm && static_cast<int>(start.levels.size()) == t.cells)
    s->level = start.levels;
  else
    s->level.assign(t.cells, 0.0);
  s->jac.resize(n, kP);
  s->weight.resize(n);
  s->res.resize(n);
  s->px.resize(n);
  s->py.resize(n);
  s->iw.resize(n);
  s->vals.resize(n);
  s->inside.resize(n);
  s->absres.resize(n);
  s->cell_j.resize(t.cells, kP);
  s->cell_r.resize(t.cells);
  s->cell_used.resize(t.cells);
}

// The homography in single precision, for the per-sample loops.
struct FloatHomography {
  float h0, h1, h2, h3, h4, h5, h6, h7;
  explicit FloatHomography(const double h[8])
      : h0(static_cast<float>(h[0])), h1(static_cast<float>(h[1])), h2(static_cast<float>(h[2])),
        h3(static_cast<float>(h[3])), h4(static_cast<float>(h[4])), h5(static_cast<float>(h[5])),
        h6(static_cast<float>(h[6])), h7(static_cast<float>(h[7])) {}
};

// Where each sample lands in the image.
void projectSamples(const AlignmentTemplate& t, const FloatHomography& f, AlignScratch* s) {
  const int n = static_cast<int>(t.ref.size());
  const float h0 = f.h0, h1 = f.h1, h2 = f.h2, h3 = f.h3, h4 = f.h4, h5 = f.h5, h6 = f.h6, h7 = f.h7;
  // (The arrays are distinct, which GCC cannot prove for this many: ivdep lets it vectorise.)
  const cv::Point2f* ref = t.ref.data();
  float *px = s->px.data(), *py = s->py.data(), *iw = s->iw.data();
#pragma GCC ivdep
  for (int k = 0; k < n; ++k) {
    const float u = ref[k].x, v = ref[k].y;
    iw[k] = 1.0f / (h6 * u + h7 * v + 1.0f);
    px[k] = (h0 * u + h1 * v + h2) * iw[k];
    py[k] = (h3 * u + h4 * v + h5) * iw[k];
  }
}

// The image there (bilinear) and the sample's residual from its cell's level; returns how many
// samples lie inside the image. Outside the image: no weight, so the sample adds nothing to any sum.
int readImage(const AlignmentTemplate& t, const cv::Mat& gray, AlignScratch* s) {
  const int n = static_cast<int>(t.ref.size());
  const float max_x = static_cast<float>(gray.cols - 1), max_y = static_cast<float>(gray.rows - 1);
  const size_t stride = gray.step[0];
  const uchar* image = gray.data;
  const int* cell = t.cell.data();
  const float *px = s->px.data(), *py = s->py.data();
  float *vals = s->vals.data(), *inside = s->inside.data(), *res = s->res.data();
  int used = 0;
  for (int k = 0; k < n; ++k) {
    float val = 0.0f;
    inside[k] = 0.0f;
    if (px[k] >= 0.0f && py[k] >= 0.0f && px[k] < max_x && py[k] < max_y) {
      const int x0 = static_cast<int>(px[k]), y0 = static_cast<int>(py[k]);
      const float fx = px[k] - x0, fy = py[k] - y0;
      const uchar* r0 = image + y0 * stride + x0;
      const uchar* r1 = r0 + stride;
      val = (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
      inside[k] = 1.0f;
      ++used;
    }
    vals[k] = val;
    res[k] = val - static_cast<float>(s->level[cell[k]]);
  }
  return used;
}

// The contrast's term of the residual, the Huber weights and the contrast's Jacobian column.
void photometricTerms(const AlignmentTemplate& t, const AlignParams& p, AlignScratch* s) {
  const int n = static_cast<int>(t.ref.size());
  const float bf = static_cast<float>(p.b), huber_f = static_cast<float>(p.huber);
  const float* value = t.value.data();
  float *inside = s->inside.data(), *res = s->res.data(), *absres = s->absres.data(), *weight = s->weight.data();
  float* jac = s->jac.data();  // column p (parameter p) at jac + p * n
#pragma GCC ivdep
  for (int k = 0; k < n; ++k) {
    const float r = res[k] - bf * value[k];
    const float ar = std::abs(r);
    res[k] = r;
    absres[k] = inside[k] > 0.0f ? ar : -1.0f;  // -1: left out of the robust scale
    weight[k] = inside[k] * huber_f / std::max(ar, huber_f);
    jac[8 * n + k] = -value[k];
  }
}

// The homography's Jacobian columns.
void geometricJacobian(const AlignmentTemplate& t, const FloatHomography& f, double b, AlignScratch* s) {
  const int n = static_cast<int>(t.ref.size());
  const float h0 = f.h0, h1 = f.h1, h3 = f.h3, h4 = f.h4, h6 = f.h6, h7 = f.h7;
  const float bf = static_cast<float>(b);
  const cv::Point2f *ref = t.ref.data(), *grad = t.grad.data();
  const float *px = s->px.data(), *py = s->py.data(), *iw = s->iw.data();
  float* jac = s->jac.data();  // column p (parameter p) at jac + p * n
#pragma GCC ivdep
  for (int k = 0; k < n; ++k) {
    // The gradient of the fitted pattern, not of the image: the scene's own texture then
    // enters only through the residual, weighted by the pattern's edges (a matched filter).
    const float u = ref[k].x, v = ref[k].y, w = iw[k], x = px[k], y = py[k];
    const float j00 = (h0 - x * h6) * w, j01 = (h1 - x * h7) * w;
    const float j10 = (h3 - y * h6) * w, j11 = (h4 - y * h7) * w;
    const float bdet = bf / (j00 * j11 - j01 * j10);
    const float tu = grad[k].x, tw = grad[k].y;
    const float gx = bdet * (j11 * tu - j10 * tw), gy = bdet * (-j01 * tu + j00 * tw);
    const float gp = -(gx * x + gy * y) * w;
    jac[k] = gx * u * w, jac[n + k] = gx * v * w, jac[2 * n + k] = gx * w;
    jac[3 * n + k] = gy * u * w, jac[4 * n + k] = gy * v * w, jac[5 * n + k] = gy * w;
    jac[6 * n + k] = gp * u, jac[7 * n + k] = gp * v;
  }
}

// 1. Residual, weight and Jacobian of every sample, in single precision (the solve below is
// in double; float is far below the image noise here), in loops that vectorise apart from the
// one that reads the image. Returns the samples inside the image.
int evaluateSamples(const AlignmentTemplate& t, const cv::Mat& gray, const AlignParams& p, bool geometric,
                    AlignScratch* s) {
  const FloatHomography f(p.h);
  projectSamples(t, f, s);
  const int used = readImage(t, gray, s);
  photometricTerms(t, p, s);
  if (geometric) geometricJacobian(t, f, p.b, s);
  return used;
}

// 2. Eliminate the cell levels (their Jacobian is -1). The Schur complement of a cell's level
// is the weighted covariance of its samples: subtract each cell's weighted mean Jacobian
// from its samples, then H = sum w j j^T and g = sum w j r over the centred rows (which also
// keeps the single-precision sums free of cancellation). Parameters first..8 take part.
void eliminateCellLevels(const AlignmentTemplate& t, int first, AlignScratch* s) {
  for (int c = 0; c < t.cells; ++c) {
    const int k0 = t.cell_start[c], k1 = t.cell_start[c + 1];
    double sw = 0, swr = 0, swj[kP] = {};
    for (int k = k0; k < k1; ++k) {
      const double w = s->weight[k];
      sw += w;
      swr += w * s->res[k];
      for (int p = first; p < kP; ++p) swj[p] += w * s->jac(k, p);
    }
    s->cell_used[c] = sw > 0;
    if (sw <= 0) continue;
    s->cell_r[c] = swr / sw;
    for (int p = first; p < kP; ++p) {
      const double mean = swj[p] / sw;
      s->cell_j(c, p) = mean;
      const float mean_f = static_cast<float>(mean);
      for (int k = k0; k < k1; ++k) s->jac(k, p) -= mean_f;
    }
  }
}

// 3. Normal equations of the centred rows, scaled by sqrt(w) (one symmetric product), solved
// for the step of parameters first..8 (the others' entries 0).
Vec solveStep(int first, AlignScratch* s) {
  s->weight = s->weight.cwiseSqrt();
  const Eigen::Index cols = kP - first;
  s->rows = s->jac.rightCols(cols).array().colwise() * s->weight.array();
  s->weighted_res = s->weight.cwiseProduct(s->res);
  Eigen::Matrix<float, kP, kP> hf = Eigen::Matrix<float, kP, kP>::Zero();
  hf.topLeftCorner(cols, cols).selfadjointView<Eigen::Lower>().rankUpdate(s->rows.transpose());
  Eigen::Matrix<float, kP, 1> gf = Eigen::Matrix<float, kP, 1>::Zero();
  gf.head(cols).noalias() = s->rows.transpose() * s->weighted_res;
  Mat full = Mat::Identity();
  Vec g = Vec::Zero();
  for (int p = first; p < kP; ++p) {
    g[p] = gf[p - first];
    for (int q = first; q <= p; ++q) full(p, q) = full(q, p) = hf(p - first, q - first);
  }
  return full.ldlt().solve(-g);
}

// Back-substitute each level (its Jacobian is -1): da = mean r + mean j . delta over the cell.
void backSubstituteLevels(const AlignmentTemplate& t, int first, const Vec& delta, AlignScratch* s) {
  for (int c = 0; c < t.cells; ++c) {
    if (!s->cell_used[c]) continue;
    double dot = 0;
    for (int p = first; p < kP; ++p) dot += s->cell_j(c, p) * delta[p];
    s->level[c] += s->cell_r[c] + dot;
  }
}

// Corner motion of the step delta that led to h (at the outer corners; the map is projective).
double cornerShift(const AlignmentTemplate& t, const double h[8], const Vec& delta) {
  const cv::Matx33d moved(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
  const cv::Matx33d before = moved - cv::Matx33d(delta[0], delta[1], delta[2], delta[3], delta[4], delta[5],
                                                 delta[6], delta[7], 0.0);
  double shift = 0;
  for (size_t id : {size_t(0), t.corners.size() - 1}) {
    const cv::Point2f c = t.corners[id];
    shift = std::max(shift, cv::norm(applyHomography(moved, c.x, c.y) - applyHomography(before, c.x, c.y)));
  }
  return shift;
}

// Each corner's own contrast: sum T r / sum T^2 over its samples, r the image minus its cell's
// level (the image as the last pass sampled it: one step from the result, too small to matter).
std::vector<float> cornerContrasts(const AlignmentTemplate& t, const AlignScratch& s, double b) {
  const int n = static_cast<int>(t.ref.size());
  std::vector<double> tr(t.corners.size(), 0.0), tt(t.corners.size(), 0.0);
  for (int k = 0; k < n; ++k) {
    if (s.inside[k] == 0.0f) continue;
    const double tv = t.value[k];
    tr[t.corner[k]] += tv * (s.vals[k] - s.level[t.cell[k]]);
    tt[t.corner[k]] += tv * tv;
  }
  std::vector<float> contrast(t.corners.size(), std::numeric_limits<float>::quiet_NaN());
  for (size_t id = 0; id < t.corners.size(); ++id)
    if (tt[id] > 0 && b > 0) contrast[id] = static_cast<float>(tr[id] / tt[id] / b);
  return contrast;
}

}  // namespace

AlignmentResult alignBoard(const AlignmentTemplate& t, const cv::Mat& gray, const AlignmentResult& start,
                           bool warm, int max_steps) {
  CV_Assert(gray.type() == CV_8UC1);
  AlignmentResult result;
  AlignParams p = startParams(start, warm);
  const int n = static_cast<int>(t.ref.size());
  static thread_local AlignScratch scratch;
  AlignScratch& s = scratch;
  prepareScratch(t, start, warm, &s);
  for (int it = warm ? 1 : 0; it <= max_steps; ++it) {
    // Pass 0 fits only the photometric terms (the start map is close): parameters first..8.
    const bool geometric = it > 0;
    const int first = geometric ? 0 : kP - 1;
    const int used = evaluateSamples(t, gray, p, geometric, &s);
    if (used < 50) return result;
    // Robust scale from this pass's residuals (normal: MAD * 1.4826), Huber at 1.345 sigma.
    p.huber = std::max(1.0, 1.345 * 1.4826 * upperMedian(s.absres.data(), n, used, &s));
    eliminateCellLevels(t, first, &s);
    const Vec delta = solveStep(first, &s);
    if (!delta.allFinite()) return result;
    for (int q = first; q < 8; ++q) p.h[q] += delta[q];
    p.b += delta[8];
    ++result.passes;
    backSubstituteLevels(t, first, delta, &s);
    result.samples = used;
    if (geometric && cornerShift(t, p.h, delta) < kConvergedPx) {
      result.converged = true;
      break;
    }
  }
  result.huber = p.huber;
  result.levels = s.level;
  result.a = cv::Matx33d(p.h[0], p.h[1], p.h[2], p.h[3], p.h[4], p.h[5], p.h[6], p.h[7], 1.0);
  result.contrast = p.b;
  result.corner_contrast = cornerContrasts(t, s, p.b);
  result.ok = std::isfinite(p.b) && p.b > 0;
  return result;
}

}  // namespace tracker
}  // namespace embedded_calibration_stereo::core
