#include "embedded_calibration_stereo/core/calibration/bringup_check.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/imgproc.hpp>

namespace embedded_calibration_stereo::core {

namespace {

double median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const size_t mid = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + static_cast<long>(mid), values.end());
  return values[mid];
}

std::string format(const char* pattern, double a, double b = 0.0, double c = 0.0, double d = 0.0) {
  char text[512];
  std::snprintf(text, sizeof(text), pattern, a, b, c, d);
  return text;
}

// A point of a virtual board's plane given in squares of its corner grid (column, row).
Eigen::Vector3d gridPointInRig(const VirtualBoard& board, double col, double row) {
  const double y = row * board.square;
  return board.rig_from_board * Eigen::Vector3d(col * board.square, board.mirrored ? -y : y, 0.0);
}

}  // namespace

std::string BringupThresholds::validate() const {
  if (!(max_stamp_offset_s >= 0.0)) return "max_stamp_offset_s must be >= 0";
  if (!(min_paired_fraction >= 0.0 && min_paired_fraction <= 1.0)) return "min_paired_fraction must be in [0, 1]";
  if (!(min_board_contrast > 0.0)) return "min_board_contrast must be > 0";
  if (!(min_board_seen >= 0.0 && min_board_seen <= 1.0)) return "min_board_seen must be in [0, 1]";
  if (!(max_clipped_fraction >= 0.0 && max_clipped_fraction <= 1.0)) return "max_clipped_fraction must be in [0, 1]";
  if (!(full_fraction > 0.5 && full_fraction < 1.0)) return "full_fraction must be in (0.5, 1)";
  return "";
}

StampPairing pairStereoStamps(const std::vector<double>& left, const std::vector<double>& right) {
  StampPairing out;
  out.left_frames = static_cast<int>(left.size());
  out.right_frames = static_cast<int>(right.size());
  std::vector<double> steps;
  for (size_t i = 1; i < left.size(); ++i) steps.push_back(left[i] - left[i - 1]);
  out.frame_period_s = median(steps);
  if (left.empty() || right.empty()) return out;
  // Without a period (one frame) any offset pairs; with one, half of it is the limit.
  const double limit = out.frame_period_s > 0.0 ? 0.5 * out.frame_period_s : 1e300;
  std::vector<double> offsets;
  size_t j = 0;
  int last_used = -1;
  for (size_t i = 0; i < left.size(); ++i) {
    while (j + 1 < right.size() && std::abs(right[j + 1] - left[i]) <= std::abs(right[j] - left[i])) ++j;
    const double offset = right[j] - left[i];
    if (std::abs(offset) >= limit || static_cast<int>(j) <= last_used) continue;
    out.pairs.emplace_back(static_cast<int>(i), static_cast<int>(j));
    last_used = static_cast<int>(j);
    offsets.push_back(offset);
    out.max_abs_offset_s = std::max(out.max_abs_offset_s, std::abs(offset));
  }
  out.median_offset_s = median(offsets);
  return out;
}

