// Loading and validation of the simulated rig's configuration (config/sim_rig.yaml).
#include <cmath>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <set>
#include <utility>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {

namespace {

// Largest texture side in texels: bounds the memory a plane can take (4096^2 floats = 64 MB).
constexpr double kMaxTexels = 4096.0;
constexpr int kMaxBlurSamples = 64;
// Where Debian's python3-skimage installs its sample photographs ("skimage:NAME" in a config).
const char* const kSkimageData = "/usr/lib/python3/dist-packages/skimage/data/";

using Problem = std::pair<std::string, std::string>;  // (parameter path, what is wrong)

Problem planeProblem(const ScenePlane& p, const std::string& key) {
  if (!p.origin.allFinite()) return {key + ".origin", "must be finite"};
  if (!(std::abs(p.u_axis.norm() - 1.0) < 1e-6)) return {key + ".u_axis", "must be a unit vector"};
  if (!(std::abs(p.v_axis.norm() - 1.0) < 1e-6)) return {key + ".v_axis", "must be a unit vector"};
  if (!(std::abs(p.u_axis.dot(p.v_axis)) < 1e-6)) return {key + ".v_axis", "must be orthogonal to u_axis"};
  if (!(p.width_m > 0) || !std::isfinite(p.width_m)) return {key + ".width_m", "must be > 0"};
  if (!(p.height_m > 0) || !std::isfinite(p.height_m)) return {key + ".height_m", "must be > 0"};
  if (!(p.texel_m > 0) || !std::isfinite(p.texel_m)) return {key + ".texel_m", "must be > 0"};
  // (A photograph is shrunk to fit instead.)
  if (p.texture_image.empty() && (p.width_m / p.texel_m > kMaxTexels || p.height_m / p.texel_m > kMaxTexels))
    return {key + ".texel_m", "too small: the texture would exceed 4096 texels per side"};
  if (!p.texture_image.empty()) {
    const Eigen::Vector2d& tile = p.texture_tile_m;
    if (!(tile.allFinite() && ((tile.x() == 0 && tile.y() == 0) || (tile.x() > 0 && tile.y() > 0))))
      return {key + ".texture.tile_m", "must be two sizes > 0 m (or absent: the image is stretched over the plane)"};
    if (!cv::haveImageReader(p.texture_image))
      return {key + ".texture.image", "cannot read the image '" + p.texture_image + "' (missing or not an image)"};
  }
  return {"", ""};
}

Problem trajectoryProblem(const SimTrajectory& t, const std::string& key) {
  const ConfigProblem p = t.problem();
  if (p.ok()) return {"", ""};
  return {key + "." + p.parameter, p.problem};
}

bool inRange(double v, double lo, double hi) { return v >= lo && v <= hi; }  // false for NaN

// The ghost (the reflection off the cover glass) and the vignetting.
Problem ghostAndVignettingProblem(const SimOpticsConfig& o) {
  const SimGhostConfig& g = o.ghost;
  if (!inRange(g.thickness_mm, 0.0, 20.0)) return {"optics.ghost.thickness_mm", "must be in [0,20] mm"};
  if (!(g.angle_deg > 0.0 && g.angle_deg <= 90.0)) return {"optics.ghost.angle_deg", "must be in (0,90] deg"};
  if (!inRange(g.refractive_index, 1.0, 3.0)) return {"optics.ghost.refractive_index", "must be in [1,3]"};
  if (!inRange(g.back_reflectance, 0.0, 0.5)) return {"optics.ghost.back_reflectance", "must be in [0,0.5]"};
  if (!inRange(g.direction_deg, -360.0, 360.0)) return {"optics.ghost.direction_deg", "must be in [-360,360] deg"};
  if (!inRange(o.vignetting.scene, 0.0, 4.0)) return {"optics.vignetting.scene", "must be in [0,4]"};
  if (!inRange(o.vignetting.device, 0.0, 4.0)) return {"optics.vignetting.device", "must be in [0,4]"};
  return {"", ""};
}

// The exposure (fixed or automatic gain) and its time within a frame.
Problem exposureProblem(const SimExposureConfig& e, double fps) {
  if (e.mode != "fixed" && e.mode != "auto") return {"optics.exposure.mode", "must be fixed or auto"};
  if (!inRange(e.min_gain, 1e-3, 64.0)) return {"optics.exposure.min_gain", "must be in [0.001,64]"};
  if (!inRange(e.max_gain, e.min_gain, 64.0))
    return {"optics.exposure.max_gain", "must be in [optics.exposure.min_gain,64]"};
  if (e.mode == "auto" ? !inRange(e.gain, e.min_gain, e.max_gain) : !inRange(e.gain, 1e-3, 64.0))
    return {"optics.exposure.gain", e.mode == "auto" ? "must be in [min_gain,max_gain]" : "must be in [0.001,64]"};
  if (!(e.target_mean > 0.0 && e.target_mean < 255.0)) return {"optics.exposure.target_mean", "must be in (0,255) grey levels"};
  if (!inRange(e.time_constant_frames, 0.1, 1e4))
    return {"optics.exposure.time_constant_frames", "must be in [0.1,10000] frames"};
  if (!inRange(e.time_s, 0.0, 1.0 / fps)) return {"optics.exposure.time_s", "must be in [0,1/fps] s"};
  return {"", ""};
}

// The light's response and the sensor.
Problem lightAndSensorProblem(const SimOpticsConfig& o) {
  const SimLightResponseConfig& l = o.light;
  if (l.model != "schedule" && l.model != "response") return {"optics.light.model", "must be schedule or response"};
  if (!inRange(l.rise_time_s, 0.0, 10.0)) return {"optics.light.rise_time_s", "must be in [0,10] s"};
  if (!inRange(l.fall_time_s, 0.0, 10.0)) return {"optics.light.fall_time_s", "must be in [0,10] s"};
  if (!inRange(l.delay_s, 0.0, 10.0)) return {"optics.light.delay_s", "must be in [0,10] s"};
  const SimSensorConfig& s = o.sensor;
  if (!inRange(s.gain_e_per_dn, 0.01, 1e5)) return {"optics.sensor.gain_e_per_dn", "must be in [0.01,100000] e-/grey level"};
  if (!inRange(s.read_noise_e, 0.0, 1e4)) return {"optics.sensor.read_noise_e", "must be in [0,10000] e-"};
  if (!inRange(s.full_well_e, 1.0, 1e7)) return {"optics.sensor.full_well_e", "must be in [1,1e7] e-"};
  return {"", ""};
}

// The real-head optics (ghost, vignetting, exposure, light response, sensor).
Problem findRealOpticsProblem(const SimOpticsConfig& o, double fps) {
  Problem p = ghostAndVignettingProblem(o);
  if (p.first.empty()) p = exposureProblem(o.exposure, fps);
  if (p.first.empty()) p = lightAndSensorProblem(o);
  return p;
}

// The scene's planes and movers and the head's trajectory.
Problem sceneProblem(const SimRigConfig& c) {
  for (size_t i = 0; i < c.scene.planes.size(); ++i) {
    const Problem p = planeProblem(c.scene.planes[i], "scene.planes[" + std::to_string(i) + "]");
    if (!p.first.empty()) return p;
  }
  for (size_t i = 0; i < c.scene.movers.size(); ++i) {
    const std::string key = "scene.movers[" + std::to_string(i) + "]";
    Problem p = planeProblem(c.scene.movers[i].panel, key);
    if (!p.first.empty()) return p;
    p = trajectoryProblem(c.scene.movers[i].trajectory, key + ".trajectory");
    if (!p.first.empty()) return p;
  }
  return trajectoryProblem(c.trajectory, "trajectory");
}

// The image formation: motion blur, optics, noise, frame rate.
Problem imagingProblem(const SimRigConfig& c) {
  if (!(c.motion_blur.samples >= 1 && c.motion_blur.samples <= kMaxBlurSamples))
    return {"motion_blur.samples", "must be in [1, 64] (1 = no motion blur)"};
  if (!(std::isfinite(c.motion_blur.exposure_s) && c.motion_blur.exposure_s >= 0.0 &&
        c.motion_blur.exposure_s <= 1.0 / c.fps))
    return {"motion_blur.exposure_s", "must be in [0, 1/fps] s (an exposure cannot outlast the frame)"};
  const SimOpticsConfig& o = c.optics;
  const std::pair<const char*, double> unit_values[] = {{"optics.transmittance", o.transmittance},
                                                        {"optics.reflectance", o.reflectance},
                                                        {"optics.device_white", o.device_white},
                                                        {"optics.device_black", o.device_black}};
  for (const auto& kv : unit_values)
    if (!(kv.second >= 0.0 && kv.second <= 1.0)) return {kv.first, "must be in [0,1]"};
  if (!(o.psf_sigma_px >= 0.0 && o.psf_sigma_px <= 5.0)) return {"optics.psf_sigma_px", "must be in [0,5] pixels"};
  if (!(o.device_black < o.device_white)) return {"optics.device_black", "must be < optics.device_white"};
  if (!(c.noise_sigma >= 0.0 && c.noise_sigma <= 64.0)) return {"noise_sigma", "must be in [0,64] grey levels"};
  if (!(c.fps > 0.0 && c.fps <= 1000.0)) return {"fps", "must be in (0,1000]"};
  return findRealOpticsProblem(o, c.fps);
}

Problem findProblem(const SimRigConfig& c) {
  std::string e = c.rig.validate();
  if (!e.empty()) return {"rig", e};
  e = c.device.validate();
  if (!e.empty()) return {"device", e};
  if (c.rig.left.width != c.rig.right.width || c.rig.left.height != c.rig.right.height)
    return {"rig.right", "must have the same image size as rig.left"};
  Problem p = sceneProblem(c);
  if (p.first.empty()) p = imagingProblem(c);
  if (!p.first.empty()) return p;
  if (c.encoding != "mono8" && c.encoding != "bgr8") return {"encoding", "must be mono8 or bgr8"};
  return {"", ""};
}

bool readBool(const cv::FileNode& node, const std::string& key, const std::string& path, bool fallback) {
  const cv::FileNode n = node[key];
  if (n.empty() || n.isNone()) return fallback;
  if (n.isInt()) return static_cast<int>(n) != 0;
  if (n.isString()) {
    const std::string s = static_cast<std::string>(n);
    if (s == "true" || s == "True") return true;
    if (s == "false" || s == "False") return false;
  }
  throw ConfigError(path + "." + key, "must be true or false");
}

// A string field; OpenCV's YAML reader keeps a trailing "# comment" in unquoted strings: cut it off.
std::string readOptionalString(const cv::FileNode& node, const std::string& key, const std::string& path,
                       const std::string& fallback) {
  const cv::FileNode n = node[key];
  if (n.empty() || n.isNone()) return fallback;
  if (!n.isString()) throw ConfigError(path + "." + key, "must be a string");
  std::string value = static_cast<std::string>(n);
  value = value.substr(0, value.find('#'));
  value.erase(value.find_last_not_of(" \t") + 1);
  return value;
}

// An optional sub-map of `node`; empty when absent.
cv::FileNode optionalMap(const cv::FileNode& node, const std::string& key, const std::string& path) {
  const cv::FileNode n = node[key];
  if (n.empty() || n.isNone()) return cv::FileNode();
  if (!n.isMap()) throw ConfigError(path + "." + key, "must be a map");
  return n;
}

void loadRealOptics(const cv::FileNode& optics, SimOpticsConfig* o) {
  const cv::FileNode ghost = optionalMap(optics, "ghost", "optics");
  if (!ghost.empty()) {
    const std::string p = "optics.ghost";
    SimGhostConfig& g = o->ghost;
    g.thickness_mm = readDouble(ghost, "thickness_mm", p, g.thickness_mm);
    g.angle_deg = readDouble(ghost, "angle_deg", p, g.angle_deg);
    g.refractive_index = readDouble(ghost, "refractive_index", p, g.refractive_index);
    g.back_reflectance = readDouble(ghost, "back_reflectance", p, g.back_reflectance);
    g.direction_deg = readDouble(ghost, "direction_deg", p, g.direction_deg);
  }
  const cv::FileNode vignetting = optionalMap(optics, "vignetting", "optics");
  if (!vignetting.empty()) {
    o->vignetting.scene = readDouble(vignetting, "scene", "optics.vignetting", o->vignetting.scene);
    o->vignetting.device = readDouble(vignetting, "device", "optics.vignetting", o->vignetting.device);
  }
  const cv::FileNode exposure = optionalMap(optics, "exposure", "optics");
  if (!exposure.empty()) {
    const std::string p = "optics.exposure";
    SimExposureConfig& e = o->exposure;
    e.mode = readOptionalString(exposure, "mode", p, e.mode);
    e.gain = readDouble(exposure, "gain", p, e.gain);
    e.target_mean = readDouble(exposure, "target_mean", p, e.target_mean);
    e.time_constant_frames = readDouble(exposure, "time_constant_frames", p, e.time_constant_frames);
    e.min_gain = readDouble(exposure, "min_gain", p, e.min_gain);
    e.max_gain = readDouble(exposure, "max_gain", p, e.max_gain);
    e.time_s = readDouble(exposure, "time_s", p, e.time_s);
  }
  const cv::FileNode light = optionalMap(optics, "light", "optics");
  if (!light.empty()) {
    const std::string p = "optics.light";
    SimLightResponseConfig& l = o->light;
    l.model = readOptionalString(light, "model", p, l.model);
    l.rise_time_s = readDouble(light, "rise_time_s", p, l.rise_time_s);
    l.fall_time_s = readDouble(light, "fall_time_s", p, l.fall_time_s);
    l.delay_s = readDouble(light, "delay_s", p, l.delay_s);
  }
  const cv::FileNode sensor = optionalMap(optics, "sensor", "optics");
  if (!sensor.empty()) {
    const std::string p = "optics.sensor";
    SimSensorConfig& s = o->sensor;
    s.enabled = true;
    s.gain_e_per_dn = readDouble(sensor, "gain_e_per_dn", p, s.gain_e_per_dn);
    s.read_noise_e = readDouble(sensor, "read_noise_e", p, s.read_noise_e);
    s.full_well_e = readDouble(sensor, "full_well_e", p, s.full_well_e);
  }
}

double readRequired(const cv::FileNode& node, const std::string& key, const std::string& path) {
  const double v = readDouble(node, key, path, std::numeric_limits<double>::quiet_NaN());
  if (std::isnan(v)) throw ConfigError(path + "." + key, "missing");
  return v;
}

// A string value; OpenCV's YAML reader keeps a trailing "# comment" in unquoted strings: cut it off.
std::string readRequiredString(const cv::FileNode& node, const std::string& key, const std::string& path,
                       const std::string& what) {
  const cv::FileNode n = node[key];
  const std::string full = path.empty() ? key : path + "." + key;
  if (n.empty() || n.isNone()) throw ConfigError(full, "missing (" + what + ")");
  if (!n.isString()) throw ConfigError(full, "must be a string (" + what + ")");
  std::string value = static_cast<std::string>(n);
  const size_t comment = value.find(" #");
  if (comment != std::string::npos) value = value.substr(0, comment);
  value.erase(value.find_last_not_of(" \t") + 1);
  return value;
}

// Refuses keys a section does not know (a misspelt key would otherwise be silently ignored).
void checkKeys(const cv::FileNode& node, const std::string& path, const std::set<std::string>& known) {
  for (const std::string& key : node.keys())
    if (!known.count(key)) {
      std::string list;
      for (const std::string& k : known) list += (list.empty() ? "" : ", ") + k;
      throw ConfigError(path + "." + key, "unknown key (known here: " + list + ")");
    }
}

std::string resolveImagePath(const std::string& value, const std::string& config_dir) {
  const std::string prefix = "skimage:";
  if (value.compare(0, prefix.size(), prefix) == 0) return kSkimageData + value.substr(prefix.size());
  if (!value.empty() && value[0] == '/') return value;
  return config_dir + value;
}

Eigen::Vector3d readVector3Or(const cv::FileNode& node, const std::string& key, const std::string& path,
                              const Eigen::Vector3d& fallback) {
  const cv::FileNode n = node[key];
  if (n.empty() || n.isNone()) return fallback;
  return readVector3(node, key, path);
}

SimTrajectory loadTrajectory(const cv::FileNode& node, const std::string& path) {
  SimTrajectory t;
  if (node.empty() || node.isNone()) return t;
  if (!node.isMap()) throw ConfigError(path, "must be a map (kind: static, drive, handheld or waypoints)");
  const std::string kind = readRequiredString(node, "kind", path, "static, drive, handheld or waypoints");
  std::set<std::string> known = {"kind", "start", "loop_s"};
  if (kind == "static") {
    t.kind = SimTrajectory::Kind::kStatic;
  } else if (kind == "drive") {
    t.kind = SimTrajectory::Kind::kDrive;
    known.insert({"speed_m_s", "yaw_rate_amplitude_deg_s", "yaw_period_s", "bump_amplitude_m",
                  "pitch_amplitude_deg", "roll_amplitude_deg", "bump_period_s"});
  } else if (kind == "handheld") {
    t.kind = SimTrajectory::Kind::kHandheld;
    known.insert({"translation_amplitude_m", "translation_period_s", "rotation_amplitude_deg", "rotation_period_s"});
  } else if (kind == "waypoints") {
    t.kind = SimTrajectory::Kind::kWaypoints;
    known.insert({"interpolation", "waypoints"});
  } else {
    throw ConfigError(path + ".kind", "must be static, drive, handheld or waypoints, not '" + kind + "'");
  }
  checkKeys(node, path, known);
  if (!node["start"].empty() && !node["start"].isNone()) t.start = loadPose(node["start"], path + ".start");
  t.loop_s = readDouble(node, "loop_s", path, t.loop_s);
  t.speed_m_s = readDouble(node, "speed_m_s", path, t.speed_m_s);
  t.yaw_rate_amplitude_deg_s = readDouble(node, "yaw_rate_amplitude_deg_s", path, t.yaw_rate_amplitude_deg_s);
  t.yaw_period_s = readDouble(node, "yaw_period_s", path, t.yaw_period_s);
  t.bump_amplitude_m = readDouble(node, "bump_amplitude_m", path, t.bump_amplitude_m);
  t.pitch_amplitude_deg = readDouble(node, "pitch_amplitude_deg", path, t.pitch_amplitude_deg);
  t.roll_amplitude_deg = readDouble(node, "roll_amplitude_deg", path, t.roll_amplitude_deg);
  t.bump_period_s = readDouble(node, "bump_period_s", path, t.bump_period_s);
  t.translation_amplitude_m = readVector3Or(node, "translation_amplitude_m", path, t.translation_amplitude_m);
  t.translation_period_s = readVector3Or(node, "translation_period_s", path, t.translation_period_s);
  t.rotation_amplitude_deg = readVector3Or(node, "rotation_amplitude_deg", path, t.rotation_amplitude_deg);
  t.rotation_period_s = readVector3Or(node, "rotation_period_s", path, t.rotation_period_s);
  if (t.kind == SimTrajectory::Kind::kWaypoints) {
    if (!node["interpolation"].empty()) {
      const std::string interpolation = readRequiredString(node, "interpolation", path, "linear or spline");
      if (interpolation != "linear" && interpolation != "spline")
        throw ConfigError(path + ".interpolation", "must be linear or spline, not '" + interpolation + "'");
      t.spline = interpolation == "spline";
    }
    const cv::FileNode list = node["waypoints"];
    if (list.empty() || !list.isSeq())
      throw ConfigError(path + ".waypoints", "must be a list of {t_s, rotation_deg, translation_m}");
    for (int i = 0; i < static_cast<int>(list.size()); ++i) {
      const std::string wp = path + ".waypoints[" + std::to_string(i) + "]";
      SimWaypoint w;
      w.t_s = readRequired(list[i], "t_s", wp);
      w.pose = loadPose(list[i], wp);
      t.waypoints.push_back(w);
    }
  }
  return t;
}

ScenePlane loadPlane(const cv::FileNode& node, const std::string& path, int index, const std::string& config_dir) {
  if (!node.isMap()) throw ConfigError(path, "must be a map (origin, u_axis, v_axis, width_m, height_m)");
  ScenePlane p;
  p.origin = readVector3(node, "origin", path);
  const Eigen::Vector3d u = readVector3(node, "u_axis", path);
  const Eigen::Vector3d v = readVector3(node, "v_axis", path);
  if (u.norm() < 1e-9) throw ConfigError(path + ".u_axis", "must be non-zero");
  if (v.norm() < 1e-9) throw ConfigError(path + ".v_axis", "must be non-zero");
  p.u_axis = u.normalized();
  // Tolerate rounding in hand-written axes (cosine < 1e-3), then make them exactly orthogonal.
  if (std::abs(p.u_axis.dot(v.normalized())) > 1e-3)
    throw ConfigError(path + ".v_axis", "must be orthogonal to u_axis");
  p.v_axis = (v - p.u_axis * p.u_axis.dot(v)).normalized();
  p.width_m = readRequired(node, "width_m", path);
  p.height_m = readRequired(node, "height_m", path);
  p.texture_seed = static_cast<int>(readDouble(node, "texture_seed", path, index + 1));
  p.texel_m = readDouble(node, "texel_m", path, p.texel_m);
  const cv::FileNode texture = node["texture"];
  if (!texture.empty() && !texture.isNone()) {
    const std::string tp = path + ".texture";
    if (!texture.isMap()) throw ConfigError(tp, "must be a map (image, tile_m)");
    checkKeys(texture, tp, {"image", "tile_m"});
    p.texture_image = resolveImagePath(readRequiredString(texture, "image", tp, "an image file"), config_dir);
    const cv::FileNode tile = texture["tile_m"];
    if (!tile.empty() && !tile.isNone()) {
      if (!tile.isSeq() || tile.size() != 2 || !(tile[0].isReal() || tile[0].isInt()) ||
          !(tile[1].isReal() || tile[1].isInt()))
        throw ConfigError(tp + ".tile_m", "must be [width, height] in metres");
      p.texture_tile_m = Eigen::Vector2d(static_cast<double>(tile[0]), static_cast<double>(tile[1]));
    }
    // Checked here too (validate() checks it again) so the error names the key as written.
    if (!cv::haveImageReader(p.texture_image))
      throw ConfigError(tp + ".image", "cannot read the image '" + p.texture_image + "' (missing or not an image)");
  }
  return p;
}

}  // namespace

