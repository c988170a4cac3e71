// Teaching: bootstrap detection with findChessboardCornersSB, identification and prior learning
// (see board_teacher.h).
#include "embedded_calibration_stereo/core/tracker/board_teacher.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

#include "board_geometry.h"

namespace embedded_calibration_stereo::core {

BoardLayout BoardLayout::plainChessboard(int cols, int rows) {
  BoardLayout layout;
  VirtualBoard b;
  b.cols = cols;
  b.rows = rows;
  b.square = 1.0;
  layout.boards.push_back(b);
  return layout;
}

BoardLayout BoardLayout::device(const std::vector<VirtualBoard>& boards, const PinholeCamera& camera,
                                const Eigen::Isometry3d& camera_from_rig) {
  BoardLayout layout;
  layout.boards = boards;
  layout.has_camera = true;
  layout.camera = camera;
  layout.camera_from_rig = camera_from_rig;
  return layout;
}

bool BoardLayout::predictCorners(size_t index, std::vector<cv::Point2f>* pixels) const {
  pixels->clear();
  if (!has_camera || index >= boards.size()) return false;
  const VirtualBoard& b = boards[index];
  for (int id = 0; id < b.cornerCount(); ++id) {
    Eigen::Vector2d px;
    if (!camera.project(camera_from_rig * b.cornerInRig(id), &px)) return false;
    pixels->emplace_back(static_cast<float>(px.x()), static_cast<float>(px.y()));
  }
  return true;
}

namespace {

struct Detection {
  int cols, rows;
  std::vector<cv::Point2f> corners;  // findChessboardCornersSB order
};

cv::Point2f centroid(const std::vector<cv::Point2f>& pts) {
  cv::Point2f c(0, 0);
  for (const cv::Point2f& p : pts) c += p;
  return c * (1.0f / static_cast<float>(pts.size()));
}

double meanSpacing(const std::vector<cv::Point2f>& corners, int cols, int rows) {
  double sum = 0;
  int count = 0;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      if (c + 1 < cols) sum += cv::norm(corners[r * cols + c + 1] - corners[r * cols + c]), ++count;
      if (r + 1 < rows) sum += cv::norm(corners[(r + 1) * cols + c] - corners[r * cols + c]), ++count;
    }
  return count ? sum / count : 0.0;
}

// Index into the detection of corner `id` under grid symmetry `sym` (bit 0: reverse columns,
// bit 1: reverse rows, bit 2: transpose, only for square grids).
int symmetricIndex(int id, int cols, int rows, int sym) {
  int c = id % cols, r = id / cols;
  if (sym & 4) std::swap(c, r);
  if (sym & 1) c = cols - 1 - c;
  if (sym & 2) r = rows - 1 - r;
  return r * cols + c;
}

int symmetryCount(int cols, int rows) { return cols == rows ? 8 : 4; }

std::vector<cv::Point2f> reorder(const Detection& d, int sym) {
  std::vector<cv::Point2f> out(d.corners.size());
  for (int id = 0; id < static_cast<int>(out.size()); ++id)
    out[id] = d.corners[symmetricIndex(id, d.cols, d.rows, sym)];
  return out;
}

// Paints over a board and its margin (2.5 squares beyond the outer corners); `corners` in the
// coordinates of `image`.
void paintOver(const std::vector<cv::Point2f>& corners, int cols, int rows, bool dark_fill, cv::Mat* image) {
  const double spacing = meanSpacing(corners, cols, rows);
  const cv::Point2f c = centroid(corners);
  std::vector<cv::Point2f> hull;
  cv::convexHull(corners, hull);
  std::vector<cv::Point> grown;
  for (const cv::Point2f& p : hull) {
    const cv::Point2f dir = p - c;
    const float len = std::max(1e-3f, static_cast<float>(cv::norm(dir)));
    grown.emplace_back(p + dir * static_cast<float>(2.5 * spacing / len));
  }
  const double fill = dark_fill ? 0.0 : cv::mean(*image)[0];
  cv::fillConvexPoly(*image, grown, cv::Scalar(fill));
}

// Searches one region repeatedly: each found board is painted over before the next search.
void detectInRegion(const cv::Mat& image, cv::Rect roi, const std::vector<cv::Size>& sizes, bool dark_fill,
                    std::vector<Detection>* out) {
  roi &= cv::Rect(0, 0, image.cols, image.rows);
  if (roi.width < 16 || roi.height < 16) return;
  cv::Mat patch = image(roi).clone();
  const int flags = cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE | cv::CALIB_CB_ACCURACY;
  for (int attempt = 0; attempt < 6; ++attempt) {
    bool found_any = false;
    for (const cv::Size& size : sizes) {
      std::vector<cv::Point2f> corners;
      if (!cv::findChessboardCornersSB(patch, size, corners, flags)) continue;
      Detection d{size.width, size.height, corners};
      for (cv::Point2f& p : d.corners) p += cv::Point2f(static_cast<float>(roi.x), static_cast<float>(roi.y));
      paintOver(corners, size.width, size.height, dark_fill, &patch);
      out->push_back(d);
      found_any = true;
    }
    if (!found_any) break;
  }
}

std::vector<cv::Rect> candidateRegions(const cv::Mat& image, bool is_difference, const BoardLayout& layout) {
  std::vector<cv::Rect> regions;
  if (layout.has_camera) {
    for (size_t i = 0; i < layout.boards.size(); ++i) {
      std::vector<cv::Point2f> px;
      if (!layout.predictCorners(i, &px)) continue;
      const double spacing = meanSpacing(px, layout.boards[i].cols, layout.boards[i].rows);
      const cv::Rect box = cv::boundingRect(px);
      const int grow = static_cast<int>(3.0 * spacing + 0.15 * std::max(box.width, box.height) + 10);
      regions.emplace_back(box.x - grow, box.y - grow, box.width + 2 * grow, box.height + 2 * grow);
    }
  } else if (is_difference) {
    // Connected bright regions of the difference image, each board with its margin.
    cv::Mat mask, labels, stats, centroids;
    cv::threshold(image, mask, 0, 255, cv::THRESH_BINARY | cv::THRESH_OTSU);
    cv::dilate(mask, mask, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(9, 9)));
    const int n = cv::connectedComponentsWithStats(mask, labels, stats, centroids);
    for (int i = 1; i < n; ++i) {
      if (stats.at<int>(i, cv::CC_STAT_AREA) < 400) continue;
      const cv::Rect box(stats.at<int>(i, cv::CC_STAT_LEFT), stats.at<int>(i, cv::CC_STAT_TOP),
                         stats.at<int>(i, cv::CC_STAT_WIDTH), stats.at<int>(i, cv::CC_STAT_HEIGHT));
      regions.emplace_back(box.x - 10, box.y - 10, box.width + 20, box.height + 20);
    }
  }
  if (regions.empty()) regions.emplace_back(0, 0, image.cols, image.rows);
  return regions;
}

