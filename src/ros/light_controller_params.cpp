#include "embedded_calibration_stereo/ros/light_controller_params.h"

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/driver_params.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"

namespace embedded_calibration_stereo {

LightControllerParams loadLightControllerParams(const ParameterReader& read, const std::string& default_prior_file) {
  LightControllerParams p;
  p.light = readLightBackendParams(read, "none");
  readBurstSchedule(read, &p.schedule);
  // Frames the light is held on beyond the settled ones: the driver's delay and the unsettled
  // frames on both sides of each switch.
  p.schedule.settle_frames = read.get("settle_frames", 5);
  readHealthSchedule(read, &p.schedule);
  core::throwIfProblem(p.schedule.problem());

  p.approximate_sync = read.get("approximate_sync", p.approximate_sync);
  p.max_interval_s = read.atLeast("max_interval_s", p.max_interval_s, 0.0);
  p.queue_size = read.atLeast("queue_size", p.queue_size, 1);
  p.prior_file = read.get("prior_file", default_prior_file);
  p.region_margin_squares = read.atLeast("region_margin_squares", p.region_margin_squares, 0.0);
  p.confirmation.min_step = read.get("min_step", p.confirmation.min_step);
  p.confirmation.switch_fraction = read.get("switch_fraction", p.confirmation.switch_fraction);
  p.confirmation.plateau_fraction = read.get("plateau_fraction", p.confirmation.plateau_fraction);
  core::throwIfProblem(p.confirmation.problem());
  p.max_delay_frames = read.atLeast("max_delay_frames", p.max_delay_frames, 0);

  p.calibration_store = read.choice("calibration_store", p.calibration_store, {"driver", "file"});
  if (p.calibration_store == "file") {
    p.left_camera_name = read.get("left_camera_name", p.left_camera_name);
    p.right_camera_name = read.get("right_camera_name", p.right_camera_name);
    p.left_camera_info_url = read.get("left_camera_info_url", "");
    p.right_camera_info_url = read.get("right_camera_info_url", "");
    p.left_reload_service = read.get("left_reload_service", "");
    p.right_reload_service = read.get("right_reload_service", "");
    if (p.left_camera_info_url.empty()) throw core::ConfigError("left_camera_info_url", "missing (calibration_store file)");
    if (p.right_camera_info_url.empty())
      throw core::ConfigError("right_camera_info_url", "missing (calibration_store file)");
  }
  return p;
}

}  // namespace embedded_calibration_stereo