std::vector<BoardRegion> projectBoardRegions(const CalibrationDevice& device, const StereoRig& rig,
                                             bool right_camera) {
  const PinholeCamera& camera = right_camera ? rig.right : rig.left;
  const Eigen::Isometry3d camera_from_rig = right_camera ? rig.right_from_left : Eigen::Isometry3d::Identity();
  const auto project = [&](const VirtualBoard& b, double col, double row, cv::Point2f* pixel) {
    Eigen::Vector2d p;
    if (!camera.project(camera_from_rig * gridPointInRig(b, col, row), &p)) return false;
    *pixel = cv::Point2f(static_cast<float>(p.x()), static_cast<float>(p.y()));
    return true;
  };
  std::vector<BoardRegion> regions;
  for (const VirtualBoard& b : device.virtualBoards()) {
    BoardRegion region;
    region.board_id = b.virtual_id;
    int inside = 0;
    cv::Point2f p;
    for (int id = 0; id < b.cornerCount(); ++id) {
      const bool in = project(b, id % b.cols, id / b.cols, &p) && p.x >= 0 && p.y >= 0 && p.x <= camera.width - 1 &&
                      p.y <= camera.height - 1;
      inside += in ? 1 : 0;
    }
    region.inside_fraction = static_cast<double>(inside) / std::max(1, b.cornerCount());
    // The squares reach one square beyond the outer inner corners: -1 .. cols (rows).
    const double c0 = -1.0, c1 = b.cols, r0 = -1.0, r1 = b.rows;
    bool outline_ok = true;
    for (const auto& g : {std::make_pair(c0, r0), std::make_pair(c1, r0), std::make_pair(c1, r1), std::make_pair(c0, r1)}) {
      outline_ok = project(b, g.first, g.second, &p) && outline_ok;
      region.outline.push_back(p);
    }
    for (const auto& g : {std::make_pair(c0 - 2, r0 - 2), std::make_pair(c1 + 2, r0 - 2),
                          std::make_pair(c1 + 2, r1 + 2), std::make_pair(c0 - 2, r1 + 2)}) {
      outline_ok = project(b, g.first, g.second, &p) && outline_ok;
      region.surround.push_back(p);
    }
    if (!outline_ok) region.outline.clear(), region.surround.clear();
    for (double r = r0; r + 2.0 <= r1; r += 2.0) {
      for (double c = c0; c + 2.0 <= c1; c += 2.0) {
        std::vector<cv::Point2f> block(4);
        if (project(b, c, r, &block[0]) && project(b, c + 2, r, &block[1]) && project(b, c + 2, r + 2, &block[2]) &&
            project(b, c, r + 2, &block[3]))
          region.blocks.push_back(block);
      }
    }
    regions.push_back(region);
  }
  return regions;
}

cv::Mat boardOutlineMask(const std::vector<BoardRegion>& regions, cv::Size size, bool surround) {
  cv::Mat mask = cv::Mat::zeros(size, CV_8UC1);
  for (const BoardRegion& region : regions) {
    const std::vector<cv::Point2f>& corners = surround ? region.surround : region.outline;
    if (corners.size() != 4) continue;
    std::vector<cv::Point> polygon;
    for (const cv::Point2f& p : corners) polygon.emplace_back(cvRound(p.x), cvRound(p.y));
    cv::fillConvexPoly(mask, polygon, cv::Scalar(255));
  }
  return mask;
}

ImageLevels measureImage(const cv::Mat& grey, const cv::Mat& mask, const cv::Mat& surround) {
  CV_Assert(grey.type() == CV_8UC1 && mask.type() == CV_8UC1 && grey.size() == mask.size());
  CV_Assert(surround.type() == CV_8UC1 && surround.size() == mask.size());
  ImageLevels out;
  const int inside = cv::countNonZero(mask);
  if (inside == 0) return out;
  out.device_level = cv::mean(grey, mask)[0];
  cv::Mat clipped = (grey == 0) | (grey == 255);
  clipped &= mask;
  out.clipped_fraction = static_cast<double>(cv::countNonZero(clipped)) / inside;
  if (cv::countNonZero(surround) < surround.rows * surround.cols) out.scene_level = cv::mean(grey, ~surround)[0];
  return out;
}

std::vector<double> withoutExposureChanges(const std::vector<double>& device_level,
                                           const std::vector<double>& scene_level) {
  CV_Assert(device_level.size() == scene_level.size());
  const double reference = median(scene_level);
  std::vector<double> out;
  for (size_t k = 0; k < device_level.size(); ++k)
    out.push_back(scene_level[k] > 0.0 ? device_level[k] * reference / scene_level[k] : device_level[k]);
  return out;
}

