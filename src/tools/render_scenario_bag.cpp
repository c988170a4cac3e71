// Renders N seconds of a simulated scenario into a rosbag, as launch/record.launch records the
// sim driver (ground_truth:=true): the same topics, types, frame ids and stamps, without a ROS
// master and without paying the renderer at replay time. Frame k (from 0) is the scene at time
// k / fps, stamped start + k / fps; the light follows the driver's schedule
// (ecs::LightSchedule: period, calibration frames, settle frames) and an optional drift script
// replays sim/set_drift requests at given scene times. So a bag is the same every time it is
// made (same seeds as the driver: frame k's noise seed is k + 1).
//
//   rosrun embedded_calibration_stereo render_scenario_bag --config config/sim_rig.yaml
//       --out /tmp/scenario.bag --seconds 20 --period 5
//
// Topics (ns "stereo" by default), as the driver publishes them:
//   /stereo/left/image_raw, /stereo/right/image_raw        sensor_msgs/Image
//   /stereo/left/camera_info, /stereo/right/camera_info    the calibration in force
//   /stereo/calibration_mode                               light_on, settled, calibration_epoch
//   /stereo/ground_truth/left/image_scene, .../right/image_scene, .../left/camera_info,
//   .../right/camera_info, .../observations, .../head_pose (nav_msgs/Odometry)
//   /tf                                                    ground_truth/world -> ground_truth/<left frame>
//   /stereo/ground_truth/left/depth                        only with --depth (record.launch has none)
#include <cv_bridge/cv_bridge.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <rosbag/bag.h>
#include <tf2_msgs/TFMessage.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/core/calibration/light_schedule.h"
#include "embedded_calibration_stereo/core/geometry/config_error.h"
#include "embedded_calibration_stereo/core/geometry/config_io.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/ros/camera_calibration.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/head_pose_truth.h"

namespace ecs_ros = embedded_calibration_stereo;

namespace {

const char* kUsage =
    "usage: render_scenario_bag --config SCENARIO.yaml --out OUT.bag [options]\n"
    "  --config FILE          scenario (sim_config format, e.g. config/sim_rig.yaml)\n"
    "  --out FILE             bag to write (replaced if it exists)\n"
    "  --seconds S            scene time to render (default 20)\n"
    "  --fps F                frame rate (default: the scenario's fps)\n"
    "  --period S             a light window every S seconds from the first frame; 0 = none (default 0)\n"
    "  --calibration-frames N settled light-on frames per window (default 10)\n"
    "  --settle-frames N      frames marked unsettled after each switch (default 2)\n"
    "  --drift FILE           drift script: a YAML list of {time_s, focal_scale, right_rotation_deg,\n"
    "                         thermal_rate_deg_per_s, knock_rotation_deg, knock_translation_m, reset}\n"
    "                         applied as sim/set_drift requests at scene time time_s\n"
    "  --ns NS                namespace of the driver's topics (default stereo)\n"
    "  --start T              stamp of the first frame, seconds since the epoch (default: now)\n"
    "  --left-frame-id ID     (default stereo_left_optical_frame)\n"
    "  --right-frame-id ID    (default stereo_right_optical_frame)\n"
    "  --right-in-left-frame B  true (default): the right image carries the left frame id\n"
    "  --left-camera-info FILE, --right-camera-info FILE\n"
    "                         calibration in force (the driver's files); default: the nominal rig\n"
    "  --no-ground-truth      only the driver's input topics (images, camera_info, calibration_mode)\n"
    "  --depth                also ground_truth/left/depth (32FC1; large)\n"
    "  --lz4                  compress the bag\n"
    "  --snapshot FILE.png    also write the first settled light-on frame's left image next to its\n"
    "                         scene-only ground truth (without --out: only the picture)\n";

struct Options {
  std::string config, out, drift, snapshot;
  double seconds = 20.0;
  double fps = 0.0;  // 0: the scenario's
  ecs::LightScheduleConfig schedule;
  std::string ns = "stereo";
  double start = -1.0;  // < 0: now
  std::string left_frame_id = "stereo_left_optical_frame";
  std::string right_frame_id = "stereo_right_optical_frame";
  bool right_in_left_frame = true;
  std::string left_info, right_info;
  bool ground_truth = true, depth = false, lz4 = false;
};

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

double parseNumber(const std::string& option, const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || !std::isfinite(v))
    throw UsageError(option + ": '" + text + "' is not a number");
  return v;
}

