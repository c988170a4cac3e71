#pragma once
// The camera driver's parameters (private namespace of the nodelet), read and validated in one
// place. Every problem throws core::ConfigError whose message starts with the parameter name.
// See the README for the table of parameters, defaults and units.
#include <ros/node_handle.h>

#include <string>

#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/ros/frame_source.h"
#include "embedded_calibration_stereo/ros/light_backend.h"

namespace embedded_calibration_stereo {

struct DriverParams {
  std::string backend = "sim";          // sim | files | v4l2
  double fps = 30.0;                    // frames per second
  std::string left_frame_id = "stereo_left_optical_frame";
  std::string right_frame_id = "stereo_right_optical_frame";
  // The right image and camera_info carry left_frame_id (true, default) or right_frame_id.
  // image_geometry::StereoCameraModel (hence stereo_image_proc) asserts that both cameras have
  // the same frame id: the right P's Tx already places the right camera in the left frame.
  bool right_in_left_frame = true;
  std::string left_camera_name = "stereo_left";
  std::string right_camera_name = "stereo_right";
  std::string left_camera_info_url;     // empty: file://${ROS_HOME}/camera_info/${NAME}.yaml
  std::string right_camera_info_url;
  // Seconds a set_camera_info whose P does not match the other camera's waits for the other
  // camera's set_camera_info (a stereo calibration sets left, then right) before it is discarded.
  double pair_timeout_s = 10.0;
  std::string sim_config;               // path of sim_rig.yaml (sim backend)
  // The device description (its `rig`: the nominal cameras); every calibration's focal lengths
  // must lie near its (kNominalFocalFactor). Empty: sim_config with the sim backend, else none.
  std::string device_config;
  core::LightScheduleConfig schedule;    // calibration_period_s, calibration_frames or _duration_s, settle_frames, trigger, ...
  FilesSourceParams files;
  V4l2SourceParams v4l2;
  LightBackendParams light;  // light_backend (default: sim for the sim backend, else none), serial_*, gpio_*
};

class ParameterReader;
// calibration_period_s and a burst's length (calibration_frames, calibration_duration_s), read
// alike by the CameraDriver and the LightController.
void readBurstSchedule(const ParameterReader& read, core::LightScheduleConfig* schedule);
// The schedule's health parameters, shared by the CameraDriver and the LightController:
// calibration_trigger (periodic | on_demand), min_calibration_interval_s, verification_period_s,
// first_burst_delay_s.
void readHealthSchedule(const ParameterReader& read, core::LightScheduleConfig* schedule);

// Reads and validates the parameters. `default_sim_config` is used when sim_config is not set.
// Checks types (ParameterReader), ranges and names (backend, light_backend, encodings, escapes);
// the existence of files and devices is checked when the backends open them.
DriverParams loadDriverParams(const ros::NodeHandle& private_nh, const std::string& default_sim_config);

}  // namespace embedded_calibration_stereo
