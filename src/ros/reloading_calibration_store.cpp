#include "embedded_calibration_stereo/ros/reloading_calibration_store.h"

#include <dynamic_reconfigure/Reconfigure.h>
#include <ros/service.h>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/set_camera_info_answer.h"

namespace embedded_calibration_stereo {

bool reloadCameraInfoUrl(const std::string& service, const std::string& url) {
  dynamic_reconfigure::Reconfigure reload;
  dynamic_reconfigure::StrParameter parameter;
  parameter.name = "camera_info_url";
  parameter.value = url;
  reload.request.config.strs.push_back(parameter);
  return ros::service::call(service, reload);
}

ReloadingCalibrationStore::ReloadingCalibrationStore(Side left, Side right, double pair_timeout_s, Log log,
                                                     Reload reload)
    : sides_{std::move(left), std::move(right)},
      pair_timeout_s_(pair_timeout_s),
      log_(std::move(log)),
      reload_(std::move(reload)) {}

void ReloadingCalibrationStore::refuse(const char* side, const std::string& message,
                                       sensor_msgs::SetCameraInfo::Response* res) {
  res->success = false;
  res->status_message = message;
  log_(Severity::kWarn, std::string("LightController: ") + side + " set_camera_info " + message);
}

bool ReloadingCalibrationStore::makeStore(const std::optional<sensor_msgs::CameraInfo> in_force[2], const char* side,
                                          sensor_msgs::SetCameraInfo::Response* res) {
  if (!in_force[0] || !in_force[1]) {
    refuse(side, "rejected: no camera_info from the driver yet (the calibration's image size is unknown)", res);
    return false;
  }
  try {
    calibration_ = std::make_unique<StereoCalibration>(sides_[0].camera, sides_[1].camera, in_force[0]->width,
                                                       in_force[0]->height, pair_timeout_s_);
    calibration_->load(*in_force[0], *in_force[1]);
  } catch (const core::ConfigError& e) {
    calibration_.reset();
    res->success = false;
    res->status_message = std::string("not stored: ") + e.what();
    log_(Severity::kError, std::string("LightController: ") + side + " set_camera_info: " + res->status_message);
    return false;
  }
  return true;
}

void ReloadingCalibrationStore::set(bool left, const sensor_msgs::CameraInfo& info,
                                    const std::optional<sensor_msgs::CameraInfo> in_force[2],
                                    sensor_msgs::SetCameraInfo::Response* res) {
  const char* side = left ? "left" : "right";
  const std::optional<sensor_msgs::CameraInfo>& own = in_force[left ? 0 : 1];
  if (own && (info.width != own->width || info.height != own->height))
    return refuse(side,
                  "rejected: calibration is for " + std::to_string(info.width) + "x" + std::to_string(info.height) +
                      " but the driver's images are " + std::to_string(own->width) + "x" + std::to_string(own->height),
                  res);
  if (!calibration_ && !makeStore(in_force, side, res)) return;
  const StereoCalibration::SetResult result = calibration_->set(left, info);
  if (!result.discarded.empty()) log_(Severity::kError, "LightController: " + result.discarded);
  res->success = result.success;
  res->status_message = result.message;
  if (!result.success) {
    if (refusals_.shouldReport(result.message))
      log_(Severity::kError, std::string("LightController: ") + side +
                                 " set_camera_info failed, calibration unchanged: " + result.message);
    return;
  }
  if (!isStagedAnswer(*res)) {  // staged: it waits for the other camera, nothing written yet
    // Both files changed together: both drivers reload theirs.
    for (const Side& s : sides_) {
      if (s.reload_service.empty() || reload_(s.reload_service, s.camera.url)) continue;
      res->success = false;
      res->status_message =
          result.message + ", but the driver did not reload it: " + s.reload_service + " is not available";
      log_(Severity::kError, std::string("LightController: ") + side + " set_camera_info: " + res->status_message);
      return;
    }
  }
  log_(Severity::kInfo, std::string("LightController: ") + side + " calibration " + res->status_message);
}

}  // namespace embedded_calibration_stereo
