#include "embedded_calibration_stereo/core/light/light_confirmation.h"

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <vector>

namespace embedded_calibration_stereo::core {

std::string LightConfirmationOptions::validate() const { return problem().text(); }

ConfigProblem LightConfirmationOptions::problem() const {
  if (!(min_step > 0.0) || !std::isfinite(min_step)) return {"min_step", "must be > 0 grey levels"};
  if (!(switch_fraction > 0.0 && switch_fraction < 1.0)) return {"switch_fraction", "must be in (0, 1)"};
  if (!(plateau_fraction > 0.0 && plateau_fraction < switch_fraction))
    return {"plateau_fraction", "must be in (0, switch_fraction)"};
  return {};
}

double regionLevel(const cv::Mat& image, const cv::Mat& mask) {
  const cv::Scalar mean = mask.empty() ? cv::mean(image) : cv::mean(image, mask);
  double sum = 0.0;
  for (int c = 0; c < image.channels(); ++c) sum += mean[c];
  return sum / image.channels();
}

cv::Mat boardRegionMask(const CameraPrior& prior, double margin_squares) {
  if (prior.boards.empty() || prior.width <= 0 || prior.height <= 0) return cv::Mat();
  cv::Mat mask = cv::Mat::zeros(prior.height, prior.width, CV_8UC1);
  for (const BoardPrior& board : prior.boards) {
    // Grid -> image through the outer corners; the board's squares reach one square beyond them.
    const cv::Mat homography = cv::getPerspectiveTransform(board.outerGridPoints(), board.meanOuterCorners());
    const float lo = static_cast<float>(-margin_squares);
    const float c = static_cast<float>(board.cols - 1 + margin_squares);
    const float r = static_cast<float>(board.rows - 1 + margin_squares);
    std::vector<cv::Point2f> grid{{lo, lo}, {c, lo}, {c, r}, {lo, r}}, image;
    cv::perspectiveTransform(grid, image, homography);
    std::vector<cv::Point> polygon;
    for (const cv::Point2f& p : image) polygon.emplace_back(cvRound(p.x), cvRound(p.y));
    cv::fillConvexPoly(mask, polygon, cv::Scalar(255));
  }
  return mask;
}

LightLevelTracker::LightLevelTracker(const LightConfirmationOptions& options) : options_(options) {}

std::optional<ConfirmedLight> LightLevelTracker::push(double level) {
  if (pending_ == 0) {
    level_ = level;
    pending_ = 1;
    return std::nullopt;
  }
  const ConfirmedLight decided = decide(before_, pending_ == 2, level_, level);
  before_ = level_;
  level_ = level;
  pending_ = 2;
  return decided;
}

void LightLevelTracker::forgetLevels() {
  pending_ = 0;
  plateau_.reset();
  step_ = 0.0;
  known_ = false;
}

ConfirmedLight LightLevelTracker::decide(double before, bool have_before, double level, double after) {
  const double scale = step_ > 0.0 ? step_ : options_.min_step;
  const double tolerance = options_.plateau_fraction * scale;
  const double threshold = step_ > 0.0 ? options_.switch_fraction * step_ : options_.min_step;
  // A frame without a predecessor cannot be shown to be on a plateau.
  const bool stable = have_before && std::abs(level - before) <= tolerance && std::abs(after - level) <= tolerance;
  if (!plateau_) {
    if (stable) plateau_ = level;  // the first plateau keeps the state held (off at the start)
    return {on_, stable && known_};
  }
  const double change = level - *plateau_;
  if (!known_) {
    // The state shows again at the next switch: its direction says which.
    if (stable && std::abs(change) >= threshold) {
      on_ = change > 0;
      known_ = true;
      step_ = std::abs(change);
      plateau_ = level;
      return {on_, true};
    }
    if (stable) plateau_ = level;
    return {on_, false};
  }
  if (!stable) return {on_ ? change > -threshold : change >= threshold, false};
  if (!on_ && change >= threshold) {
    on_ = true;
    step_ = step_ > 0.0 ? 0.5 * (step_ + change) : change;
  } else if (on_ && change <= -threshold) {
    on_ = false;
    step_ = step_ > 0.0 ? 0.5 * (step_ - change) : -change;
  }
  plateau_ = level;
  return {on_, true};
}

StereoLightConfirmer::StereoLightConfirmer(const LightConfirmationOptions& options)
    : left_(options), right_(options) {}

std::optional<ConfirmedLight> StereoLightConfirmer::push(double left_level, double right_level) {
  const std::optional<ConfirmedLight> left = left_.push(left_level);
  const std::optional<ConfirmedLight> right = right_.push(right_level);
  if (!left || !right) return std::nullopt;
  ConfirmedLight stereo;
  stereo.light_on = left->light_on && right->light_on;
  stereo.settled = left->settled && right->settled && left->light_on == right->light_on;
  return stereo;
}

void StereoLightConfirmer::forgetLevels() {
  left_.forgetLevels();
  right_.forgetLevels();
}

void LightCommandWatch::update(bool commanded_on, const std::optional<ConfirmedLight>& confirmed) {
  if (commanded_on != commanded_on_) {
    commanded_on_ = commanded_on;
    frames_since_command_ = 0;
    agreed_ = false;
  }
  ++frames_since_command_;
  // The command's effect reaches a decided, settled frame after the driver's delay, the
  // confirmation's one frame and the unsettled frames on both sides of the change.
  const long deadline = max_delay_frames_ + 3;
  if (confirmed && confirmed->settled) {
    if (confirmed->light_on == commanded_on_) {
      agreed_ = true;
      fault_.clear();
      return;
    }
    if (frames_since_command_ <= deadline) return;
    fault_ = commanded_on_ ? "switched on " + std::to_string(frames_since_command_) +
                                 " frames ago, but the images do not show the device lit (its regions did not "
                                 "brighten)"
                           : "switched off " + std::to_string(frames_since_command_) +
                                 " frames ago, but the images still show the device lit";
    return;
  }
  if (!agreed_ && frames_since_command_ > 2 * deadline + 10)
    fault_ = "switched " + std::string(commanded_on_ ? "on " : "off ") + std::to_string(frames_since_command_) +
             " frames ago, and no frame since shows a steady light";
}

}  // namespace embedded_calibration_stereo::core
