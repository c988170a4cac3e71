// CameraTracker: per-board prediction, re-centring, refinement and acceptance (see
// pattern_tracker.h for the algorithm and the threading contract).
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "board_alignment.h"
#include "board_geometry.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"

namespace embedded_calibration_stereo::core {

using tracker::applyHomography;
using tracker::BoxSampler;
using tracker::gridPoint;

namespace {

// Edge blur (px) of the coarse alignment template; the image is blurred to match it.
constexpr double kCoarseBlurPx = 3.0;
// Fraction of the board's fitted contrast a corner's own samples must show to be reported.
constexpr double kCornerContrast = 0.5;
// An aligned board's contrast (bright minus dark) must be at least this fraction of the taught
// one: a board seen dimmer than it was taught (a lower reflectance, a dimmer light, one tenth at
// worst) is still there; a light-off frame shows none of it.
constexpr double kMinContrastOfTaught = 0.05;
// Gauss-Newton steps (each template) of an alignment that starts from the re-centred prediction:
// the re-centring leaves a start up to a third of a square off, and on a dim board over a
// textured scene the steps from there are short. A converged fit stops early.
constexpr int kStepsFromPrediction = 24;

// Gauss-Newton steps of the fine alignment: from last frame's result one or two suffice; from
// the refined corners (within a fraction of a pixel) a few; from the re-centred prediction more.
int fineSteps(bool warm, bool from_refined) { return warm ? 3 : from_refined ? 6 : kStepsFromPrediction; }

struct RecentreResult {
  cv::Point2f shift;
  double score = -1.0;
};

// Mean side of one square (px) at the board's centre.
double squareSizePx(const cv::Matx33d& h, const BoardPrior& board) {
  cv::Point2f ac, ar;
  tracker::gridAxes(h, 0.5 * (board.cols - 1), 0.5 * (board.rows - 1), &ac, &ar);
  return 0.5 * (cv::norm(ac) + cv::norm(ar));
}

cv::Point2f offsetNear(const BoardPrior& board, const std::vector<cv::Point2f>& offsets, double col,
                       double row) {
  const int c = std::min(std::max(static_cast<int>(std::lround(col)), 0), board.cols - 1);
  const int r = std::min(std::max(static_cast<int>(std::lround(row)), 0), board.rows - 1);
  return offsets[r * board.cols + c];
}

// Bright (+1) or dark (-1) square whose (-col, -row) corner is grid point (col, row).
int squareSign(const BoardPrior& board, int col, int row) {
  return ((col + row) & 1) == 0 ? board.sign : -board.sign;
}

// A point of the recentring correlation: the middle of a square (or of the white margin around
// them) and its expected brightness (+1 bright, -1 dark).
struct RecentreSample {
  cv::Point2f p;
  float sign;
  int col, row;  // of the square (the margin's at -2 and cols / rows)
};

std::vector<RecentreSample> recentreSamples(const cv::Matx33d& h, const BoardPrior& board,
                                            const std::vector<cv::Point2f>& offsets) {
  std::vector<RecentreSample> samples;
  for (int r = -2; r <= board.rows; ++r) {
    for (int c = -2; c <= board.cols; ++c) {
      const bool margin = r == -2 || c == -2 || r == board.rows || c == board.cols;
      const double x = c + 0.5, y = r + 0.5;
      const float sign = margin ? 1.0f : static_cast<float>(squareSign(board, c, r));
      samples.push_back({applyHomography(h, x, y) + offsetNear(board, offsets, x, y), sign, c, r});
    }
  }
  return samples;
}

// The image region the boxes around the samples reach at any shift.
cv::Rect recentreRoi(const std::vector<RecentreSample>& samples, int box, double radius) {
  const int reach = static_cast<int>(std::ceil(radius)) + box + 2;
  float umin = 1e9f, vmin = 1e9f, umax = -1e9f, vmax = -1e9f;
  for (const RecentreSample& s : samples) {
    umin = std::min(umin, s.p.x);
    vmin = std::min(vmin, s.p.y);
    umax = std::max(umax, s.p.x);
    vmax = std::max(vmax, s.p.y);
  }
  return cv::Rect(static_cast<int>(std::floor(umin)) - reach, static_cast<int>(std::floor(vmin)) - reach,
                  static_cast<int>(umax - umin) + 2 * reach + 2, static_cast<int>(vmax - vmin) + 2 * reach + 2);
}

// The scores of the shifts, (2 * (r_int / step) + 1) on a side, centre at no shift.
struct ShiftScores {
  int step = 1;
  int cells = 0;
  cv::Mat scores;  // CV_64F
  double best = -2.0;
  cv::Point best_cell{0, 0};
  cv::Point2f shiftOf(int ix, int iy) const {
    return cv::Point2f(static_cast<float>((ix - cells / 2) * step), static_cast<float>((iy - cells / 2) * step));
  }
};

// The samples whose box stays in the image at every shift (r_int px at most along each axis).
std::vector<RecentreSample> usableSamples(const std::vector<RecentreSample>& samples, const BoxSampler& sampler,
                                          int r_int) {
  std::vector<RecentreSample> usable;
  for (const RecentreSample& s : samples) {
    if (sampler.contains(s.p + cv::Point2f(-r_int, -r_int)) && sampler.contains(s.p + cv::Point2f(r_int, r_int)))
      usable.push_back(s);
  }
  return usable;
}

// The scene under a board varies over it (a shadow, a lit wall, a face) and, at a low
// reflectance, by more than the pattern's own contrast: a correlation of the box means themselves
// then scores a board that is there below the pattern threshold. The correlation is taken on each
// sample minus the mean of its four grid neighbours instead: the checker keeps its contrast (the
// neighbours are of the other colour), while whatever the scene does over more than a square
// cancels. Samples without four usable neighbours are left out; with too few left (a board half
// out of the image), the box means themselves are correlated.
struct GridFilter {
  std::vector<std::array<int, 5>> rows;  // usable indices: the sample, then its neighbours (-1: none)
  std::vector<double> expected;          // the filtered signs, mean removed
  double expected_norm2 = 0.0;
  // A sample minus the mean of its neighbours (the sample itself without neighbours).
  static double value(const std::array<int, 5>& row, const std::vector<float>& v) {
    if (row[1] < 0) return v[row[0]];
    return v[row[0]] - 0.25 * (v[row[1]] + v[row[2]] + v[row[3]] + v[row[4]]);
  }
  std::vector<double> apply(const std::vector<float>& v) const {
    std::vector<double> out;
    for (const auto& row : rows) out.push_back(value(row, v));
    return out;
  }
};

GridFilter gridFilter(const std::vector<RecentreSample>& usable) {
  constexpr size_t kMinRows = 16;
  std::map<std::pair<int, int>, int> at;
  for (size_t i = 0; i < usable.size(); ++i) at[{usable[i].col, usable[i].row}] = static_cast<int>(i);
  GridFilter f;
  for (size_t i = 0; i < usable.size(); ++i) {
    std::array<int, 5> row{static_cast<int>(i), -1, -1, -1, -1};
    const int dc[4] = {1, -1, 0, 0}, dr[4] = {0, 0, 1, -1};
    bool complete = true;
    for (int k = 0; k < 4 && complete; ++k) {
      const auto it = at.find({usable[i].col + dc[k], usable[i].row + dr[k]});
      complete = it != at.end();
      if (complete) row[k + 1] = it->second;
    }
    if (complete) f.rows.push_back(row);
  }
  if (f.rows.size() < kMinRows) {
    f.rows.clear();
    for (size_t i = 0; i < usable.size(); ++i) f.rows.push_back({static_cast<int>(i), -1, -1, -1, -1});
  }
  std::vector<float> sign(usable.size());
  for (size_t i = 0; i < usable.size(); ++i) sign[i] = usable[i].sign;
  f.expected = f.apply(sign);
  double mean = 0;
  for (double e : f.expected) mean += e;
  mean /= f.expected.size();
  for (double& e : f.expected) e -= mean, f.expected_norm2 += e * e;
  return f;
}

// Correlation of the filtered signs with the filtered box means at every shift of the window.
void scoreShifts(const std::vector<RecentreSample>& usable, const BoxSampler& sampler, const GridFilter& filter,
                 ShiftScores* grid) {
  grid->scores = cv::Mat(grid->cells, grid->cells, CV_64F, cv::Scalar(-1.0));
  std::vector<float> v(usable.size());
  const double n = static_cast<double>(filter.rows.size());
  for (int iy = 0; iy < grid->cells; ++iy) {
    for (int ix = 0; ix < grid->cells; ++ix) {
      const cv::Point2f d = grid->shiftOf(ix, iy);
      for (size_t i = 0; i < usable.size(); ++i) sampler.mean(usable[i].p + d, &v[i]);
      double sv = 0, v1 = 0, v2 = 0;
      for (size_t r = 0; r < filter.rows.size(); ++r) {
        const double x = filter.value(filter.rows[r], v);
        sv += filter.expected[r] * x;
        v1 += x;
        v2 += x * x;
      }
      const double var = v2 - v1 * v1 / n;
      const double score = var > 1e-9 ? sv / std::sqrt(var * filter.expected_norm2) : 0.0;
      grid->scores.at<double>(iy, ix) = score;
      if (score > grid->best) {
        grid->best = score;
        grid->best_cell = cv::Point(ix, iy);
      }
    }
  }
}

// Centroid of the plateau around the best shift (within half a square of it).
cv::Point2f plateauCentroid(const ShiftScores& grid, double square) {
  const int cells = grid.cells, step = grid.step;
  const cv::Point best_cell = grid.best_cell;
  const double threshold = grid.best - 0.1 * std::abs(grid.best);
  const int half = std::max(1, static_cast<int>(0.5 * square / step));
  double wsum = 0, xsum = 0, ysum = 0;
  for (int iy = std::max(0, best_cell.y - half); iy <= std::min(cells - 1, best_cell.y + half); ++iy) {
    for (int ix = std::max(0, best_cell.x - half); ix <= std::min(cells - 1, best_cell.x + half); ++ix) {
      const double wgt = grid.scores.at<double>(iy, ix) - threshold;
      if (wgt <= 0) continue;
      wsum += wgt;
      xsum += wgt * (ix - cells / 2) * step;
      ysum += wgt * (iy - cells / 2) * step;
    }
  }
  return wsum > 0 ? cv::Point2f(static_cast<float>(xsum / wsum), static_cast<float>(ysum / wsum))
                  : cv::Point2f((best_cell.x - cells / 2) * step, (best_cell.y - cells / 2) * step);
}

// Correlates the expected brightness of the squares (and of the white margin around them)
// with box means of the image over a window of shifts. The score is flat while every box stays
// inside its square, so the shift is the centroid of the near-maximal plateau, not the argmax.
RecentreResult recentre(const cv::Mat& gray, const cv::Matx33d& h, const BoardPrior& board,
                        const std::vector<cv::Point2f>& offsets, double square, double radius, int step) {
  const std::vector<RecentreSample> samples = recentreSamples(h, board, offsets);
  const int box = std::max(1, static_cast<int>(std::lround(0.2 * square)));
  const BoxSampler sampler(gray, recentreRoi(samples, box, radius), box);
  const int r_int = static_cast<int>(std::ceil(radius));
  const std::vector<RecentreSample> usable = usableSamples(samples, sampler, r_int);
  RecentreResult result;
  if (usable.size() < 8) return result;
  const GridFilter filter = gridFilter(usable);
  if (filter.expected_norm2 <= 1e-9) return result;  // all of one sign: no contrast to correlate
  ShiftScores grid;
  grid.step = step;
  grid.cells = 2 * (r_int / step) + 1;
  scoreShifts(usable, sampler, filter, &grid);
  result.score = grid.best;
  result.shift = plateauCentroid(grid, square);
  return result;
}

// Least-squares homography of grid -> (pixel - offset) for the listed corners after a RANSAC
// pass; returns the corners within max_residual of it.
bool fitBoardModel(const BoardPrior& board, const std::vector<int>& ids, const std::vector<cv::Point2f>& pos,
                   const std::vector<cv::Point2f>& offsets, double max_residual, cv::Matx33d* h,
                   std::vector<int>* inliers) {
  inliers->clear();
  if (ids.size() < 4) return false;
  std::vector<cv::Point2f> grid, image;
  for (int id : ids) {
    grid.push_back(gridPoint(id, board.cols));
    image.push_back(pos[id] - offsets[id]);
  }
  std::vector<int> current = ids;
  // Steady state: every candidate agrees with the least-squares fit; RANSAC only otherwise.
  cv::Matx33d ls;
  bool all_fit = tracker::fitHomographyLeastSquares(grid, image, &ls);
  for (size_t k = 0; all_fit && k < ids.size(); ++k)
    all_fit = cv::norm(applyHomography(ls, grid[k].x, grid[k].y) - image[k]) <= max_residual;
  if (all_fit) {
    *h = ls;
    *inliers = ids;
    return true;
  }
  cv::Mat fit;
  if (ids.size() >= 8) {
    std::vector<uchar> mask;
    fit = cv::findHomography(grid, image, cv::RANSAC, 2.0 * max_residual, mask, 500, 0.999);
    if (fit.empty()) return false;
    std::vector<cv::Point2f> g2, i2;
    current.clear();
    for (size_t k = 0; k < ids.size(); ++k) {
      if (!mask[k]) continue;
      current.push_back(ids[k]);
      g2.push_back(grid[k]);
      i2.push_back(image[k]);
    }
    grid.swap(g2);
    image.swap(i2);
    if (current.size() < 4) return false;
  }
  // Least squares on the RANSAC inliers, then drop what is still too far and fit once more.
  for (int round = 0; round < 2; ++round) {
    if (!tracker::fitHomographyLeastSquares(grid, image, h)) return false;
    std::vector<cv::Point2f> g2, i2;
    std::vector<int> kept;
    for (size_t k = 0; k < current.size(); ++k) {
      const cv::Point2f model = applyHomography(*h, grid[k].x, grid[k].y);
      if (cv::norm(model - image[k]) <= max_residual) {
        kept.push_back(current[k]);
        g2.push_back(grid[k]);
        i2.push_back(image[k]);
      }
    }
    const bool stable = kept.size() == current.size();
    current.swap(kept);
    grid.swap(g2);
    image.swap(i2);
    if (current.size() < 4) return false;
    if (stable) break;
  }
  *inliers = current;
  return true;
}

}  // namespace

CameraTracker::CameraTracker(CameraPrior prior, TrackerOptions options)
    : prior_(std::move(prior)), options_(options) {
  const std::string problem = prior_.validate();
  if (!problem.empty()) throw ConfigError("prior", problem);
  const std::string bad_option = options_.validate();
  if (!bad_option.empty()) throw ConfigError("tracker options", bad_option);
  auto templates = std::make_shared<std::vector<tracker::AlignmentTemplate>>();
  // Pixels away from every board (outside the taught margins, with a band for drift), every
  // 4th pixel: where a background difference shows only what is left of the scene.
  away_from_boards_ = cv::Mat(prior_.height, prior_.width, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < prior_.height; y += 4)
    for (int x = 0; x < prior_.width; x += 4) away_from_boards_.at<uchar>(y, x) = 1;
  for (const BoardPrior& board : prior_.boards) {
    // Fine template (2i) and a coarse one (2i+1, a wide blur on a sparse lattice) that widens the
    // alignment's reach when it starts from a prediction rather than from refined corners.
    const double blur = !board.device_pattern && board.edge_blur_px > 0
                            ? std::min(std::max(board.edge_blur_px, 0.5), 3.0)
                            : options_.alignment_blur_px;
    templates->push_back(tracker::buildAlignmentTemplate(board, blur));
    templates->push_back(tracker::buildAlignmentTemplate(board, kCoarseBlurPx, 3));
    const cv::Matx33d h = tracker::homographyFromOuter(board, board.meanOuterCorners());
    std::vector<cv::Point> hull;
    for (const cv::Point2f& g : {cv::Point2f(-2.5f, -2.5f), cv::Point2f(board.cols + 1.5f, -2.5f),
                                 cv::Point2f(board.cols + 1.5f, board.rows + 1.5f),
                                 cv::Point2f(-2.5f, board.rows + 1.5f)})
      hull.push_back(applyHomography(h, g.x, g.y));
    cv::fillConvexPoly(away_from_boards_, hull, cv::Scalar(0));
  }
  templates_ = templates;
  reset();
}

double CameraTracker::backgroundResidual(const cv::Mat& difference) const {
  // Also away from where the boards are tracked now: after a zoom step or a knock their lit
  // margins lie outside the taught places, and would count as scene left in the difference.
  cv::Mat away = away_from_boards_.clone();
  for (size_t i = 0; i < states_.size(); ++i) {
    if (!states_[i].valid) continue;
    const BoardPrior& board = prior_.boards[i];
    std::vector<cv::Point> hull;
    for (const cv::Point2f& g : {cv::Point2f(-2.5f, -2.5f), cv::Point2f(board.cols + 1.5f, -2.5f),
                                 cv::Point2f(board.cols + 1.5f, board.rows + 1.5f),
                                 cv::Point2f(-2.5f, board.rows + 1.5f)})
      hull.push_back(applyHomography(states_[i].homography, g.x, g.y));
    cv::fillConvexPoly(away, hull, cv::Scalar(0));
  }
  std::vector<uchar> values;
  for (int y = 0; y < difference.rows; y += 4) {
    const uchar* m = away.ptr<uchar>(y);
    const uchar* d = difference.ptr<uchar>(y);
    for (int x = 0; x < difference.cols; x += 4)
      if (m[x]) values.push_back(d[x]);
  }
  if (values.size() < 100) return 0.0;
  auto mid = values.begin() + values.size() / 2;
  std::nth_element(values.begin(), mid, values.end());
  const int median = *mid;
  // Mean absolute deviation from the median, as a normal sigma (continuous, unlike the median
  // of integer deviations).
  double sum = 0;
  for (uchar v : values) sum += std::abs(v - median);
  const double spread = 1.2533 * sum / values.size();
  return spread;
}

void CameraTracker::reset() {
  states_.assign(prior_.boards.size(), BoardState());
  stats_.assign(prior_.boards.size(), BoardTrackStats());
  for (size_t i = 0; i < prior_.boards.size(); ++i) {
    states_[i].offsets = prior_.boards[i].offsets;
    stats_[i].board_id = prior_.boards[i].board_id;
  }
}

void CameraTracker::setBackground(const cv::Mat& light_off, ColorOrder order) {
  const cv::Mat gray = toGrayImage(light_off, order);
  if (gray.cols != prior_.width || gray.rows != prior_.height)
    throw std::invalid_argument("background image size differs from the prior's image size");
  background_.set(gray);
  background_known_stale_ = false;
}

namespace {
size_t cornerCount(const std::vector<BoardCorners>& boards) {
  size_t n = 0;
  for (const BoardCorners& b : boards) n += b.size();
  return n;
}
}  // namespace

std::vector<BoardCorners> CameraTracker::track(const cv::Mat& image, ColorOrder order) {
  const cv::Mat gray = toGrayImage(image, order);
  background_stale_ = false;
  if (background_.empty()) {
    background_residual_ = 0.0;
    return trackAll(gray, false, true);
  }
  if (gray.size() != cv::Size(prior_.width, prior_.height))
    throw std::invalid_argument("image size differs from the prior's image size");
  if (background_known_stale_) {
    background_stale_ = true;
    std::vector<BoardCorners> found = trackAll(gray, false, true);
    last_found_ = cornerCount(found);
    return found;
  }
  cv::Mat diff = background_.difference(gray, options_.difference_smoothing_px);
  // Kept to undo what tracking on a difference found stale below taught the boards' states.
  const std::vector<BoardState> before = states_;
  std::vector<BoardCorners> found = trackAll(diff, true, false);
  if (cornerCount(found) < last_found_ / 2) {
    // A stale background (the image moved since) can hide the boards: find them without it
    // (unaligned: the background is re-registered to them and the frame tracked again).
    std::vector<BoardCorners> raw = trackAll(gray, false, false);
    if (cornerCount(raw) > cornerCount(found)) found = std::move(raw);
  }
  for (int round = 0; round < 3 && background_.follow(found, options_.background_motion_px); ++round) {
    diff = background_.difference(gray, options_.difference_smoothing_px);
    found = trackAll(diff, true, false);
  }
  // The scene left in the difference away from the boards: a still scene cancels to the noise,
  // a moved one leaves two superimposed scenes, worse than one. Then track the raw image, and
  // keep doing so until the next background.
  background_residual_ = backgroundResidual(diff);
  if (background_residual_ > options_.stale_background_level) {
    background_stale_ = background_known_stale_ = true;
    states_ = before;
    found = trackAll(gray, false, true);
  }
  last_found_ = cornerCount(found);
  return found;
}

std::vector<BoardCorners> CameraTracker::trackSceneFree(const cv::Mat& device_image) {
  CV_Assert(device_image.type() == CV_32FC1 || device_image.type() == CV_8UC1);
  if (device_image.size() != cv::Size(prior_.width, prior_.height))
    throw std::invalid_argument("image size differs from the prior's image size");
  // As SceneBackground::difference: offset so that noise on dark squares is not clipped, smoothed.
  cv::Mat diff;
  device_image.convertTo(diff, CV_8U, 1.0, SceneBackground::kDifferenceOffset);
  if (options_.difference_smoothing_px > 0) {
    const int k = 2 * static_cast<int>(std::ceil(2.0 * options_.difference_smoothing_px)) + 1;
    cv::GaussianBlur(diff, diff, cv::Size(k, k), options_.difference_smoothing_px);
  }
  background_stale_ = false;
  background_residual_ = 0.0;
  std::vector<BoardCorners> found = trackAll(diff, true, false);
  last_found_ = cornerCount(found);
  return found;
}

std::vector<BoardCorners> CameraTracker::trackAll(const cv::Mat& gray, bool on_difference, bool align) {
  std::vector<BoardCorners> out(prior_.boards.size());
  auto body = [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) out[i] = trackBoard(gray, i, on_difference, align);
  };
  if (options_.parallel)
    cv::parallel_for_(cv::Range(0, boardCount()), body);
  else
    body(cv::Range(0, boardCount()));
  std::vector<BoardCorners> found;
  for (BoardCorners& b : out)
    if (b.size() > 0) found.push_back(std::move(b));
  return found;
}

