#include "embedded_calibration_stereo/core/tracker/window_tracker.h"

#include <algorithm>
#include <map>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo::core {

std::string WindowTrackerOptions::validate() const {
  std::vector<std::string> problems;
  const std::string learner_problems = learner.validate();
  if (!learner_problems.empty()) problems.push_back("learner: " + learner_problems);
  if (!(saddle_radius_squares > 0.1 && saddle_radius_squares < 0.5))
    problems.push_back("saddle_radius_squares must be in (0.1, 0.5)");
  if (max_saddle_radius_px < 2) problems.push_back("max_saddle_radius_px must be >= 2");
  if (min_light_on_frames < 1) problems.push_back("min_light_on_frames must be >= 1");
  const std::string matching_problems = matching.validate();
  if (!matching_problems.empty()) problems.push_back("matching: " + matching_problems);
  const std::string sides_problems = scene_sides.validate();
  if (!sides_problems.empty()) problems.push_back("scene_sides: " + sides_problems);
  if (!(max_board_motion_px > 0)) problems.push_back("max_board_motion_px must be > 0");
  std::string joined;
  for (const std::string& p : problems) joined += (joined.empty() ? "" : "; ") + p;
  return joined;
}

int refineCornersBySaddleFit(const cv::Mat& image, const CameraPrior& prior, const WindowTrackerOptions& options,
                             std::vector<BoardCorners>* boards) {
  int dropped = 0;
  for (BoardCorners& b : *boards) {
    const BoardPrior* board = nullptr;
    for (const BoardPrior& candidate : prior.boards)
      if (candidate.board_id == b.board_id) board = &candidate;
    if (!board) continue;
    std::map<int, cv::Point2f> tracked;
    for (size_t i = 0; i < b.size(); ++i) tracked[b.corner_ids[i]] = cv::Point2f(b.u[i], b.v[i]);
    const std::map<int, cv::Point2f>& at = tracked;  // read by the corner tasks below: const only
    // Direction of the board line through corner `id` towards the next corner (`step` ids on).
    const auto line = [&](int id, int step, bool along_row_of_ids) -> cv::Point2f {
      const int col = id % board->cols;
      const bool next = at.count(id + step) && (!along_row_of_ids || col + 1 < board->cols);
      const bool prev = at.count(id - step) && (!along_row_of_ids || col > 0);
      if (next && prev) return 0.5f * (at.at(id + step) - at.at(id - step));
      if (next) return at.at(id + step) - at.at(id);
      if (prev) return at.at(id) - at.at(id - step);
      return cv::Point2f(0, 0);
    };
    std::vector<SaddleFit> fits(b.size());
    std::vector<char> ok(b.size(), 0);
    cv::parallel_for_(cv::Range(0, static_cast<int>(b.size())), [&](const cv::Range& range) {
      for (int i = range.start; i < range.end; ++i) {
        const int id = b.corner_ids[i];
        const cv::Point2f along_col = line(id, 1, true), along_row = line(id, board->cols, false);
        const double square = std::min(cv::norm(along_col), cv::norm(along_row));
        if (!(square > 0)) continue;
        SaddleFitOptions saddle = options.saddle;
        saddle.radius_px = std::max(
            2, std::min(options.max_saddle_radius_px, static_cast<int>(options.saddle_radius_squares * square)));
        ok[i] = fitSaddle(image, cv::Point2f(b.u[i], b.v[i]), along_col, along_row, saddle, &fits[i]);
      }
    });
    BoardCorners out;
    out.board_id = b.board_id;
    for (size_t i = 0; i < b.size(); ++i) {
      if (!ok[i]) {
        ++dropped;
        continue;
      }
      out.corner_ids.push_back(b.corner_ids[i]);
      out.u.push_back(static_cast<float>(fits[i].corner.x));
      out.v.push_back(static_cast<float>(fits[i].corner.y));
    }
    b = std::move(out);
  }
  boards->erase(std::remove_if(boards->begin(), boards->end(), [](const BoardCorners& b) { return b.size() == 0; }),
                boards->end());
  return dropped;
}

DeviceLearnerOptions windowLearnerOptions() {
  DeviceLearnerOptions options;
  options.first_pass_pairs = 2;
  options.flow_refinement_iterations = 2;
  options.flow_patch_stride = 4;
  options.flow_pair_step = 2;
  options.parallel_pairs = false;  // the head's memory: a burst's learning runs beside depth
  return options;
}

