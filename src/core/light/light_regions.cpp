#include "embedded_calibration_stereo/core/light/light_regions.h"

#include <stdexcept>
#include <system_error>

#include "embedded_calibration_stereo/core/tracker/board_prior.h"

namespace embedded_calibration_stereo::core {

BoardRegionsFile::BoardRegionsFile(std::string path, double margin_squares)
    : path_(std::move(path)), margin_squares_(margin_squares) {}

bool BoardRegionsFile::refresh() {
  std::error_code error;
  std::optional<std::filesystem::file_time_type> mtime = std::filesystem::last_write_time(path_, error);
  if (error) mtime.reset();
  if (read_ && mtime == mtime_) return false;
  read_ = true;
  mtime_ = mtime;
  masks_[0] = masks_[1] = cv::Mat();
  problem_.clear();
  if (!mtime) return true;
  try {
    const PatternPrior prior = readPatternPrior(path_);
    if (prior.cameras.size() != 2)
      throw std::invalid_argument("expected 2 cameras, found " + std::to_string(prior.cameras.size()));
    for (int c = 0; c < 2; ++c) masks_[c] = boardRegionMask(prior.cameras[c], margin_squares_);
    if (masks_[0].empty() || masks_[1].empty()) throw std::invalid_argument("a camera has no board");
  } catch (const std::exception& e) {
    problem_ = e.what();
    masks_[0] = masks_[1] = cv::Mat();
  }
  return true;
}

DeviceLightConfirmer::DeviceLightConfirmer(const LightConfirmationOptions& options)
    : options_(options), whole_(options) {}

void DeviceLightConfirmer::setRegions(const cv::Mat& left_mask, const cv::Mat& right_mask) {
  masks_[0] = left_mask;
  masks_[1] = right_mask;
  regions_.reset();
  if (left_mask.empty() || right_mask.empty()) return;
  regions_.emplace(options_);
  regions_->forgetLevels();  // the state is unknown to it until it sees a switch
}

bool DeviceLightConfirmer::fits(int camera, const cv::Size& size) const {
  return !regions_ || masks_[camera].size() == size;
}

double DeviceLightConfirmer::level(int camera, const cv::Mat& image) const {
  return regionLevel(image, fits(camera, image.size()) ? masks_[camera] : cv::Mat());
}

std::optional<ConfirmedLight> DeviceLightConfirmer::push(const cv::Mat& left, const cv::Mat& right) {
  std::optional<ConfirmedLight> decided = whole_.push(regionLevel(left, cv::Mat()), regionLevel(right, cv::Mat()));
  if (regions_) {
    const std::optional<ConfirmedLight> by_regions = regions_->push(level(0, left), level(1, right));
    if (regions_->known() && by_regions) decided = by_regions;
  }
  return decided;
}

}  // namespace embedded_calibration_stereo::core
