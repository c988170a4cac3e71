// TrackerOptions::check, grey conversion and the stereo PatternTracker.
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "embedded_calibration_stereo/core/geometry/config_error.h"

namespace ecs {

std::string TrackerOptions::check() const {
  if (window_radius_px < 0 || window_radius_px > 15)
    return "window_radius_px must be in [0, 15] (0 = automatic)";
  if (!(search_radius_px >= 0 && search_radius_px <= 64)) return "search_radius_px must be in [0, 64]";
  if (!(min_contrast >= 0 && std::isfinite(min_contrast))) return "min_contrast must be >= 0";
  if (!(relative_contrast >= 0 && relative_contrast <= 1)) return "relative_contrast must be in [0, 1]";
  if (!(max_residual_px > 0 && std::isfinite(max_residual_px))) return "max_residual_px must be > 0";
  if (!(max_residual_no_background_px > 0 && std::isfinite(max_residual_no_background_px)))
    return "max_residual_no_background_px must be > 0";
  if (!(max_refine_shift > 0 && std::isfinite(max_refine_shift))) return "max_refine_shift must be > 0";
  if (max_iterations < 1) return "max_iterations must be >= 1";
  if (min_board_corners < 4) return "min_board_corners must be >= 4 (a homography needs 4)";
  if (!(min_board_fraction >= 0 && min_board_fraction <= 1)) return "min_board_fraction must be in [0, 1]";
  if (!(min_pattern_score >= -1 && min_pattern_score <= 1)) return "min_pattern_score must be in [-1, 1]";
  if (!(offset_update_rate >= 0 && offset_update_rate <= 1)) return "offset_update_rate must be in [0, 1]";
  if (!(difference_smoothing_px >= 0 && difference_smoothing_px <= 5))
    return "difference_smoothing_px must be in [0, 5]";
  if (!(alignment_blur_px >= 0.3 && alignment_blur_px <= 5)) return "alignment_blur_px must be in [0.3, 5]";
  if (!(stale_background_level > 0 && std::isfinite(stale_background_level)))
    return "stale_background_level must be > 0";
  if (!(background_motion_px > 0 && std::isfinite(background_motion_px)))
    return "background_motion_px must be > 0";
  return "";
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

}  // namespace ecs