LearnedDevice learnWindowDevice(const WindowFrames& f, const DeviceLearnerOptions& options) {
  LightPairSet set(255);
  const int n = static_cast<int>(f.light_on.size());
  for (int i = 0; i < n; ++i) {
    const bool first_half = 2 * i < n;
    const bool before = (first_half && !f.light_off_before.empty()) || f.light_off_after.empty();
    // Frames apart counted from the window's ends (the gap to the light-off frames is the same
    // on both sides): only their order matters.
    const int before_count = static_cast<int>(f.light_off_before.size());
    if (before)
      for (int j = 0; j < before_count; ++j) set.add(f.light_off_before[j], f.light_on[i], i + before_count - j);
    else
      for (int j = 0; j < static_cast<int>(f.light_off_after.size()); ++j)
        set.add(f.light_off_after[j], f.light_on[i], n - i + j);
  }
  DeviceLearnerOptions learner = options;
  learner.min_pairs = 2;
  learner.max_pairs = std::max(learner.max_pairs, set.size());
  return learnDeviceImage(set.snapshot(), learner, 0);
}

WindowFrames windowEnds(const WindowFrames& frames, int per_end) {
  if (per_end < 1) throw std::invalid_argument("windowEnds: per_end must be >= 1");
  WindowFrames ends = frames;
  const int n = static_cast<int>(frames.light_on.size());
  if (n <= 2 * per_end) return ends;
  ends.light_on.assign(frames.light_on.begin(), frames.light_on.begin() + per_end);
  ends.light_on.insert(ends.light_on.end(), frames.light_on.end() - per_end, frames.light_on.end());
  return ends;
}

namespace {

// One camera's device image, grey; empty with *error set when learning fails. The tracker learns
// one camera at a time, its pairs in parallel: learning holds every pair's sample until it
// combines them, so learning both cameras at once would double the head's peak memory.
cv::Mat learnGreyDevice(const WindowFrames& frames, const DeviceLearnerOptions& options, std::string* error) {
  try {
    cv::Mat device = learnWindowDevice(frames, options).device_template.device;
    if (device.channels() == 3) cv::cvtColor(device, device, cv::COLOR_BGR2GRAY);
    return device;
  } catch (const std::exception& e) {
    *error = e.what();
    return cv::Mat();
  }
}

}  // namespace

WindowTracker::WindowTracker(const PatternPrior& prior, const TrackerOptions& tracker_options,
                             const WindowTrackerOptions& options, std::optional<StereoRig> guide)
    : tracker_(prior, tracker_options), options_(options), guide_(std::move(guide)) {
  const std::string problems = options.validate();
  if (!problems.empty()) throw ConfigError("window tracker options", problems);
}

WindowTrack WindowTracker::track(const WindowFrames& left, const WindowFrames& right, double stamp) {
  const WindowFrames* frames[2] = {&left, &right};
  for (int c = 0; c < 2; ++c) {
    if (frames[c]->light_off_before.empty() && frames[c]->light_off_after.empty())
      throw std::invalid_argument(std::string(c ? "right" : "left") + ": a window needs a light-off frame");
    if (static_cast<int>(frames[c]->light_on.size()) < options_.min_light_on_frames)
      throw std::invalid_argument(std::string(c ? "right" : "left") + ": " +
                                  std::to_string(frames[c]->light_on.size()) + " light-on frames, fewer than " +
                                  std::to_string(options_.min_light_on_frames));
  }
  WindowTrack result;
  result.observation.stamp = stamp;
  // First, as it costs far less than learning: a burst whose boards moved gives nothing.
  if (options_.check_board_motion) {
    checkBoardMotion(frames, &result);
    if (result.boards_moved) return result;
  }
  std::vector<BoardCorners> corners[2];
  int dropped[2] = {0, 0}, tracked[2] = {0, 0};
  std::string error[2];
  for (int c = 0; c < 2; ++c) result.device[c] = learnGreyDevice(*frames[c], options_.learner, &error[c]);
  cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& range) {
    for (int c = range.start; c < range.end; ++c) {
      if (!error[c].empty()) continue;
      try {
        const cv::Mat& device = result.device[c];
        corners[c] = tracker_.camera(c).trackSceneFree(device);
        for (const BoardCorners& b : corners[c]) tracked[c] += static_cast<int>(b.size());
        dropped[c] = refineCornersBySaddleFit(device, tracker_.camera(c).prior(), options_, &corners[c]);
      } catch (const std::exception& e) {
        error[c] = e.what();
      }
    }
  });
  for (int c = 0; c < 2; ++c)
    if (!error[c].empty()) throw std::invalid_argument(std::string(c ? "right: " : "left: ") + error[c]);
  result.observation.left = std::move(corners[0]);
  result.observation.right = std::move(corners[1]);
  if (options_.scene_matches && guide_) matchScene(left, right, &result);
  result.corners_tracked = tracked[0] + tracked[1];
  result.saddle_failures = dropped[0] + dropped[1];
  return result;
}