// Drops repeated detections of one board (overlapping regions).
std::vector<Detection> unique(const std::vector<Detection>& all) {
  std::vector<Detection> out;
  for (const Detection& d : all) {
    const double spacing = meanSpacing(d.corners, d.cols, d.rows);
    bool seen = false;
    for (const Detection& o : out)
      if (o.cols == d.cols && o.rows == d.rows &&
          cv::norm(centroid(o.corners) - centroid(d.corners)) < spacing)
        seen = true;
    if (!seen) out.push_back(d);
  }
  return out;
}

// Identifies detections: returns per layout board the ordered corners (empty when not found).
std::vector<std::vector<cv::Point2f>> identify(const std::vector<Detection>& detections,
                                               const BoardLayout& layout, std::vector<std::string>* notes) {
  std::vector<std::vector<cv::Point2f>> out(layout.boards.size());
  if (!layout.has_camera) {
    // Plain board: the documented image-position rule.
    for (const Detection& d : detections) {
      const VirtualBoard& b = layout.boards[0];
      if (d.cols != b.cols || d.rows != b.rows) continue;
      double best = 1e30;
      for (int sym = 0; sym < symmetryCount(d.cols, d.rows); ++sym) {
        const std::vector<cv::Point2f> c = reorder(d, sym);
        const cv::Point2f along_row = c[1] - c[0], along_col = c[d.cols] - c[0];
        // Corner 0 nearest the origin; first row direction more horizontal than the column one.
        const double key = c[0].x + c[0].y + (std::abs(along_row.x) >= std::abs(along_col.x) ? 0.0 : 1e6);
        if (key < best) best = key, out[0] = c;
      }
      break;
    }
    return out;
  }
  struct Match {
    double cost;
    size_t board, detection;
    int sym;
  };
  std::vector<Match> matches;
  std::vector<double> gates(layout.boards.size(), 0.0);
  for (size_t i = 0; i < layout.boards.size(); ++i) {
    std::vector<cv::Point2f> pred;
    if (!layout.predictCorners(i, &pred)) continue;
    const cv::Rect box = cv::boundingRect(pred);
    gates[i] = 0.5 * std::hypot(box.width, box.height);
    for (size_t k = 0; k < detections.size(); ++k) {
      const Detection& d = detections[k];
      if (d.cols != layout.boards[i].cols || d.rows != layout.boards[i].rows) continue;
      for (int sym = 0; sym < symmetryCount(d.cols, d.rows); ++sym) {
        const std::vector<cv::Point2f> c = reorder(d, sym);
        double sq = 0;
        for (size_t id = 0; id < c.size(); ++id) sq += std::pow(cv::norm(c[id] - pred[id]), 2);
        matches.push_back({std::sqrt(sq / c.size()), i, k, sym});
      }
    }
  }
  // Greedy assignment by increasing cost: boards lie far apart compared with the model's error.
  std::sort(matches.begin(), matches.end(), [](const Match& a, const Match& b) { return a.cost < b.cost; });
  std::vector<char> board_done(layout.boards.size(), 0), det_done(detections.size(), 0);
  for (const Match& m : matches) {
    if (board_done[m.board] || det_done[m.detection]) continue;
    if (m.cost > gates[m.board]) {
      std::ostringstream s;
      s << "board " << layout.boards[m.board].virtual_id << ": nearest detection is " << m.cost
        << " px RMS from the prediction (gate " << gates[m.board] << " px); not assigned";
      notes->push_back(s.str());
      continue;
    }
    board_done[m.board] = det_done[m.detection] = 1;
    out[m.board] = reorder(detections[m.detection], m.sym);
  }
  return out;
}

