#include "embedded_calibration_stereo/ros/camera_calibration.h"

#include <sys/stat.h>

#include "embedded_calibration_stereo/core/geometry/config_error.h"
#include "embedded_calibration_stereo/ros/calibration_file.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace embedded_calibration_stereo {

CameraCalibration::CameraCalibration(const ros::NodeHandle& manager_nh,
                                     const std::string& camera_name, const std::string& url,
                                     const std::string& parameter)
    : camera_name_(camera_name), url_(url), parameter_(parameter) {
  std::string error;
  if (!resolveCalibrationUrl(url_, camera_name_, &path_, &error))
    throw ecs::ConfigError(parameter_, error);
  manager_ = std::make_unique<camera_info_manager::CameraInfoManager>(manager_nh, camera_name_, url_);
}

bool CameraCalibration::load(const sensor_msgs::CameraInfo& fallback) {
  struct stat st;
  if (stat(path_.c_str(), &st) != 0) {
    manager_->setCameraInfo(fallback);
    return false;
  }
  // Check the file ourselves first: camera_info_manager only logs a warning for a broken file.
  sensor_msgs::CameraInfo info;
  std::string error;
  if (!readCalibrationFile(path_, nullptr, &info, &error)) throw ecs::ConfigError(parameter_, error);
  ecs::PinholeCamera camera;
  if (!fromCameraInfo(info, &camera, &error))
    throw ecs::ConfigError(parameter_, "'" + path_ + "': " + error);
  if (!manager_->loadCameraInfo(url_))
    throw ecs::ConfigError(parameter_, "camera_info_manager could not load '" + path_ + "'");
  return true;
}

bool CameraCalibration::set(const sensor_msgs::CameraInfo& info, std::string* reason) {
  ecs::PinholeCamera camera;
  std::string error;
  if (!fromCameraInfo(info, &camera, &error)) {
    if (reason) *reason = "rejected: " + error;
    return false;
  }
  std::lock_guard<std::mutex> lock(write_mutex_);
  if (!writeCalibrationFileAtomic(path_, camera_name_, info, &error)) {
    if (reason) *reason = "not stored: " + error;
    return false;
  }
  manager_->setCameraInfo(info);
  if (reason) *reason = "stored in " + path_;
  return true;
}

sensor_msgs::CameraInfo CameraCalibration::current() const { return manager_->getCameraInfo(); }

}  // namespace embedded_calibration_stereo