BoardCorners CameraTracker::trackBoard(const cv::Mat& gray, int index, bool on_difference, bool align) {
  BoardCorners out = trackBoardOnce(gray, index, on_difference, align, false);
  // The quick steady-state path can be fooled by a move of about half a square (the score at the
  // old position is still high): retry with the full re-centring search.
  if (out.size() == 0 && !stats_[index].wide_search) out = trackBoardOnce(gray, index, on_difference, align, true);
  return out;
}

// One attempt at one board (trackBoardOnce): what its numbered steps share.
struct CameraTracker::BoardAttempt {
  BoardAttempt(const cv::Mat& image, const BoardPrior& prior, const std::vector<cv::Point2f>& board_offsets)
      : gray(image), board(prior), offsets(board_offsets), n(prior.cornerCount()), pos(n), candidate(n, 0) {}
  const cv::Mat& gray;
  const BoardPrior& board;
  const std::vector<cv::Point2f>& offsets;
  const int n;
  double square = 0.0;      // square side (px) at the predicted pose
  int window = 0;           // cornerSubPix half-window (px)
  double max_residual = 0;  // board model's residual gate (px)
  float margin = 0.0f;      // corners closer to the edge are not refined
  int needed = 0;           // corners a board needs
  float min_contrast = 0.0f;
  double max_shift = 0.0;   // a refined corner's largest move from its prediction (px)
  cv::Matx33d h;            // the board model: grid -> pixel, minus offsets
  cv::Matx33d recentred;    // the model after re-centring (step 1)
  std::vector<int> todo;    // corners to refine next
  std::vector<cv::Point2f> pos;
  std::vector<char> candidate;
  std::vector<int> accepted;
  bool fitted = false, refine_done = false;