// Edge blur (px, standard deviation of a Gaussian edge profile, pixel area included) of a taught
// board: across the middle of every edge between two neighbouring corners, the profile's
// derivative is measured along the edge's normal and its spread taken (second moment, within
// +-3 px); the median over the edges. 0 when nothing could be measured.
double measureEdgeBlur(const cv::Mat& gray, const std::vector<cv::Point2f>& corners, int cols, int rows) {
  std::vector<double> sigmas;
  const int half = 12;            // samples each side, a quarter pixel apart
  const float step = 0.25f;
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      for (int dir = 0; dir < 2; ++dir) {
        const int nc = c + (dir == 0), nr = r + (dir == 1);
        if (nc >= cols || nr >= rows) continue;
        const cv::Point2f a = corners[r * cols + c], b = corners[nr * cols + nc];
        const cv::Point2f m = 0.5f * (a + b), e = b - a;
        const float len = static_cast<float>(cv::norm(e));
        if (len < 8) continue;
        const cv::Point2f n(-e.y / len, e.x / len);
        std::vector<double> profile;
        bool inside = true;
        for (int k = -half; k <= half && inside; ++k) {
          const cv::Point2f p = m + n * (k * step);
          if (p.x < 1 || p.y < 1 || p.x > gray.cols - 2 || p.y > gray.rows - 2) inside = false;
          else {
            cv::Mat patch;
            cv::getRectSubPix(gray, cv::Size(1, 1), p, patch, CV_32F);
            profile.push_back(patch.at<float>(0, 0));
          }
        }
        if (!inside) continue;
        const double sign = profile.back() > profile.front() ? 1.0 : -1.0;
        double w = 0, w1 = 0, w2 = 0;
        for (size_t k = 1; k < profile.size(); ++k) {
          const double d = std::max(0.0, sign * (profile[k] - profile[k - 1]));
          const double t = (static_cast<double>(k) - 0.5 - half) * step;
          w += d, w1 += d * t, w2 += d * t * t;
        }
        if (w <= 10) continue;
        const double mean = w1 / w;
        // Bilinear sampling along a line adds about a third of a pixel of spread; take it out.
        const double var = w2 / w - mean * mean - 0.1;
        if (var > 0) sigmas.push_back(std::sqrt(var));
      }
    }
  }
  if (sigmas.size() < 4) return 0.0;
  std::nth_element(sigmas.begin(), sigmas.begin() + sigmas.size() / 2, sigmas.end());
  return sigmas[sigmas.size() / 2];
}

