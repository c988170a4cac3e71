#include "embedded_calibration_stereo/ros/driver_params.h"

#include <cmath>

#include "embedded_calibration_stereo/core/geometry/config_error.h"

namespace embedded_calibration_stereo {
namespace {

// Typed getters that fail loudly on a wrongly typed value instead of silently using a default.
class ParamReader {
 public:
  explicit ParamReader(const ros::NodeHandle& nh) : nh_(nh) {}

  std::string string(const std::string& name, const std::string& fallback) const {
    if (!nh_.hasParam(name)) return fallback;
    std::string value;
    if (!nh_.getParam(name, value)) throw ecs::ConfigError(name, "must be a string");
    return value;
  }
  double number(const std::string& name, double fallback) const {
    if (!nh_.hasParam(name)) return fallback;
    double value;  // getParam(double) also accepts integers
    if (!nh_.getParam(name, value) || !std::isfinite(value)) throw ecs::ConfigError(name, "must be a number");
    return value;
  }
  int integer(const std::string& name, int fallback) const {
    if (!nh_.hasParam(name)) return fallback;
    int value;
    if (!nh_.getParam(name, value)) throw ecs::ConfigError(name, "must be an integer");
    return value;
  }
  bool boolean(const std::string& name, bool fallback) const {
    if (!nh_.hasParam(name)) return fallback;
    bool value;
    if (!nh_.getParam(name, value)) throw ecs::ConfigError(name, "must be true or false");
    return value;
  }
  std::string bytes(const std::string& name, const std::string& fallback) const {
    std::string decoded, error;
    if (!unescapeBytes(string(name, fallback), &decoded, &error)) throw ecs::ConfigError(name, error);
    return decoded;
  }

 private:
  const ros::NodeHandle& nh_;
};

void checkEncoding(const std::string& encoding) {
  if (encoding != "mono8" && encoding != "bgr8")
    throw ecs::ConfigError("encoding", "must be mono8 or bgr8 (got '" + encoding + "')");
}

}  // namespace

DriverParams loadDriverParams(const ros::NodeHandle& private_nh, const std::string& default_sim_config) {
  const ParamReader read(private_nh);
  DriverParams p;
  p.backend = read.string("backend", p.backend);
  if (p.backend != "sim" && p.backend != "files" && p.backend != "v4l2")
    throw ecs::ConfigError("backend", "unknown backend '" + p.backend + "' (use sim, files or v4l2)");
  p.light_backend = read.string("light_backend", p.backend == "sim" ? "sim" : "none");
  if (p.light_backend != "sim" && p.light_backend != "serial" && p.light_backend != "gpio" &&
      p.light_backend != "none")
    throw ecs::ConfigError("light_backend", "unknown light backend '" + p.light_backend +
                                                "' (use sim, serial, gpio or none)");
  if (p.light_backend == "sim" && p.backend != "sim")
    throw ecs::ConfigError("light_backend", "sim needs backend sim");

  p.fps = read.number("fps", p.fps);
  if (!(p.fps > 0.0) || p.fps > 1000.0) throw ecs::ConfigError("fps", "must be in (0, 1000] frames per second");
  p.left_frame_id = read.string("left_frame_id", p.left_frame_id);
  p.right_frame_id = read.string("right_frame_id", p.right_frame_id);
  p.right_in_left_frame = read.boolean("right_in_left_frame", p.right_in_left_frame);
  if (p.left_frame_id.empty()) throw ecs::ConfigError("left_frame_id", "must not be empty");
  if (p.right_frame_id.empty()) throw ecs::ConfigError("right_frame_id", "must not be empty");
  p.left_camera_name = read.string("left_camera_name", p.left_camera_name);
  p.right_camera_name = read.string("right_camera_name", p.right_camera_name);
  p.left_camera_info_url = read.string("left_camera_info_url", p.left_camera_info_url);
  p.right_camera_info_url = read.string("right_camera_info_url", p.right_camera_info_url);

  p.schedule.period_s = read.number("calibration_period_s", 0.0);
  p.schedule.calibration_frames = read.integer("calibration_frames", p.schedule.calibration_frames);
  p.schedule.settle_frames = read.integer("settle_frames", p.schedule.settle_frames);
  const std::string schedule_problem = p.schedule.validate();
  if (!schedule_problem.empty())
    throw ecs::ConfigError(schedule_problem.substr(0, schedule_problem.find(' ')), schedule_problem);

  const std::string encoding = read.string("encoding", "mono8");
  checkEncoding(encoding);
  if (p.backend == "sim") {
    p.sim_config = read.string("sim_config", default_sim_config);
    if (p.sim_config.empty()) throw ecs::ConfigError("sim_config", "missing");
  } else if (p.backend == "files") {
    p.files.dir = read.string("files_dir", "");
    p.files.left_glob = read.string("files_left_glob", p.files.left_glob);
    p.files.right_glob = read.string("files_right_glob", p.files.right_glob);
    p.files.left_video = read.string("files_left_video", "");
    p.files.right_video = read.string("files_right_video", "");
    p.files.light_csv = read.string("files_light_csv", "");
    p.files.loop = read.boolean("files_loop", p.files.loop);
    p.files.encoding = encoding;
    if (p.files.dir.empty() && p.files.left_video.empty() && p.files.right_video.empty())
      throw ecs::ConfigError("files_dir", "missing (or give files_left_video and files_right_video)");
  } else {
    p.v4l2.left_device = read.string("v4l2_left_device", p.v4l2.left_device);
    p.v4l2.right_device = read.string("v4l2_right_device", p.v4l2.right_device);
    p.v4l2.width = read.integer("v4l2_width", p.v4l2.width);
    p.v4l2.height = read.integer("v4l2_height", p.v4l2.height);
    p.v4l2.fps = p.fps;
    p.v4l2.encoding = encoding;
    if (p.v4l2.width <= 0) throw ecs::ConfigError("v4l2_width", "must be > 0 pixels");
    if (p.v4l2.height <= 0) throw ecs::ConfigError("v4l2_height", "must be > 0 pixels");
  }

  if (p.light_backend == "serial") {
    p.serial.port = read.string("serial_port", "");
    if (p.serial.port.empty()) throw ecs::ConfigError("serial_port", "missing");
    p.serial.baud = read.integer("serial_baud", p.serial.baud);
    p.serial.on_bytes = read.bytes("serial_on", "ON\\n");
    p.serial.off_bytes = read.bytes("serial_off", "OFF\\n");
  } else if (p.light_backend == "gpio") {
    p.gpio.chip = read.string("gpio_chip", p.gpio.chip);
    p.gpio.line = read.integer("gpio_line", p.gpio.line);
    p.gpio.active_low = read.boolean("gpio_active_low", p.gpio.active_low);
    if (p.gpio.line < 0) throw ecs::ConfigError("gpio_line", "missing or negative line offset");
  }
  return p;
}

}  // namespace embedded_calibration_stereo