  bool inside(const cv::Point2f& p) const {
    return p.x >= margin && p.y >= margin && p.x <= gray.cols - 1 - margin && p.y <= gray.rows - 1 - margin;
  }
  cv::Point2f predicted(const cv::Matx33d& model, int id) const {
    const cv::Point2f g = gridPoint(id, board.cols);
    return applyHomography(model, g.x, g.y) + offsets[id];
  }
  // The corners not yet accepted whose prediction lies inside the image.
  void predictTodo() {
    todo.clear();
    for (int id = 0; id < n; ++id)
      if (!candidate[id] && inside(predicted(h, id))) todo.push_back(id);
  }
  bool refined() const { return fitted && static_cast<int>(accepted.size()) >= needed; }
};

BoardCorners CameraTracker::trackBoardOnce(const cv::Mat& gray, int index, bool on_difference, bool align,
                                           bool wide) {
  CV_Assert(gray.type() == CV_8UC1);
  const BoardPrior& board = prior_.boards.at(index);
  BoardState& state = states_[index];
  BoardTrackStats& stats = stats_[index];
  stats = BoardTrackStats();
  stats.board_id = board.board_id;
  BoardCorners out;
  out.board_id = board.board_id;

  BoardAttempt a(gray, board, state.offsets);
  a.h = state.valid ? state.homography : tracker::homographyFromOuter(board, board.meanOuterCorners());
  a.square = squareSizePx(a.h, board);
  a.window = options_.window_radius_px > 0 ? options_.window_radius_px
             : on_difference
                 // Scene removed: a window of 0.6 square averages the residual better.
                 ? std::min(7, std::max(2, static_cast<int>(std::lround(0.6 * a.square))))
                 // Scene present: keep its texture out of the window.
                 : std::min(5, std::max(2, static_cast<int>(std::lround(0.4 * a.square))));
  a.max_residual = on_difference ? options_.max_residual_px : options_.max_residual_no_background_px;

  // 1. Re-centre on the expected pattern.
  // Steady state: a small search around the last position, accepted when the pattern is as
  // clear as last time; otherwise (first frame, zoom step, knock) the full search window.
  RecentreResult centre;
  bool settled = false;
  if (!wide && state.valid && state.last_score > 0) {
    // The score is flat while the boxes stay inside their squares, so the score at the last
    // position tells whether the board is still within the refinement's reach.
    centre = recentre(gray, a.h, board, a.offsets, a.square, 0.0, 1);
    settled = centre.score >= 0.85 * state.last_score;
  }
  stats.wide_search = !settled;
  if (!settled)
    centre = recentre(gray, a.h, board, a.offsets, a.square, options_.search_radius_px,
                      options_.search_radius_px > 4 ? 2 : 1);
  stats.pattern_score = centre.score;
  stats.recentre_shift = centre.shift;
  if (centre.score < options_.min_pattern_score) return out;
  a.h = cv::Matx33d(1, 0, centre.shift.x, 0, 1, centre.shift.y, 0, 0, 1) * a.h;
  a.recentred = a.h;

  // Corners whose refinement window (and saddle samples) stay inside the image.
  a.margin = static_cast<float>(a.window + 2);
  a.predictTodo();
  stats.predicted = static_cast<int>(a.todo.size());
  a.needed = std::max(options_.min_board_corners,
                      static_cast<int>(std::ceil(options_.min_board_fraction * stats.predicted)));
  if (stats.predicted < a.needed) return out;
  a.min_contrast = static_cast<float>(std::max(options_.min_contrast, options_.relative_contrast * board.contrast));
  a.max_shift = options_.max_refine_shift * a.window;

  const bool align_board = align && !on_difference && options_.whole_board_alignment &&
                           !(*templates_)[2 * index].empty();
  // Steady state on a raw image: the board was aligned last frame and the pattern is still there
  // at its last position, so the alignment starts from last frame's (the refinement, there only
  // to find a start and to verify it, is skipped unless that fails).
  const bool steady = align_board && settled && state.align_valid;
  if (!steady) refineCorners(a);
  if (!a.refined() && !align_board) return out;

  // Without a background: align the whole board; its corners replace the refined ones.
  if (align_board) {
    stats.aligned = alignWholeBoard(a, index, steady);
    // Refined corners alone are not trusted on a raw image: the scene can pull one by more than
    // a pixel. A board that does not align gives nothing this frame.
    if (!stats.aligned) return out;
  }
  acceptBoard(a, index, centre.score, &out);
  return out;
}