namespace {

struct LevelSplit {
  double low = 0.0, high = 0.0;
};

// The two levels a camera's frames take (unlit, lit): the split of the sorted levels with the
// largest between-class variance (Otsu's), each side's median.
LevelSplit splitLevels(std::vector<double> levels) {
  LevelSplit out;
  if (levels.size() < 2) return out;
  std::sort(levels.begin(), levels.end());
  const size_t n = levels.size();
  std::vector<double> prefix(n + 1, 0.0);
  for (size_t i = 0; i < n; ++i) prefix[i + 1] = prefix[i] + levels[i];
  size_t best_split = 1;
  double best = -1.0;
  for (size_t k = 1; k < n; ++k) {
    const double m0 = prefix[k] / k, m1 = (prefix[n] - prefix[k]) / (n - k);
    const double score = static_cast<double>(k) * (n - k) * (m1 - m0) * (m1 - m0);
    if (score > best) best = score, best_split = k;
  }
  out.low = levels[best_split / 2];
  out.high = levels[best_split + (n - best_split) / 2];
  return out;
}

// The smallest lit-minus-unlit step taken as the light; below it the levels are the scene.
constexpr double kMinStep = 8.0;

std::vector<double> fractions(const std::vector<double>& levels, const LevelSplit& split) {
  std::vector<double> out;
  const double step = split.high - split.low;
  for (double level : levels) out.push_back(step > 0.0 ? (level - split.low) / step : 0.0);
  return out;
}

// First frames from which each camera's fraction stays past one half, in either direction.
std::vector<std::pair<int, bool>> crossings(const std::vector<double>& f) {
  std::vector<std::pair<int, bool>> out;
  bool on = !f.empty() && f[0] >= 0.5;
  for (size_t k = 1; k < f.size(); ++k) {
    if ((f[k] >= 0.5) == on) continue;
    on = !on;
    out.emplace_back(static_cast<int>(k), on);
  }
  return out;
}

// Whether a camera's frame k shows what the frames next to it show (the median of f over
// [from, to), clipped to the frames there are), within `tolerance` of the light's step: the light
// is not changing between them.
bool steady(const std::vector<double>& f, int k, int from, int to, double tolerance) {
  std::vector<double> around;
  for (int j = std::max(0, from); j < std::min(static_cast<int>(f.size()), to); ++j)
    if (j != k) around.push_back(f[j]);
  return around.empty() || std::abs(f[k] - median(around)) <= tolerance;
}

bool steadyBoth(const LightTiming& t, int k, int from, int to, double tolerance) {
  return steady(t.left_fraction, k, from, to, tolerance) && steady(t.right_fraction, k, from, to, tolerance);
}

// The driver's command of a switch: the change of its mode to the new state nearest the image's
// change, after the previous switch was done (`after`) and not after this one is.
void findModeTimes(const std::vector<FrameMode>& modes, int after, LightSwitch* s) {
  int best = -1;
  for (int k = std::max(1, after + 1); k <= s->done_frame && k < static_cast<int>(modes.size()); ++k) {
    if (!modes[k].known || !modes[k - 1].known || modes[k].light_on != s->rise || modes[k - 1].light_on == s->rise)
      continue;
    if (best < 0 || std::abs(k - s->change_frame) < std::abs(best - s->change_frame)) best = k;
  }
  if (best < 0) return;
  s->command_frame = best;
  for (int k = best; k < static_cast<int>(modes.size()) && modes[k].light_on == s->rise; ++k) {
    if (modes[k].settled) {
      s->settled_frame = k;
      break;
    }
  }
}

LightSwitch describeSwitch(const LightTiming& t, int left_k, int right_k, bool rise, double full,
                           const std::vector<FrameMode>& modes, int after) {
  LightSwitch s;
  s.rise = rise;
  s.left_middle = left_k;
  s.right_middle = right_k;
  const int n = static_cast<int>(t.left_fraction.size());
  // The change starts after the last frame that equals the frames before it, and is done at the
  // first frame that equals the frames after it (a scene or an exposure drifting slowly is no
  // change).
  const double tolerance = 1.0 - full;
  int k = std::min(left_k, right_k);
  while (k > 0 && !steadyBoth(t, k - 1, k - 4, k - 1, tolerance)) --k;
  s.change_frame = k;
  k = std::max(left_k, right_k);
  while (k < n && !steadyBoth(t, k, k + 1, k + 4, tolerance)) ++k;
  s.done_frame = k;
  findModeTimes(modes, after, &s);
  return s;
}

// A settled frame must show its mode's state in both cameras and equal the settled frames of the
// same state around it (4 frames either side): otherwise the light was still changing.
bool settledFrameRight(const LightTiming& t, const std::vector<FrameMode>& modes, int k, double tolerance) {
  const bool on = modes[k].light_on;
  const double lo = std::min(t.left_fraction[k], t.right_fraction[k]);
  const double hi = std::max(t.left_fraction[k], t.right_fraction[k]);
  if (on ? lo < 0.5 : hi >= 0.5) return false;
  std::vector<double> left, right;
  int from = k, to = k + 1;  // the frames of the same state around k, at most 4 either side
  while (from > 0 && k - from < 4 && modes[from - 1].known && modes[from - 1].light_on == on) --from;
  while (to < static_cast<int>(modes.size()) && to - k <= 4 && modes[to].known && modes[to].light_on == on) ++to;
  for (int j = from; j < to; ++j) {
    if (j == k || !modes[j].settled) continue;
    left.push_back(t.left_fraction[j]);
    right.push_back(t.right_fraction[j]);
  }
  if (left.empty()) return true;
  return std::abs(t.left_fraction[k] - median(left)) <= tolerance &&
         std::abs(t.right_fraction[k] - median(right)) <= tolerance;
}

}  // namespace