int parseCount(const std::string& option, const std::string& text) {
  const double v = parseNumber(option, text);
  if (v != std::floor(v) || v < 0 || v > 1e6) throw UsageError(option + ": '" + text + "' is not a count");
  return static_cast<int>(v);
}

Options parseOptions(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw UsageError(arg + ": needs a value");
      return argv[++i];
    };
    if (arg == "--config") o.config = value();
    else if (arg == "--out") o.out = value();
    else if (arg == "--seconds") o.seconds = parseNumber(arg, value());
    else if (arg == "--fps") o.fps = parseNumber(arg, value());
    else if (arg == "--period") o.schedule.period_s = parseNumber(arg, value());
    else if (arg == "--calibration-frames") o.schedule.calibration_frames = parseCount(arg, value());
    else if (arg == "--settle-frames") o.schedule.settle_frames = parseCount(arg, value());
    else if (arg == "--drift") o.drift = value();
    else if (arg == "--ns") o.ns = value();
    else if (arg == "--start") o.start = parseNumber(arg, value());
    else if (arg == "--left-frame-id") o.left_frame_id = value();
    else if (arg == "--right-frame-id") o.right_frame_id = value();
    else if (arg == "--right-in-left-frame") {
      const std::string v = value();
      if (v != "true" && v != "false") throw UsageError(arg + ": must be true or false, not '" + v + "'");
      o.right_in_left_frame = v == "true";
    } else if (arg == "--left-camera-info") o.left_info = value();
    else if (arg == "--right-camera-info") o.right_info = value();
    else if (arg == "--no-ground-truth") o.ground_truth = false;
    else if (arg == "--depth") o.depth = true;
    else if (arg == "--lz4") o.lz4 = true;
    else if (arg == "--snapshot") o.snapshot = value();
    else if (arg == "--help" || arg == "-h") throw UsageError("");
    else throw UsageError("unknown option '" + arg + "'");
  }
  if (o.config.empty()) throw UsageError("--config is required");
  if (o.out.empty() && o.snapshot.empty()) throw UsageError("--out is required");
  if (!(o.seconds > 0.0) || o.seconds > 86400.0) throw UsageError("--seconds: must be in (0, 86400]");
  if (o.fps != 0.0 && (!(o.fps > 0.0) || o.fps > 1000.0)) throw UsageError("--fps: must be in (0, 1000]");
  const std::string schedule_problem = o.schedule.validate();
  if (!schedule_problem.empty()) throw UsageError("light schedule: " + schedule_problem);
  if (o.left_info.empty() != o.right_info.empty())
    throw UsageError("--left-camera-info and --right-camera-info go together");
  if (o.start >= 0.0 && o.start > 4e9) throw UsageError("--start: beyond ros::Time");
  // Topic namespace without surrounding slashes.
  while (!o.ns.empty() && o.ns.front() == '/') o.ns.erase(0, 1);
  while (!o.ns.empty() && o.ns.back() == '/') o.ns.pop_back();
  return o;
}

struct DriftStep {
  double time_s = 0.0;
  ecs::DriftRequest request;
};