// Steps 2-5: predict and refine the corners, keep those that pass the saddle test, re-fit the
// board model to them, and retry the rest from the re-fitted model.
void CameraTracker::refineCorners(BoardAttempt& a) const {
  a.refine_done = true;
  const BoardPrior& board = a.board;
  const cv::TermCriteria criteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 10, 0.01);
  // Box means for the saddle test (an integral image of the board's region: built only here,
  // since the steady state on a raw image skips the refinement).
  const int saddle_box = std::max(1, static_cast<int>(std::lround(0.12 * a.square)));
  const int reach = static_cast<int>(std::ceil(0.6 * a.square)) + saddle_box + a.window + 2;
  float umin = 1e9f, vmin = 1e9f, umax = -1e9f, vmax = -1e9f;
  for (const cv::Point2f& g : board.outerGridPoints()) {
    const cv::Point2f p = applyHomography(a.h, g.x, g.y);
    umin = std::min(umin, p.x);
    vmin = std::min(vmin, p.y);
    umax = std::max(umax, p.x);
    vmax = std::max(vmax, p.y);
  }
  const BoxSampler saddle_sampler(
      a.gray,
      cv::Rect(static_cast<int>(umin) - reach, static_cast<int>(vmin) - reach,
               static_cast<int>(umax - umin) + 2 * reach, static_cast<int>(vmax - vmin) + 2 * reach),
      saddle_box);
  for (int iteration = 0; iteration < options_.max_iterations && !a.todo.empty(); ++iteration) {
    // 2. Predict and refine.
    std::vector<cv::Point2f> points;
    for (int id : a.todo) points.push_back(a.predicted(a.h, id));
    const std::vector<cv::Point2f> predicted = points;
    cv::cornerSubPix(a.gray, points, cv::Size(a.window, a.window), cv::Size(-1, -1), criteria);
    // 3. Saddle test: the expected polarity with enough contrast.
    int fresh = 0;
    for (size_t k = 0; k < a.todo.size(); ++k) {
      const int id = a.todo[k];
      if (!a.inside(points[k]) || cv::norm(points[k] - predicted[k]) > a.max_shift) continue;
      const cv::Point2f g = gridPoint(id, board.cols);
      cv::Point2f ac, ar;
      tracker::gridAxes(a.h, g.x, g.y, &ac, &ar);
      const int bright = ((static_cast<int>(g.x) + static_cast<int>(g.y)) & 1) == 0 ? board.sign : -board.sign;
      if (tracker::saddleContrast(saddle_sampler, points[k], ac, ar, bright) < a.min_contrast) continue;
      a.pos[id] = points[k];
      a.candidate[id] = 1;
      ++fresh;
    }
    if (fresh == 0 && a.fitted) break;
    // 4. Re-fit the board model to every candidate; keep the consistent ones.
    std::vector<int> ids;
    for (int id = 0; id < a.n; ++id)
      if (a.candidate[id]) ids.push_back(id);
    cv::Matx33d refit;
    std::vector<int> inliers;
    if (!fitBoardModel(board, ids, a.pos, a.offsets, a.max_residual, &refit, &inliers)) break;
    a.h = refit;
    a.fitted = true;
    a.accepted = inliers;
    std::fill(a.candidate.begin(), a.candidate.end(), 0);
    for (int id : a.accepted) a.candidate[id] = 1;
    // 5. Retry the rest from the re-fitted model.
    a.predictTodo();
  }
}