LightTiming analyseLight(const std::vector<double>& left_level, const std::vector<double>& right_level,
                         const std::vector<FrameMode>& modes, const BringupThresholds& thresholds) {
  CV_Assert(left_level.size() == right_level.size() && (modes.empty() || modes.size() == left_level.size()));
  LightTiming t;
  const LevelSplit left = splitLevels(left_level), right = splitLevels(right_level);
  t.left_step = left.high - left.low;
  t.right_step = right.high - right.low;
  t.switched = t.left_step >= kMinStep && t.right_step >= kMinStep;
  if (!t.switched) return t;
  t.left_fraction = fractions(left_level, left);
  t.right_fraction = fractions(right_level, right);
  const auto left_x = crossings(t.left_fraction), right_x = crossings(t.right_fraction);
  // Each left crossing with the right one of the same direction nearest to it.
  for (const auto& lx : left_x) {
    int best = -1;
    for (const auto& rx : right_x) {
      if (rx.second == lx.second && (best < 0 || std::abs(rx.first - lx.first) < std::abs(best - lx.first)))
        best = rx.first;
    }
    if (best < 0) continue;
    const int after = t.switches.empty() ? -1 : t.switches.back().done_frame;
    t.switches.push_back(describeSwitch(t, lx.first, best, lx.second, thresholds.full_fraction, modes, after));
    if (best != lx.first) ++t.split_switches;
  }
  for (int k = 0; k < static_cast<int>(modes.size()); ++k) {
    if (!modes[k].known || !modes[k].settled) continue;
    ++t.settled_frames;
    if (settledFrameRight(t, modes, k, 1.0 - thresholds.full_fraction)) continue;
    ++t.settled_wrong;
    t.settled_wrong_frames.push_back(k);
  }
  return t;
}

namespace {

// Lit white minus lit black inside one block: the spread between its 10th and 90th percentile.
double blockContrast(const cv::Mat& difference, const std::vector<cv::Point2f>& block) {
  std::vector<cv::Point> polygon;
  for (const cv::Point2f& p : block) polygon.emplace_back(cvRound(p.x), cvRound(p.y));
  const cv::Rect box = cv::boundingRect(polygon);
  cv::Mat mask = cv::Mat::zeros(box.size(), CV_8UC1);
  for (cv::Point& p : polygon) p -= box.tl();
  cv::fillConvexPoly(mask, polygon, cv::Scalar(255));
  std::vector<double> values;
  const cv::Mat roi = difference(box);
  for (int y = 0; y < box.height; ++y)
    for (int x = 0; x < box.width; ++x)
      if (mask.at<uchar>(y, x)) values.push_back(roi.at<float>(y, x));
  if (values.size() < 10) return 0.0;
  const auto at = [&](double q) {
    const auto it = values.begin() + static_cast<long>(q * (values.size() - 1));
    std::nth_element(values.begin(), it, values.end());
    return *it;
  };
  return at(0.9) - at(0.1);
}

}  // namespace