// The board's polarity (which diagonal pair of a corner is bright) and its saddle contrast in the
// light-on frames (scene included), from the corners found there.
void learnPolarityAndContrast(const VirtualBoard& vb, const std::vector<std::vector<cv::Point2f>>& per_frame,
                              const std::vector<cv::Mat>& light_on, BoardPrior* prior) {
  const int n = vb.cornerCount();
  const int frames = static_cast<int>(per_frame.size());
  const int outer_ids[4] = {0, vb.cols - 1, n - 1, n - vb.cols};
  const double spacing = prior->square_px;
  const int box = std::max(1, static_cast<int>(std::lround(0.12 * spacing)));
  double vote = 0;
  std::vector<float> plus, minus;
  for (int f = 0; f < frames; ++f) {
    const tracker::BoxSampler sampler(light_on[f], cv::Rect(0, 0, light_on[f].cols, light_on[f].rows), box);
    const cv::Matx33d h =
        tracker::homographyFromOuter(*prior, {per_frame[f][outer_ids[0]], per_frame[f][outer_ids[1]],
                                              per_frame[f][outer_ids[2]], per_frame[f][outer_ids[3]]});
    for (int id = 0; id < n; ++id) {
      const cv::Point2f g = tracker::gridPoint(id, vb.cols);
      cv::Point2f ac, ar;
      tracker::gridAxes(h, g.x, g.y, &ac, &ar);
      const int parity = ((id % vb.cols + id / vb.cols) & 1) == 0 ? 1 : -1;
      const float cp = tracker::saddleContrast(sampler, per_frame[f][id], ac, ar, parity);
      const float cm = tracker::saddleContrast(sampler, per_frame[f][id], ac, ar, -parity);
      if (!std::isfinite(cp) || !std::isfinite(cm)) continue;
      plus.push_back(cp);
      minus.push_back(cm);
      vote += (cp > cm) ? 1 : -1;
    }
  }
  prior->sign = vote >= 0 ? 1 : -1;
  std::vector<float>& good = prior->sign > 0 ? plus : minus;
  if (!good.empty()) {
    std::nth_element(good.begin(), good.begin() + good.size() / 2, good.end());
    prior->contrast = std::max(1.0f, good[good.size() / 2]);
  } else {
    prior->contrast = 1.0;
  }
}