// Step 6, without a background: the whole board aligned to its taught template; its corners
// replace the refined ones. Its geometry is verified either by the refined corners (when enough
// passed the saddle test, they must agree with it) or, when the scene hides too many saddles for
// that (a dim board over a textured scene), by the re-centring: the alignment starts from the
// re-centred prediction and must stay within a fraction of a square of it, so no square can slip.
// In steady state it starts from last frame's alignment; then from the refined corners when
// there are enough, else (or when that fails) from the re-centred prediction.
bool CameraTracker::alignWholeBoard(BoardAttempt& a, int index, bool steady) {
  BoardState& state = states_[index];
  const bool was_aligned = state.align_valid;
  state.align_valid = false;
  for (int attempt = steady ? -1 : a.refined() ? 0 : 1; attempt < 2; ++attempt) {
    if (attempt == 0) {
      if (!a.refine_done) refineCorners(a);
      if (!a.refined()) continue;
    }
    if (alignFrom(a, index, attempt, was_aligned)) return true;
  }
  return false;
}

// The corners an alignment start is checked against: the template's corners under last frame's
// alignment (`last`), or the re-centred prediction (`last` null); those inside the image.
void CameraTracker::referenceCorners(const BoardAttempt& a, const tracker::AlignmentTemplate& tmpl,
                                     const cv::Matx33d* last, std::vector<int>* ids,
                                     std::vector<cv::Point2f>* positions) {
  for (int id = 0; id < a.n; ++id) {
    const cv::Point2f c = tmpl.corners[id];
    const cv::Point2f p = last ? applyHomography(*last, c.x, c.y) : a.predicted(a.recentred, id);
    if (!a.inside(p)) continue;
    ids->push_back(id);
    positions->push_back(p);
  }
}

