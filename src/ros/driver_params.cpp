#include "embedded_calibration_stereo/ros/driver_params.h"

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"

namespace embedded_calibration_stereo {

void readHealthSchedule(const ParameterReader& read, core::LightScheduleConfig* schedule) {
  const std::string trigger = read.choice("calibration_trigger", "periodic", {"periodic", "on_demand"});
  schedule->trigger = trigger == "on_demand" ? core::CalibrationTrigger::kOnDemand : core::CalibrationTrigger::kPeriodic;
  schedule->min_interval_s = read.atLeast("min_calibration_interval_s", schedule->min_interval_s, 0.0);
  schedule->verification_period_s = read.atLeast("verification_period_s", schedule->verification_period_s, 0.0);
  schedule->first_burst_delay_s = read.atLeast("first_burst_delay_s", 0.5, 0.0);
}

void readBurstSchedule(const ParameterReader& read, core::LightScheduleConfig* schedule) {
  schedule->period_s = read.get("calibration_period_s", 0.0);
  // A burst's length is a time by default, so that it lasts as long at any frame rate; a count
  // of frames (calibration_frames > 0) is for tests and replays that need exact frames.
  schedule->calibration_frames = read.get("calibration_frames", 0);
  schedule->calibration_duration_s = read.get("calibration_duration_s", 0.33);
}

DriverParams loadDriverParams(const ros::NodeHandle& private_nh, const std::string& default_sim_config) {
  const ParameterReader read(private_nh);
  DriverParams p;
  p.backend = read.choice("backend", p.backend, {"sim", "files", "v4l2"});
  p.light = readLightBackendParams(read, p.backend == "sim" ? "sim" : "none");
  if (p.light.backend == "sim" && p.backend != "sim") throw core::ConfigError("light_backend", "sim needs backend sim");

  p.fps = read.get("fps", p.fps);
  if (!(p.fps > 0.0) || p.fps > 1000.0) throw core::ConfigError("fps", "must be in (0, 1000] frames per second");
  p.left_frame_id = read.get("left_frame_id", p.left_frame_id);
  p.right_frame_id = read.get("right_frame_id", p.right_frame_id);
  p.right_in_left_frame = read.get("right_in_left_frame", p.right_in_left_frame);
  if (p.left_frame_id.empty()) throw core::ConfigError("left_frame_id", "must not be empty");
  if (p.right_frame_id.empty()) throw core::ConfigError("right_frame_id", "must not be empty");
  p.left_camera_name = read.get("left_camera_name", p.left_camera_name);
  p.right_camera_name = read.get("right_camera_name", p.right_camera_name);
  p.left_camera_info_url = read.get("left_camera_info_url", p.left_camera_info_url);
  p.right_camera_info_url = read.get("right_camera_info_url", p.right_camera_info_url);
  p.device_config = read.get("device_config", p.device_config);
  p.pair_timeout_s = read.get("pair_timeout_s", p.pair_timeout_s);
  if (!(p.pair_timeout_s > 0.0) || p.pair_timeout_s > 3600.0)
    throw core::ConfigError("pair_timeout_s", "must be in (0, 3600] seconds");

  readBurstSchedule(read, &p.schedule);
  p.schedule.settle_frames = read.get("settle_frames", p.schedule.settle_frames);
  readHealthSchedule(read, &p.schedule);
  core::throwIfProblem(p.schedule.problem());

  const std::string encoding = read.choice("encoding", "mono8", {"mono8", "bgr8"});
  if (p.backend == "sim") {
    p.sim_config = read.get("sim_config", default_sim_config);
    if (p.sim_config.empty()) throw core::ConfigError("sim_config", "missing");
    if (p.device_config.empty()) p.device_config = p.sim_config;
  } else if (p.backend == "files") {
    p.files.dir = read.get("files_dir", "");
    p.files.left_glob = read.get("files_left_glob", p.files.left_glob);
    p.files.right_glob = read.get("files_right_glob", p.files.right_glob);
    p.files.left_video = read.get("files_left_video", "");
    p.files.right_video = read.get("files_right_video", "");
    p.files.light_csv = read.get("files_light_csv", "");
    p.files.loop = read.get("files_loop", p.files.loop);
    p.files.encoding = encoding;
    if (p.files.dir.empty() && p.files.left_video.empty() && p.files.right_video.empty())
      throw core::ConfigError("files_dir", "missing (or give files_left_video and files_right_video)");
  } else {
    p.v4l2.left_device = read.get("v4l2_left_device", p.v4l2.left_device);
    p.v4l2.right_device = read.get("v4l2_right_device", p.v4l2.right_device);
    p.v4l2.width = read.get("v4l2_width", p.v4l2.width);
    p.v4l2.height = read.get("v4l2_height", p.v4l2.height);
    p.v4l2.fps = p.fps;
    p.v4l2.encoding = encoding;
    if (p.v4l2.width <= 0) throw core::ConfigError("v4l2_width", "must be > 0 pixels");
    if (p.v4l2.height <= 0) throw core::ConfigError("v4l2_height", "must be > 0 pixels");
  }

  return p;
}

}  // namespace embedded_calibration_stereo
