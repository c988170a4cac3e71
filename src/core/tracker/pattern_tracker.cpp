// TrackerOptions::check, grey conversion and the stereo PatternTracker.
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo::core {

namespace {

// The corner refinement's options (windows, contrast, residuals, iterations).
std::string refinementProblem(const TrackerOptions& o) {
  if (o.window_radius_px < 0 || o.window_radius_px > 15)
    return "window_radius_px must be in [0, 15] (0 = automatic)";
  if (!(o.search_radius_px >= 0 && o.search_radius_px <= 64)) return "search_radius_px must be in [0, 64]";
  if (!(o.min_contrast >= 0 && std::isfinite(o.min_contrast))) return "min_contrast must be >= 0";
  if (!(o.relative_contrast >= 0 && o.relative_contrast <= 1)) return "relative_contrast must be in [0, 1]";
  if (!(o.max_residual_px > 0 && std::isfinite(o.max_residual_px))) return "max_residual_px must be > 0";
  if (!(o.max_residual_no_background_px > 0 && std::isfinite(o.max_residual_no_background_px)))
    return "max_residual_no_background_px must be > 0";
  if (!(o.max_refine_shift > 0 && std::isfinite(o.max_refine_shift))) return "max_refine_shift must be > 0";
  if (o.max_iterations < 1) return "max_iterations must be >= 1";
  return "";
}

// The board's, the alignment's and the background's options.
std::string boardProblem(const TrackerOptions& o) {
  if (o.min_board_corners < 4) return "min_board_corners must be >= 4 (a homography needs 4)";
  if (!(o.min_board_fraction >= 0 && o.min_board_fraction <= 1)) return "min_board_fraction must be in [0, 1]";
  if (!(o.min_pattern_score >= -1 && o.min_pattern_score <= 1)) return "min_pattern_score must be in [-1, 1]";
  if (!(o.offset_update_rate >= 0 && o.offset_update_rate <= 1)) return "offset_update_rate must be in [0, 1]";
  if (!(o.difference_smoothing_px >= 0 && o.difference_smoothing_px <= 5))
    return "difference_smoothing_px must be in [0, 5]";
  if (!(o.alignment_blur_px >= 0.3 && o.alignment_blur_px <= 5)) return "alignment_blur_px must be in [0.3, 5]";
  if (!(o.stale_background_level > 0 && std::isfinite(o.stale_background_level)))
    return "stale_background_level must be > 0";
  if (!(o.background_motion_px > 0 && std::isfinite(o.background_motion_px)))
    return "background_motion_px must be > 0";
  return "";
}

}  // namespace

std::string TrackerOptions::validate() const {
  const std::string problem = refinementProblem(*this);
  return problem.empty() ? boardProblem(*this) : problem;
}

cv::Mat toGrayImage(const cv::Mat& image, ColorOrder order) {
  if (image.empty()) throw std::invalid_argument("empty image");
  if (image.type() == CV_8UC1) return image;
  if (image.type() == CV_8UC3) {
    cv::Mat gray;
    cv::cvtColor(image, gray, order == ColorOrder::kRgb ? cv::COLOR_RGB2GRAY : cv::COLOR_BGR2GRAY);
    return gray;
  }
  throw std::invalid_argument("unsupported image type " + cv::typeToString(image.type()) +
                              " (the pattern tracker takes 8UC1 mono8 or 8UC3 bgr8/rgb8)");
}

PatternTracker::PatternTracker(const PatternPrior& prior, const TrackerOptions& options) : options_(options) {
  const std::string problem = prior.validate();
  if (!problem.empty()) throw ConfigError("prior", problem);
  for (const CameraPrior& camera : prior.cameras) cameras_.emplace_back(camera, options);
}

void PatternTracker::reset() {
  for (CameraTracker& c : cameras_) c.reset();
}

void PatternTracker::setBackground(const cv::Mat& left, const cv::Mat& right, ColorOrder order) {
  if (cameras_.size() != 2) throw std::logic_error("setBackground needs a prior with two cameras");
  cameras_[0].setBackground(left, order);
  cameras_[1].setBackground(right, order);
}

StereoObservation PatternTracker::trackStereo(const cv::Mat& left, const cv::Mat& right, double stamp,
                                              ColorOrder order) {
  if (cameras_.size() != 2) throw std::logic_error("trackStereo needs a prior with two cameras");
  // One task per camera: each reads its own image and writes only its own tracker, so the two
  // cameras never share mutable state. (Boards inside a camera run in parallel when this runs
  // on one thread; OpenCV serialises the nested loop otherwise.)
  const cv::Mat images[2] = {left, right};
  std::vector<BoardCorners> results[2];
  auto body = [&](const cv::Range& range) {
    for (int c = range.start; c < range.end; ++c) results[c] = cameras_[c].track(images[c], order);
  };
  if (options_.parallel)
    cv::parallel_for_(cv::Range(0, 2), body);
  else
    body(cv::Range(0, 2));
  StereoObservation obs;
  obs.stamp = stamp;
  obs.left = std::move(results[0]);
  obs.right = std::move(results[1]);
  return obs;
}

}  // namespace embedded_calibration_stereo::core
