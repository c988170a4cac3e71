#pragma once
// Scene estimate for the pattern tracker: a light-off frame (I_off = t * scene), kept registered
// to the current frame so that the tracker can refine corners on I_on - I_off = r * device.
//
// Why: the scene behind the half-mirror is superimposed on the boards; its texture pulls every
// local corner refinement, by far more than the sensor noise does; on the difference the scene
// is gone. The background is only valid for a static scene: it is re-registered when the
// boards move in the image (zoom step, knock: the whole image moves, the scene with the boards)
// by a cubic polynomial warp fitted to the tracked corners' displacement since the background was
// taken. Resampling cannot recreate the scene exactly (corners are then somewhat less
// accurate), so a fresh light-off frame should replace it when one is available.
// A scene that changes by itself (moving objects) is not modelled: set a fresh light-off frame
// (the driver takes one every time the light goes off) or clear the background.
//
// Threading: owned by one CameraTracker, used by the thread tracking that camera only.
#include <map>
#include <opencv2/core.hpp>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/observation.h"

namespace embedded_calibration_stereo::core {

class SceneBackground {
 public:
  // Grey value added to the difference so that noise on dark squares is not clipped at 0.
  static constexpr int kDifferenceOffset = 32;

  // A light-off frame (CV_8UC1). The next tracked frame defines where the corners lie in it.
  void set(const cv::Mat& gray_light_off);
  void clear();
  bool empty() const { return image_.empty(); }

  // gray - background + kDifferenceOffset, saturated to CV_8U, smoothed by a Gaussian of
  // smoothing_sigma px (0 = none): with the scene gone, smoothing only helps cv::cornerSubPix
  // (on the anti-aliased edges of the boards).
  cv::Mat difference(const cv::Mat& gray, double smoothing_sigma) const;
  // The background as currently registered (CV_8UC1; empty when none).
  const cv::Mat& image() const { return image_; }

  // Compares corners tracked in the current frame with those the background is registered to.
  // When their RMS displacement exceeds motion_threshold_px, warps the background onto the
  // current frame and returns true (the caller re-tracks on the new difference).
  bool follow(const std::vector<BoardCorners>& tracked, double motion_threshold_px);

  // Last RMS displacement (px) measured by follow().
  double lastMotionPx() const { return last_motion_px_; }

 private:
  cv::Mat image_;
  std::map<std::pair<int, int>, cv::Point2f> anchor_;  // (board, corner) -> pixel in image_
  double last_motion_px_ = 0.0;
};

}  // namespace embedded_calibration_stereo::core
