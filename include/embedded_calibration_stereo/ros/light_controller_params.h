#pragma once
// The LightController's parameters (private namespace of the nodelet), read and validated in
// one place; the table of parameters, defaults and units is in docs/nodelets.md#lightcontroller.
// Every problem throws core::ConfigError naming the parameter.
#include <string>

#include "embedded_calibration_stereo/core/light/light_confirmation.h"
#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/ros/light_backend.h"

namespace embedded_calibration_stereo {

class ParameterReader;

struct LightControllerParams {
  LightBackendParams light;           // light_backend (default none), serial_*, gpio_*
  core::LightScheduleConfig schedule;  // calibration_period_s, calibration_frames or _duration_s, settle_frames, trigger, ...
  bool approximate_sync = true;
  double max_interval_s = 0.0;  // ApproximateTime's limit on a set's stamp spread; 0 = none
  int queue_size = 5;
  std::string prior_file;
  double region_margin_squares = 1.5;
  core::LightConfirmationOptions confirmation;
  int max_delay_frames = 3;
  std::string calibration_store = "driver";  // driver | file
  std::string left_camera_name = "stereo_left", right_camera_name = "stereo_right";
  std::string left_camera_info_url, right_camera_info_url;  // calibration_store file: required
  std::string left_reload_service, right_reload_service;    // the driver's .../set_parameters
};

// Reads and checks every parameter. `default_prior_file`: prior_file when it is not set.
LightControllerParams loadLightControllerParams(const ParameterReader& read, const std::string& default_prior_file);

}  // namespace embedded_calibration_stereo