// The aligned board's corners that are inside the image and where the pattern is there around
// them: the contrast fitted on their own samples is at least half the board's (what an occluder
// or a light-off region lacks; an averaged measure, unlike a saddle test, which a scene brighter
// than the pattern defeats). Enough of them replace the accepted corners and re-fit the model.
bool CameraTracker::keepAligned(BoardAttempt& a, const tracker::AlignmentTemplate& tmpl,
                                const tracker::AlignmentResult& fit) {
  std::vector<int> kept;
  for (int id = 0; id < a.n; ++id) {
    const cv::Point2f c = tmpl.corners[id];
    const cv::Point2f p = applyHomography(fit.a, c.x, c.y);
    if (!a.inside(p) || !(fit.corner_contrast[id] >= kCornerContrast)) continue;
    a.pos[id] = p;
    kept.push_back(id);
  }
  if (static_cast<int>(kept.size()) < a.needed) return false;
  a.accepted = kept;
  std::vector<cv::Point2f> grid, image;
  for (int id : a.accepted) {
    grid.push_back(gridPoint(id, a.board.cols));
    image.push_back(a.pos[id] - a.offsets[id]);
  }
  cv::Matx33d refit;
  if (tracker::fitHomographyLeastSquares(grid, image, &refit)) a.h = refit;
  return true;
}

