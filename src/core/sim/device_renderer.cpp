#include "device_renderer.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace embedded_calibration_stereo::core {
namespace sim {

namespace {

// The pattern along one board axis is built from three piecewise-constant functions whose
// discontinuities all sit at integers (grid lines, grid border, margin border):
//   step(x)   = 1 on [lo, hi], 0 elsewhere               (grid / margin indicator)
//   square(x) = +1 on [2k, 2k+1), -1 on [2k+1, 2k+2), restricted to [lo, hi]
// A unit pixel square seen through the local affine map spreads the axis coordinate as the sum
// of two uniform variables of widths a = |dx/du|, b = |dx/dv|, i.e. the pixel-area average is
// a convolution with box(a) * box(b): the exact value is a second difference of the second
// antiderivative G2 divided by a*b.

inline double clampd(double x, double lo, double hi) { return std::min(std::max(x, lo), hi); }

// First antiderivative of the unrestricted square wave: a triangle wave in [0, 1].
inline double triangle(double x) {
  const double m = x - 2.0 * std::floor(0.5 * x);
  return 1.0 - std::abs(m - 1.0);
}
// Antiderivative of triangle(): k per full period plus the partial period.
inline double triangleIntegral(double x) {
  const double k = std::floor(0.5 * x);
  const double m = x - 2.0 * k;
  return k + (m <= 1.0 ? 0.5 * m * m : 0.5 + 2.0 * (m - 1.0) - 0.5 * (m * m - 1.0));
}

struct Step {  // G1 and G2 of the indicator of [lo, hi]
  double lo, hi;
  double g1(double x) const { return clampd(x, lo, hi); }
  double g2(double x) const {
    if (x < lo) return lo * (x - lo);
    if (x > hi) return 0.5 * (hi * hi - lo * lo) + hi * (x - hi);
    return 0.5 * (x * x - lo * lo);
  }
};

struct Square {  // G1 and G2 of the square wave restricted to [lo, hi]
  double lo, hi;
  double g1(double x) const { return triangle(clampd(x, lo, hi)); }
  double g2(double x) const {
    if (x < lo) return triangle(lo) * (x - lo);
    if (x > hi) return triangleIntegral(hi) - triangleIntegral(lo) + triangle(hi) * (x - hi);
    return triangleIntegral(x) - triangleIntegral(lo);
  }
};

// Average of the function over x + U(a) + U(b).
template <typename F>
inline double pixelAverage(const F& f, double x, double a, double b) {
  if (a < b) std::swap(a, b);
  if (b < 1e-5) {  // one box: difference of the first antiderivative
    const double w = std::max(a + b, 1e-9);
    return (f.g1(x + 0.5 * w) - f.g1(x - 0.5 * w)) / w;
  }
  const double s = 0.5 * (a + b), d = 0.5 * (a - b);
  return (f.g2(x + s) - f.g2(x + d) - f.g2(x - d) + f.g2(x - s)) / (a * b);
}

struct AxisFilter {
  double inside_grid;    // indicator of [-1, n]
  double checker;        // square wave restricted to [-1, n]
  double inside_margin;  // indicator of [-2, n + 1]
};

// Pixel-area average of a step function over [x - half, x + half]; filtered only when one of
// its two discontinuities lies under the pixel.
inline double filteredStep(double x, double a, double b, double half, double lo, double hi) {
  if (x - half >= lo && x + half <= hi) return 1.0;
  if (x + half <= lo || x - half >= hi) return 0.0;
  return pixelAverage(Step{lo, hi}, x, a, b);
}

inline AxisFilter filterAxis(double x, double a, double b, int n) {
  AxisFilter f;
  const double half = 0.5 * (a + b);
  f.inside_margin = filteredStep(x, a, b, half, -2.0, n + 1.0);
  f.inside_grid = filteredStep(x, a, b, half, -1.0, n);
  if (f.inside_grid == 0.0) {
    f.checker = 0.0;
  } else if (std::floor(x - half) == std::floor(x + half)) {
    // No grid line under the pixel: the square wave is constant there.
    f.checker = f.inside_grid * ((static_cast<long>(std::floor(x)) & 1) ? -1.0 : 1.0);
  } else {
    f.checker = pixelAverage(Square{-1.0, static_cast<double>(n)}, x, a, b);
  }
  return f;
}

// A board as a homography from the camera ray (x, y, 1) to board coordinates in squares
// (column, row; row grows with the corner id's row for mirrored boards too).
struct BoardInCamera {
  Eigen::Vector3d h_col, h_row, h_w;  // col = h_col.m / h_w.m, row = h_row.m / h_w.m
  double plane_offset;                 // t = plane_offset / h_w.m is the ray parameter (> 0)
  int cols, rows;
  cv::Rect box;                        // pixels that can see the board or its margin
  // Upper bound of the pixel footprint's half-extent (in squares) over the box: pixels
  // farther than this from every grid line are constant and skip the filtering.
  double half_footprint = 0.0;
};

// d(col,row)/d(u,v) at one pixel: the homography's derivative chained with the ray map's.
inline void boardJacobian(const BoardInCamera& b, const double J[4], double col, double row, double w,
                          double* dcol, double* drow) {
  const double dcol_dx = (b.h_col.x() - col * b.h_w.x()) / w;
  const double dcol_dy = (b.h_col.y() - col * b.h_w.y()) / w;
  const double drow_dx = (b.h_row.x() - row * b.h_w.x()) / w;
  const double drow_dy = (b.h_row.y() - row * b.h_w.y()) / w;
  dcol[0] = dcol_dx * J[0] + dcol_dy * J[2];
  dcol[1] = dcol_dx * J[1] + dcol_dy * J[3];
  drow[0] = drow_dx * J[0] + drow_dy * J[2];
  drow[1] = drow_dx * J[1] + drow_dy * J[3];
}

double footprintBound(const BoardInCamera& b, const CameraRays& rays) {
  double bound = 0.0;
  const int kSamples = 6;
  for (int j = 0; j <= kSamples; ++j)
    for (int i = 0; i <= kSamples; ++i) {
      const int u = b.box.x + (b.box.width - 1) * i / kSamples;
      const int v = b.box.y + (b.box.height - 1) * j / kSamples;
      const Eigen::Vector3d m(rays.x.at<float>(v, u), rays.y.at<float>(v, u), 1.0);
      const double w = b.h_w.dot(m);
      if (std::abs(w) < 1e-12) return 1e9;  // degenerate view: always filter
      double J[4], dcol[2], drow[2];
      rays.jacobian(m.x(), m.y(), J);
      boardJacobian(b, J, b.h_col.dot(m) / w, b.h_row.dot(m) / w, w, dcol, drow);
      bound = std::max({bound, std::abs(dcol[0]) + std::abs(dcol[1]), std::abs(drow[0]) + std::abs(drow[1])});
    }
  return 0.5 * bound * 1.25 + 1e-3;  // half-extent, with a safety factor for the variation
}

bool boardBoundingBox(const VirtualBoard& board, const Eigen::Isometry3d& camera_from_board,
                      const CameraRays& rays, cv::Rect* box) {
  // Sample the margin's outline; distortion bends straight edges, so use many points.
  const PinholeCamera& cam = rays.camera;
  const double s = board.square;
  const double y_sign = board.mirrored ? -1.0 : 1.0;
  const double c0 = -2.0, c1 = board.cols + 1.0, r0 = -2.0, r1 = board.rows + 1.0;
  double umin = 1e30, umax = -1e30, vmin = 1e30, vmax = -1e30;
  const int kSteps = 24;
  for (int edge = 0; edge < 4; ++edge) {
    for (int k = 0; k <= kSteps; ++k) {
      const double f = static_cast<double>(k) / kSteps;
      double c, r;
      switch (edge) {
        case 0: c = c0 + f * (c1 - c0); r = r0; break;
        case 1: c = c1; r = r0 + f * (r1 - r0); break;
        case 2: c = c0 + f * (c1 - c0); r = r1; break;
        default: c = c0; r = r0 + f * (r1 - r0); break;
      }
      const Eigen::Vector3d p = camera_from_board * Eigen::Vector3d(c * s, y_sign * r * s, 0.0);
      // Behind the camera or outside the cone the image sees: distortion is not invertible
      // there, so fall back to testing every pixel.
      if (p.z() <= 1e-9 || std::hypot(p.x() / p.z(), p.y() / p.z()) > 1.2 * rays.max_radius) {
        *box = cv::Rect(0, 0, cam.width, cam.height);
        return true;
      }
      Eigen::Vector2d px;
      cam.project(p, &px);
      umin = std::min(umin, px.x());
      umax = std::max(umax, px.x());
      vmin = std::min(vmin, px.y());
      vmax = std::max(vmax, px.y());
    }
  }
  const int pad = 3;
  const cv::Rect raw(static_cast<int>(std::floor(umin)) - pad, static_cast<int>(std::floor(vmin)) - pad,
                     static_cast<int>(std::ceil(umax - umin)) + 2 * pad + 2,
                     static_cast<int>(std::ceil(vmax - vmin)) + 2 * pad + 2);
  *box = raw & cv::Rect(0, 0, cam.width, cam.height);
  return box->area() > 0;
}
// The boards the camera sees the front of, with their bounding boxes in the image.
std::vector<BoardInCamera> visibleBoards(const std::vector<VirtualBoard>& boards, const CameraRays& rays,
                                         const Eigen::Isometry3d& rig_from_camera) {
  std::vector<BoardInCamera> visible;
  for (const VirtualBoard& b : boards) {
    const Eigen::Isometry3d board_from_camera = b.rig_from_board.inverse() * rig_from_camera;
    const Eigen::Vector3d C = board_from_camera.translation();  // camera centre, board frame
    if (C.z() <= 0) continue;  // the camera looks at the back of the board
    const Eigen::Matrix3d Rbc = board_from_camera.linear();
    BoardInCamera bc;
    const double y_sign = b.mirrored ? -1.0 : 1.0;
    // Ray point C + t*Rbc*m meets z = 0 at t = -C.z / (r3.m); see the class comment.
    bc.h_w = Rbc.row(2).transpose();
    bc.h_col = (C.x() * Rbc.row(2) - C.z() * Rbc.row(0)).transpose() / b.square;
    bc.h_row = y_sign * (C.y() * Rbc.row(2) - C.z() * Rbc.row(1)).transpose() / b.square;
    bc.plane_offset = -C.z();
    bc.cols = b.cols;
    bc.rows = b.rows;
    if (!boardBoundingBox(b, board_from_camera.inverse(), rays, &bc.box)) continue;
    bc.half_footprint = footprintBound(bc, rays);
    visible.push_back(bc);
  }
  return visible;
}

// Renders image rows: each pixel shows the nearest visible board whose pattern (with its margin)
// covers it, else the housing. One per thread (it keeps the nearest hit of each pixel of the row).
class RowRenderer {
 public:
  RowRenderer(const std::vector<BoardInCamera>& visible, const CameraRays& rays, double white, double black)
      : visible_(visible), rays_(rays), white_(white), black_(black), best_t_(rays.camera.width) {}