std::string SimRigConfig::validate() const {
  const Problem p = findProblem(*this);
  return p.first.empty() ? std::string() : p.first + ": " + p.second;
}

ConfigProblem SimRigConfig::problem() const {
  const Problem p = findProblem(*this);
  return {p.first, p.second};
}

namespace {

// The scene section (enabled, planes, movers); config_dir: where relative image paths start.
void loadScene(const cv::FileNode& scene, const std::string& config_dir, SimSceneConfig* out) {
  if (scene.empty() || scene.isNone()) return;
  if (!scene.isMap()) throw ConfigError("scene", "must be a map (enabled, planes)");
  out->enabled = readBool(scene, "enabled", "scene", true);
  const cv::FileNode planes = scene["planes"];
  if (!planes.empty() && !planes.isNone()) {
    if (!planes.isSeq()) throw ConfigError("scene.planes", "must be a list");
    for (int i = 0; i < static_cast<int>(planes.size()); ++i)
      out->planes.push_back(loadPlane(planes[i], "scene.planes[" + std::to_string(i) + "]", i, config_dir));
  }
  const cv::FileNode movers = scene["movers"];
  if (!movers.empty() && !movers.isNone()) {
    if (!movers.isSeq()) throw ConfigError("scene.movers", "must be a list");
    for (int i = 0; i < static_cast<int>(movers.size()); ++i) {
      const std::string key = "scene.movers[" + std::to_string(i) + "]";
      SimMover m;
      // Movers' default noise seeds follow the planes' so every surface differs.
      m.panel = loadPlane(movers[i], key, static_cast<int>(out->planes.size()) + i, config_dir);
      m.trajectory = loadTrajectory(movers[i]["trajectory"], key + ".trajectory");
      out->movers.push_back(m);
    }
  }
}

void loadMotionBlur(const cv::FileNode& blur, SimMotionBlurConfig* out) {
  if (blur.empty() || blur.isNone()) return;
  if (!blur.isMap()) throw ConfigError("motion_blur", "must be a map (exposure_s, samples)");
  checkKeys(blur, "motion_blur", {"exposure_s", "samples"});
  out->exposure_s = readDouble(blur, "exposure_s", "motion_blur", out->exposure_s);
  const double samples = readDouble(blur, "samples", "motion_blur", out->samples);
  if (samples != std::floor(samples) || samples < 1 || samples > kMaxBlurSamples)
    throw ConfigError("motion_blur.samples", "must be an integer in [1, 64] (1 = no motion blur)");
  out->samples = static_cast<int>(samples);
}

void loadOptics(const cv::FileNode& optics, SimOpticsConfig* out) {
  if (optics.empty() || optics.isNone()) return;
  if (!optics.isMap()) throw ConfigError("optics", "must be a map");
  out->transmittance = readDouble(optics, "transmittance", "optics", out->transmittance);
  out->reflectance = readDouble(optics, "reflectance", "optics", out->reflectance);
  out->device_white = readDouble(optics, "device_white", "optics", out->device_white);
  out->device_black = readDouble(optics, "device_black", "optics", out->device_black);
  out->psf_sigma_px = readDouble(optics, "psf_sigma_px", "optics", out->psf_sigma_px);
  loadRealOptics(optics, out);
}

void loadEncoding(const cv::FileNode& encoding, std::string* out) {
  if (encoding.empty() || encoding.isNone()) return;
  if (!encoding.isString()) throw ConfigError("encoding", "must be mono8 or bgr8");
  // OpenCV's YAML reader keeps a trailing "# comment" in unquoted strings: cut it off.
  std::string value = static_cast<std::string>(encoding);
  value = value.substr(0, value.find('#'));
  value.erase(value.find_last_not_of(" \t") + 1);
  *out = value;
}

}  // namespace

SimRigConfig loadSimRigConfig(const std::string& path) {
  cv::FileStorage fs = openYaml(path);
  const size_t slash = path.find_last_of('/');
  const std::string config_dir = slash == std::string::npos ? std::string() : path.substr(0, slash + 1);
  const cv::FileNode root = fs.root();
  SimRigConfig c;
  c.rig = loadStereoRig(root["rig"], "rig");
  c.device = loadDevice(root["device"], "device");
  loadScene(root["scene"], config_dir, &c.scene);
  c.trajectory = loadTrajectory(root["trajectory"], "trajectory");
  loadMotionBlur(root["motion_blur"], &c.motion_blur);
  loadOptics(root["optics"], &c.optics);
  c.noise_sigma = readDouble(root, "noise_sigma", "", c.noise_sigma);
  c.fps = readDouble(root, "fps", "", c.fps);
  loadEncoding(root["encoding"], &c.encoding);
  const Problem problem = findProblem(c);
  if (!problem.first.empty()) throw ConfigError(problem.first, problem.second);
  return c;
}

}  // namespace embedded_calibration_stereo::core