void learnBoard(const VirtualBoard& vb, const std::vector<std::vector<cv::Point2f>>& per_frame,
                const std::vector<cv::Mat>& light_on, BoardPrior* prior) {
  prior->board_id = vb.virtual_id;
  prior->cols = vb.cols;
  prior->rows = vb.rows;
  const int n = vb.cornerCount();
  const int frames = static_cast<int>(per_frame.size());
  cv::Mat data(frames, 8, CV_64F);
  std::vector<cv::Point2f> offsets(n, cv::Point2f(0, 0));
  double spacing = 0;
  const int outer_ids[4] = {0, vb.cols - 1, n - 1, n - vb.cols};
  for (int f = 0; f < frames; ++f) {
    std::vector<cv::Point2f> outer;
    for (int i = 0; i < 4; ++i) {
      outer.push_back(per_frame[f][outer_ids[i]]);
      data.at<double>(f, 2 * i) = outer[i].x;
      data.at<double>(f, 2 * i + 1) = outer[i].y;
    }
    const cv::Matx33d h = tracker::homographyFromOuter(*prior, outer);
    for (int id = 0; id < n; ++id) {
      const cv::Point2f g = tracker::gridPoint(id, vb.cols);
      offsets[id] += (per_frame[f][id] - tracker::applyHomography(h, g.x, g.y)) * (1.0f / frames);
    }
    spacing += meanSpacing(per_frame[f], vb.cols, vb.rows) / frames;
  }
  cv::reduce(data, prior->outer_mean, 0, cv::REDUCE_AVG, CV_64F);
  prior->outer_modes = cv::Mat(0, 8, CV_64F);
  prior->outer_sigma = cv::Mat(1, 0, CV_64F);
  if (frames >= 2) {
    const cv::PCA pca(data, cv::Mat(), cv::PCA::DATA_AS_ROW, std::min(frames - 1, 4));
    for (int m = 0; m < pca.eigenvectors.rows; ++m) {
      const double var = pca.eigenvalues.at<double>(m);
      if (!(var > 1e-12)) continue;
      prior->outer_modes.push_back(pca.eigenvectors.row(m));
      cv::hconcat(prior->outer_sigma, cv::Mat(1, 1, CV_64F, cv::Scalar(std::sqrt(var))), prior->outer_sigma);
    }
  }
  prior->offsets = offsets;
  prior->square_px = spacing;
  std::vector<double> blurs;
  for (int f = 0; f < frames; ++f) {
    const double blur = measureEdgeBlur(light_on[f], per_frame[f], vb.cols, vb.rows);
    if (blur > 0) blurs.push_back(blur);
  }
  if (!blurs.empty()) {
    std::nth_element(blurs.begin(), blurs.begin() + blurs.size() / 2, blurs.end());
    prior->edge_blur_px = blurs[blurs.size() / 2];
  }

  learnPolarityAndContrast(vb, per_frame, light_on, prior);
}

// A region around a board also holds parts of its neighbours, which can keep the detector from
// the board itself: each board still missing is searched again in its region, and in tighter
// ones, with every board identified so far painted over. Returns whether anything new was found (added to *all).
bool searchAgainForMissing(const cv::Mat& search, const std::vector<cv::Rect>& regions,
                           const std::vector<cv::Size>& sizes, bool difference, const BoardLayout& layout,
                           const std::vector<std::vector<cv::Point2f>>& identified, std::vector<Detection>* all) {
  if (!layout.has_camera || regions.size() != layout.boards.size() || all->empty()) return false;
  const auto missing = std::count_if(identified.begin(), identified.end(), [](const auto& c) { return c.empty(); });
  if (missing == 0) return false;
  cv::Mat painted = search.clone();
  for (size_t i = 0; i < identified.size(); ++i)
    if (!identified[i].empty())
      paintOver(identified[i], layout.boards[i].cols, layout.boards[i].rows, difference, &painted);
  const size_t before = all->size();
  for (size_t i = 0; i < identified.size(); ++i) {
    // The region itself, then tighter ones about its centre (the board fills about half of it):
    // a region that still holds the edge of a neighbour may keep the detector off the board.
    for (const double scale : {1.0, 0.8, 0.65}) {
      if (!identified[i].empty()) break;
      const cv::Rect& r = regions[i];
      const cv::Size size(static_cast<int>(r.width * scale), static_cast<int>(r.height * scale));
      const size_t found = all->size();
      detectInRegion(painted, cv::Rect(r.x + (r.width - size.width) / 2, r.y + (r.height - size.height) / 2,
                                       size.width, size.height),
                     sizes, difference, all);
      if (all->size() > found) break;
    }
  }
  return all->size() > before;
}

// Every board of the layout found in `search` (ordered corners by layout index; empty when not
// found); *detected counts the distinct chessboards detected.
std::vector<std::vector<cv::Point2f>> detectAndIdentify(const cv::Mat& search, bool difference,
                                                        const BoardLayout& layout, const std::vector<cv::Size>& sizes,
                                                        size_t* detected, std::vector<std::string>* notes) {
  std::vector<Detection> all;
  const std::vector<cv::Rect> regions = candidateRegions(search, difference, layout);
  for (const cv::Rect& roi : regions) detectInRegion(search, roi, sizes, difference, &all);
  std::vector<Detection> detections = unique(all);
  std::vector<std::string> first_notes;
  std::vector<std::vector<cv::Point2f>> identified = identify(detections, layout, &first_notes);
  if (searchAgainForMissing(search, regions, sizes, difference, layout, identified, &all)) {
    detections = unique(all);
    identified = identify(detections, layout, notes);
  } else {
    notes->insert(notes->end(), first_notes.begin(), first_notes.end());
  }
  *detected = detections.size();
  return identified;
}

}  // namespace