// The drift script: a YAML list (or a map whose `drift` key is the list) of sim/set_drift
// requests with their scene time. Unknown keys are refused, so a misspelt field is not ignored.
std::vector<DriftStep> loadDriftScript(const std::string& path) {
  std::ifstream in(path);
  if (!in.good()) throw ecs::ConfigError(path, "file not found or not readable");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  // OpenCV's YAML reader wants its "%YAML:1.0" directive; a hand-written script has none.
  if (text.rfind("%YAML", 0) != 0) text = "%YAML:1.0\n---\n" + text;
  cv::FileStorage fs;
  try {
    fs.open(text, cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
  } catch (const cv::Exception& e) {
    throw ecs::ConfigError(path, std::string("malformed YAML: ") + e.err);
  }
  if (!fs.isOpened()) throw ecs::ConfigError(path, "malformed YAML");
  cv::FileNode list = fs.root();
  std::string base = "drift";
  if (list.isMap()) list = list["drift"];
  if (list.empty() || list.isNone()) throw ecs::ConfigError("drift", "missing: the file must be a list of drift steps");
  if (!list.isSeq()) throw ecs::ConfigError("drift", "must be a list of {time_s, ...} maps");
  static const std::set<std::string> kKeys = {"time_s", "focal_scale", "right_rotation_deg", "thermal_rate_deg_per_s",
                                              "knock_rotation_deg", "knock_translation_m", "reset"};
  std::vector<DriftStep> steps;
  for (int i = 0; i < static_cast<int>(list.size()); ++i) {
    const cv::FileNode n = list[i];
    const std::string where = base + "[" + std::to_string(i) + "]";
    if (!n.isMap()) throw ecs::ConfigError(where, "must be a map {time_s: ..., ...}");
    for (const std::string& key : n.keys())
      if (!kKeys.count(key)) throw ecs::ConfigError(where + "." + key, "unknown field");
    DriftStep step;
    const cv::FileNode time = n["time_s"];
    if (time.empty() || time.isNone()) throw ecs::ConfigError(where + ".time_s", "missing");
    step.time_s = ecs::readDouble(n, "time_s", where, 0.0);
    if (step.time_s < 0.0) throw ecs::ConfigError(where + ".time_s", "must be >= 0");
    if (!steps.empty() && step.time_s < steps.back().time_s)
      throw ecs::ConfigError(where + ".time_s", "steps must be in time order");
    ecs::DriftRequest& r = step.request;
    r.focal_scale = ecs::readDouble(n, "focal_scale", where, 1.0);
    r.thermal_rate_deg_per_s = ecs::readDouble(n, "thermal_rate_deg_per_s", where, 0.0);
    for (const auto& [key, vec] : {std::pair<const char*, Eigen::Vector3d*>{"right_rotation_deg", &r.right_rotation_deg},
                                   {"knock_rotation_deg", &r.knock_rotation_deg},
                                   {"knock_translation_m", &r.knock_translation_m}})
      if (!n[key].empty() && !n[key].isNone()) *vec = ecs::readVector3(n, key, where);
    const cv::FileNode reset = n["reset"];
    if (!reset.empty() && !reset.isNone()) {
      if (!reset.isInt() && !(reset.isString() && (reset.string() == "true" || reset.string() == "false")))
        throw ecs::ConfigError(where + ".reset", "must be true or false");
      r.reset = reset.isInt() ? static_cast<int>(reset) != 0 : reset.string() == "true";
    }
    steps.push_back(step);
  }
  return steps;
}

// The calibration in force in the driver: its files when given (checked as the driver checks
// them; a rejected pair is an error here, not a fallback), else the nominal rig.
ecs_ros::StereoCalibration::InForce calibrationInForce(const Options& o, const ecs::StereoRig& rig) {
  ecs_ros::StereoCalibration::InForce in_force;
  std::tie(in_force.left, in_force.right) = ecs_ros::toStereoCameraInfo(rig);
  if (o.left_info.empty()) return in_force;
  for (const std::string* file : {&o.left_info, &o.right_info})
    if (!std::filesystem::exists(*file)) throw ecs::ConfigError(*file, "calibration file not found");
  const auto url = [](const std::string& file) { return "file://" + std::filesystem::absolute(file).string(); };
  ecs_ros::StereoCalibration calibration({"stereo_left", url(o.left_info), "--left-camera-info"},
                                         {"stereo_right", url(o.right_info), "--right-camera-info"},
                                         static_cast<uint32_t>(rig.left.width),
                                         static_cast<uint32_t>(rig.left.height), 10.0);
  calibration.load(in_force.left, in_force.right);
  if (!calibration.problem().empty()) throw ecs::ConfigError("camera info", calibration.problem());
  return calibration.inForce();
}

// Left image | scene-only ground truth, side by side with a gap.
void writeSnapshot(const std::string& path, const ecs::SimFrame& frame) {
  const int gap = 8;
  cv::Mat canvas(frame.left.rows, 2 * frame.left.cols + gap, frame.left.type(), cv::Scalar::all(255));
  frame.left.copyTo(canvas(cv::Rect(0, 0, frame.left.cols, frame.left.rows)));
  frame.left_scene.copyTo(canvas(cv::Rect(frame.left.cols + gap, 0, frame.left.cols, frame.left.rows)));
  if (!cv::imwrite(path, canvas)) throw std::runtime_error("--snapshot: cannot write '" + path + "'");
}

int run(const Options& o) {
  ecs::SimRigConfig config;
  try {
    config = ecs::loadSimRigConfig(o.config);
  } catch (const std::exception& e) {
    throw ecs::ConfigError("--config", "'" + o.config + "': " + e.what());
  }
  std::vector<DriftStep> drift;
  if (!o.drift.empty()) {
    try {
      drift = loadDriftScript(o.drift);
    } catch (const std::exception& e) {
      throw ecs::ConfigError("--drift", "'" + o.drift + "': " + e.what());
    }
  }
  const double fps = o.fps > 0.0 ? o.fps : config.fps;
  const auto frames = static_cast<int64_t>(std::llround(o.seconds * fps));
  const ecs_ros::StereoCalibration::InForce in_force = calibrationInForce(o, config.rig);

  ecs::SimRig sim(config);
  ecs::LightSchedule schedule(o.schedule);
  ecs_ros::HeadPoseTruth head_pose(o.left_frame_id);
  const ros::Time start = o.start >= 0.0 ? ros::Time(o.start) : ros::Time(ros::WallTime::now().toSec());
  const std::string prefix = o.ns.empty() ? "" : "/" + o.ns;
  const std::string encoding = config.encoding;

  const bool write_bag = !o.out.empty();
  const std::string active = o.out + ".active";  // renamed to `out` once complete
  rosbag::Bag bag;
  if (write_bag) {
    bag.open(active, rosbag::bagmode::Write);
    if (o.lz4) bag.setCompression(rosbag::compression::LZ4);
  }
  char light_text[64] = "no light windows";
  if (o.schedule.period_s > 0.0) std::snprintf(light_text, sizeof(light_text), "a light window every %g s", o.schedule.period_s);
  std::printf("render_scenario_bag: %s, %g s at %g fps (%lld frames), %s, %zu drift steps\n", o.config.c_str(),
              o.seconds, fps, static_cast<long long>(frames), light_text, drift.size());
  std::fflush(stdout);

  const auto wall_start = std::chrono::steady_clock::now();
  size_t next_drift = 0, light_windows = 0, messages = 0;
  double switch_time_s = -1e300;  // the light's last switch: never
  bool snapshot_written = o.snapshot.empty();
  for (int64_t k = 0; k < frames && (write_bag || !snapshot_written); ++k) {
    const double time_s = static_cast<double>(k) / fps;
    for (; next_drift < drift.size() && drift[next_drift].time_s <= time_s; ++next_drift) {
      const std::string refusal = sim.setDrift(drift[next_drift].request, drift[next_drift].time_s);
      if (!refusal.empty())
        throw ecs::ConfigError("--drift", "'" + o.drift + "': drift[" + std::to_string(next_drift) + "]: " + refusal);
    }
    const ecs::LightState light = schedule.step(time_s);
    if (light.light_on && light.switched) ++light_windows;
    // As the driver's sim light and sim source pass them: the schedule's level, and the command
    // with the scene time of its last switch (for a scenario with a light response model).
    if (light.switched) switch_time_s = time_s;
    ecs::SimRenderRequest request;
    request.time_s = time_s;
    request.light_level = light.light_level;
    request.noise_seed = static_cast<uint64_t>(k + 1);
    request.has_light_command = true;
    request.light_command.on = light.light_on;
    request.light_command.switch_time_s = switch_time_s;
    const ecs::SimFrame frame = sim.render(request);
    head_pose.update(frame.world_from_left, frame.time_s);
    if (!snapshot_written && light.light_on && light.settled) {
      writeSnapshot(o.snapshot, frame);
      snapshot_written = true;
      std::printf("render_scenario_bag: wrote %s (frame %lld, %.2f s: left image | scene-only ground truth)\n",
                  o.snapshot.c_str(), static_cast<long long>(k), time_s);
    }
    if (!write_bag) continue;

    const ros::Time stamp = start + ros::Duration(time_s);
    std_msgs::Header left_header, right_header;
    left_header.stamp = right_header.stamp = stamp;
    left_header.frame_id = o.left_frame_id;
    right_header.frame_id = o.right_in_left_frame ? o.left_frame_id : o.right_frame_id;
    // As the driver's capture loop builds them.
    sensor_msgs::CameraInfo left_info = in_force.left, right_info = in_force.right;
    left_info.header = left_header;
    right_info.header = right_header;
    ecs_ros::CalibrationMode mode;
    mode.header = left_header;
    mode.light_on = light.light_on;
    mode.settled = light.settled;
    mode.calibration_epoch = in_force.epoch;
    const auto write = [&](const std::string& topic, const auto& msg) {
      bag.write(topic, stamp, msg);
      ++messages;
    };
    write(prefix + "/left/image_raw", cv_bridge::CvImage(left_header, encoding, frame.left).toImageMsg());
    write(prefix + "/left/camera_info", left_info);
    write(prefix + "/right/image_raw", cv_bridge::CvImage(right_header, encoding, frame.right).toImageMsg());
    write(prefix + "/right/camera_info", right_info);
    write(prefix + "/calibration_mode", mode);
    if (o.ground_truth) {
      auto truth_infos = ecs_ros::toStereoCameraInfo(frame.truth);
      truth_infos.first.header = left_header;
      truth_infos.second.header = right_header;
      auto observations = ecs_ros::toMsg(frame.observations);
      observations.header = left_header;
      write(prefix + "/ground_truth/left/camera_info", truth_infos.first);
      write(prefix + "/ground_truth/right/camera_info", truth_infos.second);
      write(prefix + "/ground_truth/observations", observations);
      write(prefix + "/ground_truth/left/image_scene",
            cv_bridge::CvImage(left_header, encoding, frame.left_scene).toImageMsg());
      write(prefix + "/ground_truth/right/image_scene",
            cv_bridge::CvImage(right_header, encoding, frame.right_scene).toImageMsg());
      write(prefix + "/ground_truth/head_pose", head_pose.odometry(stamp));
      tf2_msgs::TFMessage tf;
      tf.transforms.push_back(head_pose.transform(stamp));
      write("/tf", tf);
      if (o.depth)
        write(prefix + "/ground_truth/left/depth", cv_bridge::CvImage(left_header, "32FC1", frame.left_depth).toImageMsg());
    }
    const int64_t every = std::max<int64_t>(1, static_cast<int64_t>(std::llround(5.0 * fps)));
    if ((k + 1) % every == 0 || k + 1 == frames) {
      const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
      std::printf("render_scenario_bag: %.1f / %.1f s rendered (%lld frames, %.1f s wall)\n", (k + 1) / fps,
                  o.seconds, static_cast<long long>(k + 1), wall);
      std::fflush(stdout);
    }
  }
  if (!snapshot_written)
    throw std::runtime_error("--snapshot: no settled light-on frame in the rendered time (set --period)");
  if (!write_bag) return 0;
  bag.close();
  std::filesystem::rename(active, o.out);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  std::printf("render_scenario_bag: wrote %s: %lld frames (%.1f s from stamp %.3f), %zu messages, %zu light "
              "windows, %zu drift steps applied, %.0f MB, %.1f ms per frame\n",
              o.out.c_str(), static_cast<long long>(frames), frames / fps, start.toSec(), messages, light_windows,
              next_drift, std::filesystem::file_size(o.out) / 1e6, 1e3 * wall / std::max<int64_t>(frames, 1));
  std::printf("render_scenario_bag: topics %s/{left,right}/image_raw, %s/{left,right}/camera_info, "
              "%s/calibration_mode%s\n",
              prefix.c_str(), prefix.c_str(), prefix.c_str(),
              o.ground_truth ? (", " + prefix + "/ground_truth/{left,right}/image_scene, " + prefix +
                                "/ground_truth/{left,right}/camera_info, " + prefix + "/ground_truth/observations, " +
                                prefix + "/ground_truth/head_pose, /tf" +
                                (o.depth ? ", " + prefix + "/ground_truth/left/depth" : ""))
                                   .c_str()
                             : "");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options options;
  try {
    options = parseOptions(argc, argv);
  } catch (const UsageError& e) {
    if (std::string(e.what()).empty()) {
      std::fputs(kUsage, stdout);
      return 0;
    }
    std::fprintf(stderr, "render_scenario_bag: %s\n%s", e.what(), kUsage);
    return 2;
  }
  ros::Time::init();  // stamps only: no master is contacted
  try {
    return run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "render_scenario_bag: %s\n", e.what());
    if (!options.out.empty()) std::filesystem::remove(options.out + ".active");
    return 1;
  }
}