std::vector<BoardVisibility> measureBoards(const cv::Mat& lit_minus_unlit, const std::vector<BoardRegion>& regions,
                                           const BringupThresholds& thresholds) {
  CV_Assert(lit_minus_unlit.type() == CV_32FC1);
  const cv::Rect image(0, 0, lit_minus_unlit.cols, lit_minus_unlit.rows);
  std::vector<BoardVisibility> out;
  for (const BoardRegion& region : regions) {
    BoardVisibility v;
    v.board_id = region.board_id;
    v.inside_fraction = region.inside_fraction;
    std::vector<double> contrasts;
    for (const auto& block : region.blocks) {
      std::vector<cv::Point> polygon;
      for (const cv::Point2f& p : block) polygon.emplace_back(cvRound(p.x), cvRound(p.y));
      const cv::Rect box = cv::boundingRect(polygon);
      if ((box & image) != box) continue;  // a block past the image edge says nothing
      contrasts.push_back(blockContrast(lit_minus_unlit, block));
    }
    const auto seen = std::count_if(contrasts.begin(), contrasts.end(),
                                    [&](double c) { return c >= thresholds.min_board_contrast; });
    v.contrast = median(contrasts);
    v.seen_fraction = contrasts.empty() ? 0.0 : static_cast<double>(seen) / contrasts.size();
    out.push_back(v);
  }
  return out;
}

