#pragma once
// The LightController's calibration_store "file" (docs/nodelets.md#lightcontroller): for an
// external driver that reads a calibration file but cannot store one (image_publisher), it
// serves both cameras' set_camera_info as the CameraDriver does (StereoCalibration: refused,
// staged or stored as one pair of files), then asks both drivers to reload their files through
// their dynamic_reconfigure parameter camera_info_url. The pair store is made at the first
// set_camera_info, when the driver's image size is known.
//
// Threading: not thread-safe; one owner (the LightController's callback queue).
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "embedded_calibration_stereo/ros/camera_calibration.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

// Calls the driver's dynamic_reconfigure `service` (.../set_parameters) with camera_info_url
// `url`; false when the service is not available.
bool reloadCameraInfoUrl(const std::string& service, const std::string& url);

class ReloadingCalibrationStore {
 public:
  struct Side {
    StereoCalibration::Camera camera;  // name, camera_info_url and its parameter's name
    std::string reload_service;        // the driver's .../set_parameters; empty: none
  };
  enum class Severity { kInfo, kWarn, kError };
  using Log = std::function<void(Severity, const std::string& text)>;
  using Reload = std::function<bool(const std::string& service, const std::string& url)>;

  /// `pair_timeout_s`: how long a calibration of one camera waits for the other camera's.
  /// `log` gets each line to log (texts start "LightController: ").
  ReloadingCalibrationStore(Side left, Side right, double pair_timeout_s, Log log,
                            Reload reload = reloadCameraInfoUrl);

  /// One camera's set_camera_info. `in_force`: the driver's latest camera_info of each camera
  /// (none before the first). Refused when `info` is not of the driver's image size, or before
  /// both cameras' camera_info arrived (the size is unknown); a staged calibration is answered
  /// as staged and nothing is reloaded; a stored pair makes both drivers reload, and a reload
  /// service that is not available fails the call.
  void set(bool left, const sensor_msgs::CameraInfo& info, const std::optional<sensor_msgs::CameraInfo> in_force[2],
           sensor_msgs::SetCameraInfo::Response* res);

 private:
  // The pair store, made from the driver's calibration in force; false with `res` refused.
  bool makeStore(const std::optional<sensor_msgs::CameraInfo> in_force[2], const char* side,
                 sensor_msgs::SetCameraInfo::Response* res);
  void refuse(const char* side, const std::string& message, sensor_msgs::SetCameraInfo::Response* res);

  Side sides_[2];
  double pair_timeout_s_;
  Log log_;
  Reload reload_;
  std::unique_ptr<StereoCalibration> calibration_;
  ErrorThrottle refusals_{5.0};  // refusals, per message: a caller in a loop must not flood the log
};

}  // namespace embedded_calibration_stereo
