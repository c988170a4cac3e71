#include "embedded_calibration_stereo/core/calibration/scene_matches.h"

#include <algorithm>
#include <cmath>
#include <opencv2/features2d.hpp>
#include <opencv2/video/tracking.hpp>
#include <stdexcept>

namespace embedded_calibration_stereo::core {

std::string SceneMatchOptions::validate() const { return problem().text(); }

ConfigProblem SceneMatchOptions::problem() const {
  if (max_features < 10) return {"max_features", "must be >= 10"};
  if (fast_threshold < 1 || fast_threshold > 255) return {"fast_threshold", "must be in [1, 255]"};
  if (grid_cols < 1) return {"grid_cols", "must be >= 1"};
  if (grid_rows < 1) return {"grid_rows", "must be >= 1"};
  if (lk_window_px < 5 || lk_window_px % 2 == 0) return {"lk_window_px", "must be odd and >= 5"};
  if (lk_levels < 0 || lk_levels > 6) return {"lk_levels", "must be in [0, 6]"};
  if (!(std::isfinite(lk_max_backward_error_px) && lk_max_backward_error_px > 0.0))
    return {"lk_max_backward_error_px", "must be > 0"};
  return {};
}

std::vector<SceneMatch> matchStereoScene(const cv::Mat& left, const cv::Mat& right, const StereoRig& rig,
                                         const SceneMatchOptions& options, SceneMatchBuffers* buffers,
                                         int* features_found) {
  const std::string problem = options.validate();
  if (!problem.empty()) throw std::invalid_argument("scene matching: " + problem);
  const cv::Size size(rig.left.width, rig.left.height);
  if (left.type() != CV_8UC1 || right.type() != CV_8UC1 || left.size() != size || right.size() != size)
    throw std::invalid_argument("scene matching: expected two 8-bit grey images of " + std::to_string(size.width) +
                                "x" + std::to_string(size.height));
  SceneMatchBuffers local;
  SceneMatchBuffers& b = buffers ? *buffers : local;

  std::vector<cv::KeyPoint> keypoints;
  cv::FAST(left, keypoints, options.fast_threshold, true);
  const int margin = options.lk_window_px / 2 + 2;
  const int cells = options.grid_cols * options.grid_rows;
  const size_t per_cell = static_cast<size_t>(std::max(1, options.max_features / cells));
  std::vector<std::vector<cv::KeyPoint>> grid(cells);
  for (const auto& k : keypoints) {
    if (k.pt.x < margin || k.pt.y < margin || k.pt.x > size.width - 1 - margin || k.pt.y > size.height - 1 - margin)
      continue;
    const int cx = std::min(options.grid_cols - 1, static_cast<int>(k.pt.x * options.grid_cols / size.width));
    const int cy = std::min(options.grid_rows - 1, static_cast<int>(k.pt.y * options.grid_rows / size.height));
    grid[cy * options.grid_cols + cx].push_back(k);
  }
  std::vector<cv::Point2f> left_points, right_points, guesses;
  for (auto& cell : grid) {
    if (cell.size() > per_cell) {
      std::nth_element(cell.begin(), cell.begin() + per_cell, cell.end(),
                       [](const cv::KeyPoint& a, const cv::KeyPoint& c) { return a.response > c.response; });
      cell.resize(per_cell);
    }
    for (const auto& k : cell) {
      left_points.push_back(k.pt);
      const Eigen::Vector2d ray = rig.left.pixelToNormalized(Eigen::Vector2d(k.pt.x, k.pt.y));
      Eigen::Vector2d guess;
      if (!rig.right.project(rig.right_from_left.linear() * ray.homogeneous(), &guess) || !rig.right.inImage(guess))
        guess = Eigen::Vector2d(k.pt.x, k.pt.y);
      right_points.emplace_back(static_cast<float>(guess.x()), static_cast<float>(guess.y()));
      guesses.push_back(right_points.back());
    }
  }
  if (features_found) *features_found = static_cast<int>(left_points.size());
  std::vector<SceneMatch> matches;
  if (left_points.empty()) return matches;

  const cv::Size window(options.lk_window_px, options.lk_window_px);
  cv::buildOpticalFlowPyramid(left, b.pyramid_left, window, options.lk_levels);
  cv::buildOpticalFlowPyramid(right, b.pyramid_right, window, options.lk_levels);
  const cv::TermCriteria criteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 10, 0.01);
  std::vector<uchar> status, status_back;
  std::vector<float> error;
  cv::calcOpticalFlowPyrLK(b.pyramid_left, b.pyramid_right, left_points, right_points, status, error, window,
                           options.lk_levels, criteria, cv::OPTFLOW_USE_INITIAL_FLOW);
  // The way back starts from the left pixel the right one would have without the disparity
  // found, so that it has to find the disparity again.
  std::vector<cv::Point2f> back(left_points.size());
  for (size_t i = 0; i < left_points.size(); ++i) back[i] = left_points[i] + (right_points[i] - guesses[i]);
  cv::calcOpticalFlowPyrLK(b.pyramid_right, b.pyramid_left, right_points, back, status_back, error, window,
                           options.lk_levels, criteria, cv::OPTFLOW_USE_INITIAL_FLOW);
  const double max_back_sq = options.lk_max_backward_error_px * options.lk_max_backward_error_px;
  matches.reserve(left_points.size());
  for (size_t i = 0; i < left_points.size(); ++i) {
    if (!status[i] || !status_back[i]) continue;
    const cv::Point2f d = back[i] - left_points[i];
    if (d.dot(d) > max_back_sq) continue;
    if (!rig.right.inImage(Eigen::Vector2d(right_points[i].x, right_points[i].y))) continue;
    matches.push_back({left_points[i].x, left_points[i].y, right_points[i].x, right_points[i].y});
  }
  return matches;
}

}  // namespace embedded_calibration_stereo::core
