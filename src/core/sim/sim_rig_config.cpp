// Loading and validation of the simulated rig's configuration (config/sim_rig.yaml).
#include <cmath>
#include <limits>
#include <utility>

#include "embedded_calibration_stereo/core/geometry/config_error.h"
#include "embedded_calibration_stereo/core/geometry/config_io.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace ecs {

namespace {

// Largest texture side in texels: bounds the memory a plane can take (4096^2 floats = 64 MB).
constexpr double kMaxTexels = 4096.0;

using Problem = std::pair<std::string, std::string>;  // (parameter path, what is wrong)

Problem findProblem(const SimRigConfig& c) {
  std::string e = c.rig.validate();
  if (!e.empty()) return {"rig", e};
  e = c.device.validate();
  if (!e.empty()) return {"device", e};
  if (c.rig.left.width != c.rig.right.width || c.rig.left.height != c.rig.right.height)
    return {"rig.right", "must have the same image size as rig.left"};
  for (size_t i = 0; i < c.scene.planes.size(); ++i) {
    const ScenePlane& p = c.scene.planes[i];
    const std::string key = "scene.planes[" + std::to_string(i) + "]";
    if (!p.origin.allFinite()) return {key + ".origin", "must be finite"};
    if (!(std::abs(p.u_axis.norm() - 1.0) < 1e-6)) return {key + ".u_axis", "must be a unit vector"};
    if (!(std::abs(p.v_axis.norm() - 1.0) < 1e-6)) return {key + ".v_axis", "must be a unit vector"};
    if (!(std::abs(p.u_axis.dot(p.v_axis)) < 1e-6)) return {key + ".v_axis", "must be orthogonal to u_axis"};
    if (!(p.width_m > 0) || !std::isfinite(p.width_m)) return {key + ".width_m", "must be > 0"};
    if (!(p.height_m > 0) || !std::isfinite(p.height_m)) return {key + ".height_m", "must be > 0"};
    if (!(p.texel_m > 0) || !std::isfinite(p.texel_m)) return {key + ".texel_m", "must be > 0"};
    if (p.width_m / p.texel_m > kMaxTexels || p.height_m / p.texel_m > kMaxTexels)
      return {key + ".texel_m", "too small: the texture would exceed 4096 texels per side"};
  }
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

double readRequired(const cv::FileNode& node, const std::string& key, const std::string& path) {
  const double v = readDouble(node, key, path, std::numeric_limits<double>::quiet_NaN());
  if (std::isnan(v)) throw ConfigError(path + "." + key, "missing");
  return v;
}

ScenePlane loadPlane(const cv::FileNode& node, const std::string& path, int index) {
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
  return p;
}

}  // namespace

std::string SimRigConfig::validate() const {
  const Problem p = findProblem(*this);
  return p.first.empty() ? std::string() : p.first + ": " + p.second;
}

SimRigConfig loadSimRigConfig(const std::string& path) {
  cv::FileStorage fs = openYaml(path);
  const cv::FileNode root = fs.root();
  SimRigConfig c;
  c.rig = loadStereoRig(root["rig"], "rig");
  c.device = loadDevice(root["device"], "device");

  const cv::FileNode scene = root["scene"];
  if (!scene.empty() && !scene.isNone()) {
    if (!scene.isMap()) throw ConfigError("scene", "must be a map (enabled, planes)");
    c.scene.enabled = readBool(scene, "enabled", "scene", true);
    const cv::FileNode planes = scene["planes"];
    if (!planes.empty() && !planes.isNone()) {
      if (!planes.isSeq()) throw ConfigError("scene.planes", "must be a list");
      for (int i = 0; i < static_cast<int>(planes.size()); ++i)
        c.scene.planes.push_back(loadPlane(planes[i], "scene.planes[" + std::to_string(i) + "]", i));
    }
  }
  const cv::FileNode optics = root["optics"];
  if (!optics.empty() && !optics.isNone()) {
    if (!optics.isMap()) throw ConfigError("optics", "must be a map");
    c.optics.transmittance = readDouble(optics, "transmittance", "optics", c.optics.transmittance);
    c.optics.reflectance = readDouble(optics, "reflectance", "optics", c.optics.reflectance);
    c.optics.device_white = readDouble(optics, "device_white", "optics", c.optics.device_white);
    c.optics.device_black = readDouble(optics, "device_black", "optics", c.optics.device_black);
    c.optics.psf_sigma_px = readDouble(optics, "psf_sigma_px", "optics", c.optics.psf_sigma_px);
  }
  c.noise_sigma = readDouble(root, "noise_sigma", "", c.noise_sigma);
  c.fps = readDouble(root, "fps", "", c.fps);
  const cv::FileNode encoding = root["encoding"];
  if (!encoding.empty() && !encoding.isNone()) {
    if (!encoding.isString()) throw ConfigError("encoding", "must be mono8 or bgr8");
    // OpenCV's YAML reader keeps a trailing "# comment" in unquoted strings: cut it off.
    std::string value = static_cast<std::string>(encoding);
    value = value.substr(0, value.find('#'));
    value.erase(value.find_last_not_of(" \t") + 1);
    c.encoding = value;
  }
  const Problem problem = findProblem(c);
  if (!problem.first.empty()) throw ConfigError(problem.first, problem.second);
  return c;
}

}  // namespace ecs
