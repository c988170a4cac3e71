#pragma once
// Where the LightController confirms its light (docs/nodelets.md#lightcontroller): the device's
// board regions taught in the tracker's prior file, re-read whenever the file changes, or the
// whole image. The whole image confirms from the start; regions taught later take over once
// their own confirmation has seen a switch, so that a change of regions never guesses the state.
//
// Threading: plain values; each object is used by one thread at a time.
#include <opencv2/core.hpp>

#include <chrono>
#include <filesystem>
#include <optional>
#include <string>

#include "embedded_calibration_stereo/core/light/light_confirmation.h"

namespace embedded_calibration_stereo::core {

// The board regions of a prior file, re-read when it appears, changes or goes away.
class BoardRegionsFile {
 public:
  /// `margin_squares`: squares added around each board (boardRegionMask).
  BoardRegionsFile(std::string path, double margin_squares);

  /// Re-reads the file when it appeared, changed or went away since the previous call (the
  /// first call always reads). Returns true when it did: the masks and problem() are new.
  bool refresh();
  /// The regions of camera 0 (left) or 1 (right); both empty when none are usable.
  const cv::Mat& mask(int camera) const { return masks_[camera]; }
  /// Whether usable regions were read (both cameras have a mask).
  bool taught() const { return !masks_[0].empty(); }
  /// Why a present file is not used (not two cameras, a camera without boards, unreadable);
  /// "" when it is used or absent.
  const std::string& problem() const { return problem_; }
  /// The prior file's path.
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  double margin_squares_;
  bool read_ = false;
  std::optional<std::filesystem::file_time_type> mtime_;  // none: absent
  cv::Mat masks_[2];
  std::string problem_;
};

// The light of each stereo frame, from the whole image or from the taught regions.
class DeviceLightConfirmer {
 public:
  explicit DeviceLightConfirmer(const LightConfirmationOptions& options);

  /// New regions (both empty: none). Their confirmation starts knowing nothing: the whole image
  /// decides until it has seen a switch.
  void setRegions(const cv::Mat& left_mask, const cv::Mat& right_mask);
  /// The next stereo frame's images; returns the light of the frame before it (one frame late,
  /// see LightLevelTracker). A region mask of another size than its image (taught on another
  /// camera mode) is not used: that camera's level is taken over the whole image.
  std::optional<ConfirmedLight> push(const cv::Mat& left, const cv::Mat& right);
  /// Whether the regions of camera 0 or 1 (if any) apply to images of `size`.
  bool fits(int camera, const cv::Size& size) const;

  /// Whether regions were set (used or still waiting for a switch).
  bool hasRegions() const { return regions_.has_value(); }
  /// Whether the taught regions decide (they have seen a switch).
  bool regionsInUse() const { return regions_ && regions_->known(); }
  /// The confirmation that decides now (for its measured steps).
  const StereoLightConfirmer& inUse() const { return regionsInUse() ? *regions_ : whole_; }

 private:
  double level(int camera, const cv::Mat& image) const;

  LightConfirmationOptions options_;
  StereoLightConfirmer whole_;
  std::optional<StereoLightConfirmer> regions_;
  cv::Mat masks_[2];
};

}  // namespace embedded_calibration_stereo::core
