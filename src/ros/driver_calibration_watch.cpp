#include "embedded_calibration_stereo/ros/driver_calibration_watch.h"

namespace embedded_calibration_stereo {

bool sameCalibration(const sensor_msgs::CameraInfo& a, const sensor_msgs::CameraInfo& b) {
  return a.width == b.width && a.height == b.height && a.distortion_model == b.distortion_model && a.D == b.D &&
         a.K == b.K && a.R == b.R && a.P == b.P;
}

bool DriverCalibrationWatch::update(int camera, const sensor_msgs::CameraInfo& info) {
  const bool changed = latest_[camera] && !sameCalibration(*latest_[camera], info);
  if (changed) ++epoch_;
  latest_[camera] = info;
  uncalibrated_[camera] = info.K[0] == 0.0 || info.P[0] == 0.0;
  return changed;
}

}  // namespace embedded_calibration_stereo