TeachResult teachCamera(const std::vector<TeachFrame>& frames, const BoardLayout& layout,
                        const std::string& camera_name, ColorOrder order) {
  if (frames.empty()) throw std::invalid_argument("teachCamera: no frames");
  if (layout.boards.empty()) throw std::invalid_argument("teachCamera: no boards in the layout");
  TeachResult result;
  std::vector<cv::Size> sizes;
  for (const VirtualBoard& b : layout.boards)
    if (std::find(sizes.begin(), sizes.end(), cv::Size(b.cols, b.rows)) == sizes.end())
      sizes.emplace_back(b.cols, b.rows);

  // per_board[i]: the ordered corners of board i in each frame where it was found.
  std::vector<std::vector<std::vector<cv::Point2f>>> per_board(layout.boards.size());
  std::vector<std::vector<cv::Mat>> on_frames(layout.boards.size());
  cv::Size image_size;
  for (size_t f = 0; f < frames.size(); ++f) {
    const cv::Mat on = toGrayImage(frames[f].light_on, order);
    if (image_size.area() == 0) image_size = on.size();
    if (on.size() != image_size) throw std::invalid_argument("teachCamera: frames differ in size");
    const bool difference = !frames[f].light_off.empty();
    cv::Mat search;  // a new buffer: `on` may share the caller's pixels
    if (difference) {
      const cv::Mat off = toGrayImage(frames[f].light_off, order);
      if (off.size() != on.size())
        throw std::invalid_argument("teachCamera: light-off frame differs in size");
      cv::subtract(on, off, search);  // saturates at 0: the scene cancels, the device stays
    } else {
      search = on;  // only read below
    }
    size_t detected = 0;
    std::vector<std::vector<cv::Point2f>> identified =
        detectAndIdentify(search, difference, layout, sizes, &detected, &result.notes);
    // Polish on the detection image (SB's own corners are less accurate than cornerSubPix's).
    std::vector<BoardCorners> frame_result;
    for (size_t i = 0; i < identified.size(); ++i) {
      if (identified[i].empty()) continue;
      const int window = std::min(
          5, std::max(2, static_cast<int>(std::lround(0.4 * meanSpacing(identified[i], layout.boards[i].cols,
                                                                        layout.boards[i].rows)))));
      cv::cornerSubPix(search, identified[i], cv::Size(window, window), cv::Size(-1, -1),
                       cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 0.001));
      per_board[i].push_back(identified[i]);
      on_frames[i].push_back(on);
      BoardCorners bc;
      bc.board_id = layout.boards[i].virtual_id;
      for (size_t id = 0; id < identified[i].size(); ++id) {
        bc.corner_ids.push_back(static_cast<int>(id));
        bc.u.push_back(identified[i][id].x);
        bc.v.push_back(identified[i][id].y);
      }
      frame_result.push_back(bc);
    }
    std::ostringstream s;
    s << camera_name << " frame " << f << ": " << detected << " chessboards detected, "
      << frame_result.size() << " of " << layout.boards.size() << " boards identified";
    result.notes.push_back(s.str());
    result.detections.push_back(frame_result);
  }
  result.prior.name = camera_name;
  result.prior.width = image_size.width;
  result.prior.height = image_size.height;
  result.prior.taught_frames = static_cast<int>(frames.size());
  for (size_t i = 0; i < layout.boards.size(); ++i) {
    if (per_board[i].empty()) {
      result.notes.push_back(camera_name + ": board " + std::to_string(layout.boards[i].virtual_id) +
                             " was not found in any frame; it is left out of the prior");
      continue;
    }
    BoardPrior prior;
    learnBoard(layout.boards[i], per_board[i], on_frames[i], &prior);
    prior.device_pattern = layout.has_camera;
    result.prior.boards.push_back(prior);
  }
  if (result.prior.boards.empty()) {
    std::string why;
    for (const std::string& n : result.notes) why += "\n  " + n;
    throw std::runtime_error("teachCamera: no board found in " + camera_name + why);
  }
  return result;
}

}  // namespace embedded_calibration_stereo::core