// One start of the whole-board alignment: -1 last frame's alignment, 0 the refined corners,
// 1 the re-centred prediction. True when the board aligned; its corners are then accepted.
bool CameraTracker::alignFrom(BoardAttempt& a, int index, int attempt, bool was_aligned) {
  const tracker::AlignmentTemplate& tmpl = (*templates_)[2 * index];
  BoardState& state = states_[index];
  const bool from_last = attempt == -1, from_refined = attempt == 0;
  std::vector<int> ref_ids;
  std::vector<cv::Point2f> ref_pos;
  if (from_refined) {
    ref_ids = a.accepted;
    for (int id : a.accepted) ref_pos.push_back(a.pos[id]);
  } else {
    referenceCorners(a, tmpl, from_last ? &state.align_a : nullptr, &ref_ids, &ref_pos);
  }
  // How far the aligned corners may be from where the attempt started: the refined corners
  // agree to within the residual gate; a board re-centred (or still in place) is within a
  // fraction of a square, so no square can slip.
  const double agree_px = from_refined ? a.max_residual : from_last ? 0.25 * a.square : 0.35 * a.square;
  const auto rmsTo = [&](const cv::Matx33d& model) {
    double sq = 0;
    for (size_t k = 0; k < ref_ids.size(); ++k) {
      const cv::Point2f c = tmpl.corners[ref_ids[k]];
      sq += std::pow(cv::norm(applyHomography(model, c.x, c.y) - ref_pos[k]), 2);
    }
    return std::sqrt(sq / std::max<size_t>(1, ref_ids.size()));
  };
  tracker::AlignmentResult start;
  // Start from the last frame's alignment while the board stays where it was (its corners
  // agree with this frame's refined ones): one step then usually suffices.
  const bool warm = from_last || (from_refined && was_aligned && rmsTo(state.align_a) <= a.max_residual);
  if (warm) {
    start.a = state.align_a;
    start.contrast = state.align_contrast;
    start.huber = state.align_huber;
    start.levels = state.align_levels;
  }
  bool started = warm || tracker::fitAlignmentStart(tmpl, ref_ids, ref_pos, &start.a);
  if (started && !warm && !from_refined) {
    // From a prediction (within a few pixels): first on the blurred image with the coarse
    // template, whose edges reach that far.
    const tracker::AlignmentTemplate& coarse = (*templates_)[2 * index + 1];
    cv::Mat blurred;
    const double blur = std::min(kCoarseBlurPx - 0.5, options_.alignment_blur_px);
    cv::GaussianBlur(a.gray, blurred, cv::Size(), std::sqrt(kCoarseBlurPx * kCoarseBlurPx - blur * blur));
    const tracker::AlignmentResult c = tracker::alignBoard(coarse, blurred, start, false, kStepsFromPrediction);
    started = c.ok;
    if (c.ok) start.a = c.a;
  }
  if (!started) return false;
  const tracker::AlignmentResult fit = tracker::alignBoard(tmpl, a.gray, start, warm, fineSteps(warm, from_refined));
  // The board's contrast in this frame (bright minus dark, as teaching measured it): present,
  // and not far below the taught one (a light-off frame has none).
  if (!fit.ok || 2.0 * fit.contrast < std::max(options_.min_contrast, kMinContrastOfTaught * a.board.contrast)) return false;
  if (rmsTo(fit.a) > agree_px) return false;
  // From last frame's position only when the fit settled there: a board that moved by more
  // than the fine template's reach is found again from its refined corners.
  // A template off the edges also sees much less of the pattern's contrast than last frame.
  if (from_last && (!fit.converged || fit.contrast < 0.7 * state.align_contrast)) return false;
  if (!keepAligned(a, tmpl, fit)) return false;
  state.align_valid = true;
  state.align_a = fit.a;
  state.align_contrast = fit.contrast;
  state.align_huber = fit.huber;
  state.align_levels = fit.levels;
  return true;
}