namespace {

// How far the boards moved from one tracking to another: the largest mean displacement of a
// board's corners (same board and id in both; a rig's change moves a board's corners together,
// while their noise averages out); -1 when the two share no corner.
double largestBoardShift(const std::vector<BoardCorners>& a, const std::vector<BoardCorners>& b) {
  std::map<std::pair<int, int>, cv::Point2f> first;
  for (const BoardCorners& board : a)
    for (size_t i = 0; i < board.size(); ++i)
      first[{board.board_id, board.corner_ids[i]}] = cv::Point2f(board.u[i], board.v[i]);
  double largest = -1.0;
  for (const BoardCorners& board : b) {
    cv::Point2d sum(0, 0);
    int n = 0;
    for (size_t i = 0; i < board.size(); ++i) {
      const auto it = first.find({board.board_id, board.corner_ids[i]});
      if (it == first.end()) continue;
      sum += cv::Point2d(board.u[i] - it->second.x, board.v[i] - it->second.y);
      ++n;
    }
    if (n > 0) largest = std::max(largest, cv::norm(sum) / n);
  }
  return largest;
}

}  // namespace

void WindowTracker::checkBoardMotion(const WindowFrames* frames[2], WindowTrack* result) {
  double largest = 0.0;
  for (int c = 0; c < 2; ++c) {
    const WindowFrames& f = *frames[c];
    if (f.light_off_before.empty() || f.light_off_after.empty() || f.light_on.size() < 2) return;
    // Each end of the burst against the light-off frame next to it, by copies of the tracker (the
    // checks leave its state alone).
    std::vector<BoardCorners> ends[2];
    for (int e = 0; e < 2; ++e) {
      CameraTracker tracker = tracker_.camera(c);
      tracker.reset();
      tracker.setBackground(e == 0 ? f.light_off_before.back() : f.light_off_after.front());
      ends[e] = tracker.track(e == 0 ? f.light_on.front() : f.light_on.back());
    }
    const double shift = largestBoardShift(ends[0], ends[1]);
    if (shift < 0) return;
    largest = std::max(largest, shift);
  }
  result->board_motion_checked = true;
  result->board_motion_px = largest;
  result->boards_moved = largest > options_.max_board_motion_px;
}

void WindowTracker::matchScene(const WindowFrames& left, const WindowFrames& right, WindowTrack* result) {
  // The light-off frames are stereo frames: left and right of one instant, pair by pair.
  const auto grey = [](const cv::Mat& image) {
    if (image.channels() == 1) return image;
    cv::Mat out;
    cv::cvtColor(image, out, cv::COLOR_BGR2GRAY);
    return out;
  };
  std::vector<SceneMatch> sides[2];
  int s = 0;
  for (const auto side : {&WindowFrames::light_off_before, &WindowFrames::light_off_after}) {
    for (size_t i = 0; i < std::min((left.*side).size(), (right.*side).size()); ++i) {
      if ((left.*side)[i].size() != cv::Size(guide_->left.width, guide_->left.height)) {
        result->scene_problem = "the guide calibration is for another image size; no scene correspondences";
        continue;
      }
      const std::vector<SceneMatch> m =
          matchStereoScene(grey((left.*side)[i]), grey((right.*side)[i]), *guide_, options_.matching, &scene_buffers_);
      sides[s].insert(sides[s].end(), m.begin(), m.end());
    }
    ++s;
  }
  if (options_.check_scene_sides) result->scene_sides = compareSceneSides(sides[0], sides[1], *guide_, options_.scene_sides);
  if (result->scene_sides.consistent)
    for (const std::vector<SceneMatch>& m : sides)
      result->observation.scene.insert(result->observation.scene.end(), m.begin(), m.end());
}

}  // namespace embedded_calibration_stereo::core
