// Renders N seconds of a simulated scenario into a rosbag, as launch/record.launch records the
// sim driver (ground_truth:=true): the same topics, types, frame ids and stamps, without a ROS
// master and without paying the renderer at replay time. Frame k (from 0) is the scene at time
// k / fps, stamped start + k / fps; the light follows the driver's schedule
// (core::LightSchedule: period, calibration frames, settle frames) and an optional drift script
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
#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/ros/camera_calibration.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/head_pose_truth.h"

namespace core = embedded_calibration_stereo::core;

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
  core::LightScheduleConfig schedule;
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

// The options of what to render (scenario, output, time, light schedule, drift); false when
// `arg` is none of them. value() takes the option's value.
template <typename Value>
bool parseRenderOption(const std::string& arg, const Value& value, Options* o) {
  if (arg == "--config") o->config = value();
  else if (arg == "--out") o->out = value();
  else if (arg == "--seconds") o->seconds = parseNumber(arg, value());
  else if (arg == "--fps") o->fps = parseNumber(arg, value());
  else if (arg == "--period") o->schedule.period_s = parseNumber(arg, value());
  else if (arg == "--calibration-frames") o->schedule.calibration_frames = parseCount(arg, value());
  else if (arg == "--settle-frames") o->schedule.settle_frames = parseCount(arg, value());
  else if (arg == "--drift") o->drift = value();
  else if (arg == "--snapshot") o->snapshot = value();
  else return false;
  return true;
}

// The options of how the driver would publish it (topics, frames, stamps, calibration, what is
// recorded); false when `arg` is none of them.
template <typename Value>
bool parsePublishOption(const std::string& arg, const Value& value, Options* o) {
  if (arg == "--ns") o->ns = value();
  else if (arg == "--start") o->start = parseNumber(arg, value());
  else if (arg == "--left-frame-id") o->left_frame_id = value();
  else if (arg == "--right-frame-id") o->right_frame_id = value();
  else if (arg == "--right-in-left-frame") {
    const std::string v = value();
    if (v != "true" && v != "false") throw UsageError(arg + ": must be true or false, not '" + v + "'");
    o->right_in_left_frame = v == "true";
  } else if (arg == "--left-camera-info") o->left_info = value();
  else if (arg == "--right-camera-info") o->right_info = value();
  else if (arg == "--no-ground-truth") o->ground_truth = false;
  else if (arg == "--depth") o->depth = true;
  else if (arg == "--lz4") o->lz4 = true;
  else return false;
  return true;
}

// Refuses what the options cannot mean together; the namespace without surrounding slashes.
void checkOptions(Options* o) {
  if (o->config.empty()) throw UsageError("--config is required");
  if (o->out.empty() && o->snapshot.empty()) throw UsageError("--out is required");
  if (!(o->seconds > 0.0) || o->seconds > 86400.0) throw UsageError("--seconds: must be in (0, 86400]");
  if (o->fps != 0.0 && (!(o->fps > 0.0) || o->fps > 1000.0)) throw UsageError("--fps: must be in (0, 1000]");
  const std::string schedule_problem = o->schedule.validate();
  if (!schedule_problem.empty()) throw UsageError("light schedule: " + schedule_problem);
  if (o->left_info.empty() != o->right_info.empty())
    throw UsageError("--left-camera-info and --right-camera-info go together");
  if (o->start >= 0.0 && o->start > 4e9) throw UsageError("--start: beyond ros::Time");
  // Topic namespace without surrounding slashes.
  while (!o->ns.empty() && o->ns.front() == '/') o->ns.erase(0, 1);
  while (!o->ns.empty() && o->ns.back() == '/') o->ns.pop_back();
}

Options parseOptions(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw UsageError(arg + ": needs a value");
      return argv[++i];
    };
    if (parseRenderOption(arg, value, &o) || parsePublishOption(arg, value, &o)) continue;
    if (arg == "--help" || arg == "-h") throw UsageError("");
    throw UsageError("unknown option '" + arg + "'");
  }
  checkOptions(&o);
  return o;
}

struct DriftStep {
  double time_s = 0.0;
  core::DriftRequest request;
};