// Step 7: the accepted corners out; the board's state (model, offsets, score) and statistics,
// with the tracked outer corners' deviation from the prior's mean and modes.
void CameraTracker::acceptBoard(BoardAttempt& a, int index, double score, BoardCorners* out) {
  BoardState& state = states_[index];
  BoardTrackStats& stats = stats_[index];
  const BoardPrior& board = a.board;
  std::sort(a.accepted.begin(), a.accepted.end());
  double sq = 0;
  for (int id : a.accepted) {
    const cv::Point2f g = gridPoint(id, board.cols);
    const cv::Point2f residual = a.pos[id] - state.offsets[id] - applyHomography(a.h, g.x, g.y);
    sq += residual.dot(residual);
    out->corner_ids.push_back(id);
    out->u.push_back(a.pos[id].x);
    out->v.push_back(a.pos[id].y);
    // Follow slow changes of the distortion pattern (the board moving in the image).
    state.offsets[id] += static_cast<float>(options_.offset_update_rate) * residual;
  }
  state.homography = a.h;
  state.valid = true;
  state.last_score = score;
  stats.found = static_cast<int>(a.accepted.size());
  stats.rms_residual_px = std::sqrt(sq / a.accepted.size());
  if (board.outer_mean.empty()) return;
  cv::Mat x(1, 8, CV_64F);
  const std::vector<cv::Point2f> grid = board.outerGridPoints();
  const int n = a.n;
  const int outer_ids[4] = {0, board.cols - 1, n - 1, n - board.cols};
  for (int i = 0; i < 4; ++i) {
    const cv::Point2f p = applyHomography(a.h, grid[i].x, grid[i].y) + state.offsets[outer_ids[i]];
    x.at<double>(0, 2 * i) = p.x;
    x.at<double>(0, 2 * i + 1) = p.y;
  }
  cv::Mat d = x - board.outer_mean;
  for (int m = 0; m < board.outer_modes.rows; ++m) d -= d.dot(board.outer_modes.row(m)) * board.outer_modes.row(m);
  stats.prior_deviation_px = std::sqrt(d.dot(d) / 4.0);
}

}  // namespace embedded_calibration_stereo::core
