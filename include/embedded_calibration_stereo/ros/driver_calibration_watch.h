#pragma once
// The calibration an external driver publishes (the LightController's calibration_epoch,
// docs/nodelets.md#lightcontroller): the epoch counts the changes of the driver's camera_info,
// one per camera, as the CameraDriver counts the set_camera_info calls it puts in force; a
// camera_info whose K or P is all zero (read from its fx) is uncalibrated.
//
// Threading: plain values; used by one thread (the LightController's callback queue).
#include <sensor_msgs/CameraInfo.h>

#include <cstdint>
#include <optional>

namespace embedded_calibration_stereo {

// The calibration fields of a CameraInfo (size, distortion, K, R, P; not its header) agree.
bool sameCalibration(const sensor_msgs::CameraInfo& a, const sensor_msgs::CameraInfo& b);

class DriverCalibrationWatch {
 public:
  /// The camera_info of camera 0 (left) or 1 (right) of a stereo frame. Returns true when it
  /// changes that camera's calibration (the epoch moved on); the first one does not.
  bool update(int camera, const sensor_msgs::CameraInfo& info);
  /// The changes counted so far (0 at start).
  uint32_t epoch() const { return epoch_; }
  /// Whether the latest camera_info of `camera` has K or P all zero (false before the first).
  bool uncalibrated(int camera) const { return uncalibrated_[camera]; }
  /// The latest camera_info of each camera (none before the first).
  const std::optional<sensor_msgs::CameraInfo>* latest() const { return latest_; }

 private:
  std::optional<sensor_msgs::CameraInfo> latest_[2];
  bool uncalibrated_[2] = {false, false};
  uint32_t epoch_ = 0;
};

}  // namespace embedded_calibration_stereo