  void render(int v, float* out) {
    const int W = rays_.camera.width, H = rays_.camera.height;
    const float housing = static_cast<float>(black_);
    std::fill(out, out + W, housing);
    std::fill(best_t_.begin(), best_t_.end(), std::numeric_limits<double>::infinity());
    ray_x_ = rays_.x.ptr<float>(v);
    ray_y_ = rays_.y.ptr<float>(v);
    row_above_ = std::max(v - 1, 0), row_below_ = std::min(v + 1, H - 1);
    ray_x_above_ = rays_.x.ptr<float>(row_above_);
    ray_y_above_ = rays_.y.ptr<float>(row_above_);
    ray_x_below_ = rays_.x.ptr<float>(row_below_);
    ray_y_below_ = rays_.y.ptr<float>(row_below_);
    for (const BoardInCamera& b : visible_) {
      if (v < b.box.y || v >= b.box.y + b.box.height) continue;
      for (int u = b.box.x; u < b.box.x + b.box.width; ++u) shade(b, u, out);
    }
  }

 private:
  // Board b at pixel u of the row, when nearer than what the pixel shows so far.
  void shade(const BoardInCamera& b, int u, float* out) {
    const double x = ray_x_[u], y = ray_y_[u];
    const double w = b.h_w.x() * x + b.h_w.y() * y + b.h_w.z();
    if (std::abs(w) < 1e-12) return;
    const double inv_w = 1.0 / w;
    const double t = b.plane_offset * inv_w;
    if (!(t > 0) || t >= best_t_[u]) return;
    const double col = (b.h_col.x() * x + b.h_col.y() * y + b.h_col.z()) * inv_w;
    const double row = (b.h_row.x() * x + b.h_row.y() * y + b.h_row.z()) * inv_w;
    // Quick reject well outside the margin (footprints are far below a square wide).
    if (col < -3.0 || col > b.cols + 2.0 || row < -3.0 || row > b.rows + 2.0) return;
    const double col_floor = std::floor(col), row_floor = std::floor(row);
    const double col_line = std::min(col - col_floor, col_floor + 1.0 - col);
    const double row_line = std::min(row - row_floor, row_floor + 1.0 - row);
    if (col_line > b.half_footprint && row_line > b.half_footprint) {
      // Fast path: no line under the pixel, the pattern is constant there.
      if (col < -2.0 || col > b.cols + 1.0 || row < -2.0 || row > b.rows + 1.0) return;
      const bool in_grid = col > -1.0 && col < b.cols && row > -1.0 && row < b.rows;
      const bool black_square = ((static_cast<long>(col_floor) + static_cast<long>(row_floor)) & 1) == 0;
      best_t_[u] = t;
      out[u] = static_cast<float>(in_grid && black_square ? black_ : white_);
      return;
    }
    // Pixel-area averages along each board axis (exact for straight edges; near a
    // corner the product of the two axes' averages keeps the saddle at the corner).
    // d(x,y)/d(u,v) by central differences of the ray map (rows in cache; one-sided at
    // the image border): the filter width needs a few digits, not the analytic value.
    const int W = rays_.camera.width;
    const int ul = std::max(u - 1, 0), ur = std::min(u + 1, W - 1);
    const double du = 1.0 / (ur - ul), dv = 1.0 / (row_below_ - row_above_);
    const double J[4] = {(ray_x_[ur] - ray_x_[ul]) * du, (ray_x_below_[u] - ray_x_above_[u]) * dv,
                         (ray_y_[ur] - ray_y_[ul]) * du, (ray_y_below_[u] - ray_y_above_[u]) * dv};
    double dcol[2], drow[2];
    boardJacobian(b, J, col, row, w, dcol, drow);
    const AxisFilter fc = filterAxis(col, std::abs(dcol[0]), std::abs(dcol[1]), b.cols);
    const AxisFilter fr = filterAxis(row, std::abs(drow[0]), std::abs(drow[1]), b.rows);
    const double coverage = fc.inside_margin * fr.inside_margin;
    if (coverage <= 0.0) return;
    // Black fraction: housing outside the margin + black squares (both corner squares
    // (-1,-1) etc. are black: square (i, j) is black when i + j is even).
    const double black_fraction =
        1.0 - coverage + 0.5 * (fc.inside_grid * fr.inside_grid + fc.checker * fr.checker);
    best_t_[u] = t;
    out[u] = static_cast<float>(white_ - (white_ - black_) * clampd(black_fraction, 0.0, 1.0));
  }

  const std::vector<BoardInCamera>& visible_;
  const CameraRays& rays_;
  const double white_, black_;
  std::vector<double> best_t_;  // per pixel of the row: distance along the ray of what it shows
  // The row's rays and those of the rows above and below it (one-sided at the image border).
  int row_above_ = 0, row_below_ = 0;
  const float *ray_x_ = nullptr, *ray_y_ = nullptr;
  const float *ray_x_above_ = nullptr, *ray_y_above_ = nullptr, *ray_x_below_ = nullptr, *ray_y_below_ = nullptr;
};

}  // namespace

void renderDevice(const std::vector<VirtualBoard>& boards, const CameraRays& rays,
                  const Eigen::Isometry3d& rig_from_camera, double white, double black,
                  cv::Mat* radiance) {
  radiance->create(rays.camera.height, rays.camera.width, CV_32F);
  const std::vector<BoardInCamera> visible = visibleBoards(boards, rays, rig_from_camera);
  cv::parallel_for_(cv::Range(0, rays.camera.height), [&](const cv::Range& range) {
    RowRenderer renderer(visible, rays, white, black);
    for (int v = range.start; v < range.end; ++v) renderer.render(v, radiance->ptr<float>(v));
  });
}

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