// The drift script's list: the YAML document's root, or its `drift` key when the root is a map.
// fs holds the document (the nodes point into it).
cv::FileNode driftList(const std::string& path, cv::FileStorage* fs) {
  std::ifstream in(path);
  if (!in.good()) throw core::ConfigError(path, "file not found or not readable");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  // OpenCV's YAML reader wants its "%YAML:1.0" directive; a hand-written script has none.
  if (text.rfind("%YAML", 0) != 0) text = "%YAML:1.0\n---\n" + text;
  try {
    fs->open(text, cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
  } catch (const cv::Exception& e) {
    throw core::ConfigError(path, std::string("malformed YAML: ") + e.err);
  }
  if (!fs->isOpened()) throw core::ConfigError(path, "malformed YAML");
  cv::FileNode list = fs->root();
  if (list.isMap()) list = list["drift"];
  if (list.empty() || list.isNone()) throw core::ConfigError("drift", "missing: the file must be a list of drift steps");
  if (!list.isSeq()) throw core::ConfigError("drift", "must be a list of {time_s, ...} maps");
  return list;
}

// The request's fields of one step (time_s aside), defaults for those it leaves out.
core::DriftRequest driftRequest(const cv::FileNode& n, const std::string& where) {
  core::DriftRequest r;
  r.focal_scale = core::readDouble(n, "focal_scale", where, 1.0);
  r.thermal_rate_deg_per_s = core::readDouble(n, "thermal_rate_deg_per_s", where, 0.0);
  for (const auto& [key, vec] : {std::pair<const char*, Eigen::Vector3d*>{"right_rotation_deg", &r.right_rotation_deg},
                                 {"knock_rotation_deg", &r.knock_rotation_deg},
                                 {"knock_translation_m", &r.knock_translation_m}})
    if (!n[key].empty() && !n[key].isNone()) *vec = core::readVector3(n, key, where);
  const cv::FileNode reset = n["reset"];
  if (!reset.empty() && !reset.isNone()) {
    if (!reset.isInt() && !(reset.isString() && (reset.string() == "true" || reset.string() == "false")))
      throw core::ConfigError(where + ".reset", "must be true or false");
    r.reset = reset.isInt() ? static_cast<int>(reset) != 0 : reset.string() == "true";
  }
  return r;
}

// Step `where` of the script; previous: the step before it (nullptr for the first).
DriftStep driftStep(const cv::FileNode& n, const std::string& where, const DriftStep* previous) {
  static const std::set<std::string> kKeys = {"time_s", "focal_scale", "right_rotation_deg", "thermal_rate_deg_per_s",
                                              "knock_rotation_deg", "knock_translation_m", "reset"};
  if (!n.isMap()) throw core::ConfigError(where, "must be a map {time_s: ..., ...}");
  for (const std::string& key : n.keys())
    if (!kKeys.count(key)) throw core::ConfigError(where + "." + key, "unknown field");
  DriftStep step;
  const cv::FileNode time = n["time_s"];
  if (time.empty() || time.isNone()) throw core::ConfigError(where + ".time_s", "missing");
  step.time_s = core::readDouble(n, "time_s", where, 0.0);
  if (step.time_s < 0.0) throw core::ConfigError(where + ".time_s", "must be >= 0");
  if (previous && step.time_s < previous->time_s) throw core::ConfigError(where + ".time_s", "steps must be in time order");
  step.request = driftRequest(n, where);
  return step;
}

// The drift script: a YAML list (or a map whose `drift` key is the list) of sim/set_drift
// requests with their scene time. Unknown keys are refused, so a misspelt field is not ignored.
std::vector<DriftStep> loadDriftScript(const std::string& path) {
  cv::FileStorage fs;
  const cv::FileNode list = driftList(path, &fs);
  std::vector<DriftStep> steps;
  for (int i = 0; i < static_cast<int>(list.size()); ++i)
    steps.push_back(driftStep(list[i], "drift[" + std::to_string(i) + "]", steps.empty() ? nullptr : &steps.back()));
  return steps;
}

// The calibration in force in the driver: its files when given (checked as the driver checks
// them; a rejected pair is an error here, not a fallback), else the nominal rig.
ecs_ros::StereoCalibration::InForce calibrationInForce(const Options& o, const core::StereoRig& rig) {
  ecs_ros::StereoCalibration::InForce in_force;
  std::tie(in_force.left, in_force.right) = ecs_ros::toStereoCameraInfo(rig);
  if (o.left_info.empty()) return in_force;
  for (const std::string* file : {&o.left_info, &o.right_info})
    if (!std::filesystem::exists(*file)) throw core::ConfigError(*file, "calibration file not found");
  const auto url = [](const std::string& file) { return "file://" + std::filesystem::absolute(file).string(); };
  ecs_ros::StereoCalibration calibration({"stereo_left", url(o.left_info), "--left-camera-info"},
                                         {"stereo_right", url(o.right_info), "--right-camera-info"},
                                         static_cast<uint32_t>(rig.left.width),
                                         static_cast<uint32_t>(rig.left.height), 10.0);
  calibration.load(in_force.left, in_force.right);
  if (!calibration.problem().empty()) throw core::ConfigError("camera info", calibration.problem());
  return calibration.inForce();
}

// Left image | scene-only ground truth, side by side with a gap.
void writeSnapshot(const std::string& path, const core::SimFrame& frame) {
  const int gap = 8;
  cv::Mat canvas(frame.left.rows, 2 * frame.left.cols + gap, frame.left.type(), cv::Scalar::all(255));
  frame.left.copyTo(canvas(cv::Rect(0, 0, frame.left.cols, frame.left.rows)));
  frame.left_scene.copyTo(canvas(cv::Rect(frame.left.cols + gap, 0, frame.left.cols, frame.left.rows)));
  if (!cv::imwrite(path, canvas)) throw std::runtime_error("--snapshot: cannot write '" + path + "'");
}

// What a run renders: the scenario, its drift script, the frame rate and count, and the
// calibration in force.
struct Scenario {
  core::SimRigConfig config;
  std::vector<DriftStep> drift;
  double fps = 0.0;
  int64_t frames = 0;
  ecs_ros::StereoCalibration::InForce in_force;
};

Scenario loadScenario(const Options& o) {
  Scenario s;
  try {
    s.config = core::loadSimRigConfig(o.config);
  } catch (const std::exception& e) {
    throw core::ConfigError("--config", "'" + o.config + "': " + e.what());
  }
  if (!o.drift.empty()) {
    try {
      s.drift = loadDriftScript(o.drift);
    } catch (const std::exception& e) {
      throw core::ConfigError("--drift", "'" + o.drift + "': " + e.what());
    }
  }
  s.fps = o.fps > 0.0 ? o.fps : s.config.fps;
  s.frames = static_cast<int64_t>(std::llround(o.seconds * s.fps));
  s.in_force = calibrationInForce(o, s.config.rig);
  return s;
}

// Renders a scenario frame by frame into the bag (and the snapshot), as the driver would
// publish it.
class ScenarioRun {
 public:
  ScenarioRun(const Options& o, const Scenario& s)
      : o_(o), s_(s), sim_(s.config), schedule_(o.schedule), head_pose_(o.left_frame_id),
        start_(o.start >= 0.0 ? ros::Time(o.start) : ros::Time(ros::WallTime::now().toSec())),
        prefix_(o.ns.empty() ? "" : "/" + o.ns), write_bag_(!o.out.empty()), active_(o.out + ".active"),
        snapshot_written_(o.snapshot.empty()) {}

  int run() {
    openBag();
    wall_start_ = std::chrono::steady_clock::now();
    for (int64_t k = 0; k < s_.frames && (write_bag_ || !snapshot_written_); ++k) {
      const double time_s = static_cast<double>(k) / s_.fps;
      applyDrift(time_s);
      const core::LightState light = schedule_.step(time_s);
      const core::SimFrame frame = render(k, time_s, light);
      head_pose_.update(frame.world_from_left, frame.time_s);
      if (!snapshot_written_ && light.light_on && light.settled) writeSnapshotOf(frame, k, time_s);
      if (!write_bag_) continue;
      writeFrame(frame, light, start_ + ros::Duration(time_s));
      reportProgress(k);
    }
    if (!snapshot_written_)
      throw std::runtime_error("--snapshot: no settled light-on frame in the rendered time (set --period)");
    if (!write_bag_) return 0;
    finish();
    return 0;
  }

 private:
  void openBag() {
    if (write_bag_) {
      bag_.open(active_, rosbag::bagmode::Write);
      if (o_.lz4) bag_.setCompression(rosbag::compression::LZ4);
    }
    char light_text[64] = "no light windows";
    if (o_.schedule.period_s > 0.0)
      std::snprintf(light_text, sizeof(light_text), "a light window every %g s", o_.schedule.period_s);
    std::printf("render_scenario_bag: %s, %g s at %g fps (%lld frames), %s, %zu drift steps\n", o_.config.c_str(),
                o_.seconds, s_.fps, static_cast<long long>(s_.frames), light_text, s_.drift.size());
    std::fflush(stdout);
  }

  // The drift script's requests due by scene time time_s.
  void applyDrift(double time_s) {
    for (; next_drift_ < s_.drift.size() && s_.drift[next_drift_].time_s <= time_s; ++next_drift_) {
      const std::string refusal = sim_.setDrift(s_.drift[next_drift_].request, s_.drift[next_drift_].time_s);
      if (!refusal.empty())
        throw core::ConfigError("--drift", "'" + o_.drift + "': drift[" + std::to_string(next_drift_) + "]: " + refusal);
    }
  }

  core::SimFrame render(int64_t k, double time_s, const core::LightState& light) {
    if (light.light_on && light.switched) ++light_windows_;
    // As the driver's sim light and sim source pass them: the schedule's level, and the command
    // with the scene time of its last switch (for a scenario with a light response model).
    if (light.switched) switch_time_s_ = time_s;
    core::SimRenderRequest request;
    request.time_s = time_s;
    request.light_level = light.light_level;
    request.noise_seed = static_cast<uint64_t>(k + 1);
    request.has_light_command = true;
    request.light_command.on = light.light_on;
    request.light_command.switch_time_s = switch_time_s_;
    return sim_.render(request);
  }

  void writeSnapshotOf(const core::SimFrame& frame, int64_t k, double time_s) {
    writeSnapshot(o_.snapshot, frame);
    snapshot_written_ = true;
    std::printf("render_scenario_bag: wrote %s (frame %lld, %.2f s: left image | scene-only ground truth)\n",
                o_.snapshot.c_str(), static_cast<long long>(k), time_s);
  }

  template <typename Message>
  void write(const std::string& topic, const ros::Time& stamp, const Message& msg) {
    bag_.write(topic, stamp, msg);
    ++messages_;
  }

  // The driver's topics, as its capture loop builds them.
  void writeFrame(const core::SimFrame& frame, const core::LightState& light, const ros::Time& stamp) {
    std_msgs::Header left_header, right_header;
    left_header.stamp = right_header.stamp = stamp;
    left_header.frame_id = o_.left_frame_id;
    right_header.frame_id = o_.right_in_left_frame ? o_.left_frame_id : o_.right_frame_id;
    sensor_msgs::CameraInfo left_info = s_.in_force.left, right_info = s_.in_force.right;
    left_info.header = left_header;
    right_info.header = right_header;
    ecs_ros::CalibrationMode mode;
    mode.header = left_header;
    mode.light_on = light.light_on;
    mode.settled = light.settled;
    mode.calibration_epoch = s_.in_force.epoch;
    const std::string& encoding = s_.config.encoding;
    write(prefix_ + "/left/image_raw", stamp, cv_bridge::CvImage(left_header, encoding, frame.left).toImageMsg());
    write(prefix_ + "/left/camera_info", stamp, left_info);
    write(prefix_ + "/right/image_raw", stamp, cv_bridge::CvImage(right_header, encoding, frame.right).toImageMsg());
    write(prefix_ + "/right/camera_info", stamp, right_info);
    write(prefix_ + "/calibration_mode", stamp, mode);
    if (o_.ground_truth) writeGroundTruth(frame, left_header, right_header);
  }

  void writeGroundTruth(const core::SimFrame& frame, const std_msgs::Header& left_header,
                        const std_msgs::Header& right_header) {
    const ros::Time& stamp = left_header.stamp;
    const std::string& encoding = s_.config.encoding;
    auto truth_infos = ecs_ros::toStereoCameraInfo(frame.truth);
    truth_infos.first.header = left_header;
    truth_infos.second.header = right_header;
    auto observations = ecs_ros::toMsg(frame.observations);
    observations.header = left_header;
    write(prefix_ + "/ground_truth/left/camera_info", stamp, truth_infos.first);
    write(prefix_ + "/ground_truth/right/camera_info", stamp, truth_infos.second);
    write(prefix_ + "/ground_truth/observations", stamp, observations);
    write(prefix_ + "/ground_truth/left/image_scene", stamp,
          cv_bridge::CvImage(left_header, encoding, frame.left_scene).toImageMsg());
    write(prefix_ + "/ground_truth/right/image_scene", stamp,
          cv_bridge::CvImage(right_header, encoding, frame.right_scene).toImageMsg());
    write(prefix_ + "/ground_truth/head_pose", stamp, head_pose_.odometry(stamp));
    tf2_msgs::TFMessage tf;
    tf.transforms.push_back(head_pose_.transform(stamp));
    write("/tf", stamp, tf);
    if (o_.depth)
      write(prefix_ + "/ground_truth/left/depth", stamp,
            cv_bridge::CvImage(left_header, "32FC1", frame.left_depth).toImageMsg());
  }

  double wallSeconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start_).count();
  }

  // A line every 5 s of scene time and at the end.
  void reportProgress(int64_t k) {
    const int64_t every = std::max<int64_t>(1, static_cast<int64_t>(std::llround(5.0 * s_.fps)));
    if ((k + 1) % every == 0 || k + 1 == s_.frames) {
      const double wall = wallSeconds();
      std::printf("render_scenario_bag: %.1f / %.1f s rendered (%lld frames, %.1f s wall)\n", (k + 1) / s_.fps,
                  o_.seconds, static_cast<long long>(k + 1), wall);
      std::fflush(stdout);
    }
  }

  // Closes the bag, gives it its name and prints what it holds.
  void finish() {
    bag_.close();
    std::filesystem::rename(active_, o_.out);
    const double wall = wallSeconds();
    const int64_t frames = s_.frames;
    std::printf("render_scenario_bag: wrote %s: %lld frames (%.1f s from stamp %.3f), %zu messages, %zu light "
                "windows, %zu drift steps applied, %.0f MB, %.1f ms per frame\n",
                o_.out.c_str(), static_cast<long long>(frames), frames / s_.fps, start_.toSec(), messages_,
                light_windows_, next_drift_, std::filesystem::file_size(o_.out) / 1e6,
                1e3 * wall / std::max<int64_t>(frames, 1));
    const std::string& prefix = prefix_;
    std::printf("render_scenario_bag: topics %s/{left,right}/image_raw, %s/{left,right}/camera_info, "
                "%s/calibration_mode%s\n",
                prefix.c_str(), prefix.c_str(), prefix.c_str(),
                o_.ground_truth ? (", " + prefix + "/ground_truth/{left,right}/image_scene, " + prefix +
                                   "/ground_truth/{left,right}/camera_info, " + prefix + "/ground_truth/observations, " +
                                   prefix + "/ground_truth/head_pose, /tf" +
                                   (o_.depth ? ", " + prefix + "/ground_truth/left/depth" : ""))
                                      .c_str()
                                : "");
  }

  const Options& o_;
  const Scenario& s_;
  core::SimRig sim_;
  core::LightSchedule schedule_;
  ecs_ros::HeadPoseTruth head_pose_;
  const ros::Time start_;
  const std::string prefix_;
  const bool write_bag_;
  const std::string active_;  // renamed to `out` once complete
  rosbag::Bag bag_;
  std::chrono::steady_clock::time_point wall_start_;
  size_t next_drift_ = 0, light_windows_ = 0, messages_ = 0;
  double switch_time_s_ = -1e300;  // the light's last switch: never
  bool snapshot_written_;
};

int run(const Options& o) {
  const Scenario scenario = loadScenario(o);
  ScenarioRun renderer(o, scenario);
  return renderer.run();
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