namespace {

void judgeStamps(const BringupMeasurements& m, const BringupThresholds& th, std::vector<std::string>* reasons) {
  const StampPairing& s = m.stamps;
  if (s.left_frames == 0) return;  // no stamps measured (the tool refuses a bag without images)
  const double paired = s.left_frames > 0 ? static_cast<double>(s.pairs.size()) / s.left_frames : 0.0;
  if (paired < th.min_paired_fraction)
    reasons->push_back(format("only %.0f %% of the left images have a right image within half a frame "
                              "(%.0f of %.0f): frames are dropped or the cameras do not run together",
                              100.0 * paired, static_cast<double>(s.pairs.size()), s.left_frames));
  if (!s.pairs.empty() && s.max_abs_offset_s > th.max_stamp_offset_s)
    reasons->push_back(format("the right image's stamp is %.1f ms from the left's (median; at most %.1f ms, "
                              "allowed %.1f ms): trigger both cameras together, or make their driver stamp "
                              "a stereo frame once",
                              1e3 * s.median_offset_s, 1e3 * s.max_abs_offset_s, 1e3 * th.max_stamp_offset_s));
}

// The largest lags over the switches of one direction, in frames from the command: to the
// image's first change, to the light fully in its state, to the first settled frame.
struct Lags {
  int to_change = -1, to_done = -1, to_settled = -1;
};

Lags lags(const LightTiming& t, bool rise) {
  Lags out;
  for (const LightSwitch& s : t.switches) {
    if (s.rise != rise || s.command_frame < 0) continue;
    out.to_change = std::max(out.to_change, s.change_frame - s.command_frame);
    out.to_done = std::max(out.to_done, s.done_frame - s.command_frame);
    if (s.settled_frame >= 0) out.to_settled = std::max(out.to_settled, s.settled_frame - s.command_frame);
  }
  return out;
}

void judgeLight(const BringupMeasurements& m, double tolerance, std::vector<std::string>* reasons) {
  const LightTiming& t = m.light;
  if (!t.switched) {
    reasons->push_back(format("the light never switched: the boards' brightness steps by %.1f (left) and %.1f "
                              "(right) grey levels, at least 8 needed; record a light burst (docs/bringup.md)",
                              t.left_step, t.right_step));
    return;
  }
  if (m.lit_frames == 0)
    reasons->push_back("no frame shows the light fully on in both cameras: the light is held on too briefly");
  if (t.split_switches > 0)
    reasons->push_back(format("the cameras see the light switch in different stereo frames (%.0f of %.0f "
                              "switches): the left and right images of a pair were not exposed together",
                              t.split_switches, static_cast<double>(t.switches.size())));
  if (t.settled_wrong == 0) return;
  const Lags on = lags(t, true), off = lags(t, false);
  if (on.to_done <= on.to_settled && off.to_done <= off.to_settled) {
    // The light is in time: what moves the settled frames is the exposure or the scene.
    reasons->push_back(format("%.0f of %.0f frames the driver marks settled differ from the settled frames around "
                              "them by more than %.0f %% of the light's step (first: stereo frame %.0f), though the "
                              "light is fully on (off) before frames count as settled: the scene or the exposure "
                              "changed (keep the head and the scene still; clipped boards do not follow the exposure)",
                              t.settled_wrong, t.settled_frames, 100.0 * tolerance, t.settled_wrong_frames.front()));
    return;
  }
  reasons->push_back(format("%.0f of %.0f frames the driver marks settled show the light still changing: the "
                            "light starts to change %.0f frames after its command and is fully on %.0f frames "
                            "after it,",
                            t.settled_wrong, t.settled_frames, on.to_change, on.to_done) +
                     format(" but frames count as settled from %.0f frames after it (off: changes after %.0f, "
                            "fully off after %.0f, settled after %.0f);",
                            on.to_settled, off.to_change, off.to_done, off.to_settled) +
                     format(" make the light faster or raise the driver's settle_frames to %.0f",
                            std::max(on.to_done, off.to_done)));
}

void judgeBoards(const BringupMeasurements& m, const BringupThresholds& th, std::vector<std::string>* reasons) {
  const char* names[2] = {"left", "right"};
  for (int cam = 0; cam < 2; ++cam) {
    for (const BoardVisibility& b : m.boards[cam]) {
      std::string what;
      if (b.inside_fraction < 1.0)
        what = format("%.0f %% of its corners fall inside the image by the device description", 100.0 * b.inside_fraction);
      else if (b.contrast < th.min_board_contrast)
        what = format("contrast %.1f grey levels (at least %.0f needed): covered, unlit or out of focus", b.contrast,
                      th.min_board_contrast);
      else if (b.seen_fraction < th.min_board_seen)
        what = format("only %.0f %% of it shows the pattern (contrast %.1f grey levels where seen): partly covered",
                      100.0 * b.seen_fraction, b.contrast);
      if (!what.empty())
        reasons->push_back("board " + std::to_string(b.board_id) + " in the " + names[cam] + " camera: " + what);
    }
  }
}

void judgeClipping(const BringupMeasurements& m, const BringupThresholds& th, std::vector<std::string>* reasons) {
  const char* names[2] = {"left", "right"};
  for (int cam = 0; cam < 2; ++cam) {
    if (m.clipped_fraction[cam] <= th.max_clipped_fraction) continue;
    reasons->push_back(format("%.1f %% of the boards' pixels are clipped (0 or full scale) in the lit frames of the ",
                              100.0 * m.clipped_fraction[cam]) +
                       names[cam] +
                       format(" camera (%.0f of %.0f frames above %.1f %%): lower the exposure, gain or light",
                              m.clipped_frames[cam], m.lit_frames, 100.0 * th.max_clipped_fraction));
  }
}

}  // namespace

BringupVerdict judgeBringup(const BringupMeasurements& m, const BringupThresholds& thresholds) {
  BringupVerdict verdict;
  judgeStamps(m, thresholds, &verdict.reasons);
  judgeLight(m, 1.0 - thresholds.full_fraction, &verdict.reasons);
  if (m.light.switched && m.lit_frames > 0 && m.unlit_frames > 0) {
    judgeBoards(m, thresholds, &verdict.reasons);
    judgeClipping(m, thresholds, &verdict.reasons);
  }
  verdict.ready = verdict.reasons.empty();
  return verdict;
}

}  // namespace embedded_calibration_stereo::core
