#include "embedded_calibration_stereo/core/io/config_io.h"

#include <cmath>
#include <fstream>
#include <opencv2/core.hpp>

namespace embedded_calibration_stereo::core {

cv::FileStorage openYaml(const std::string& path) {
  std::ifstream probe(path);
  if (!probe.good()) throw ConfigError(path, "file not found or not readable");
  cv::FileStorage fs;
  try {
    fs.open(path, cv::FileStorage::READ | cv::FileStorage::FORMAT_YAML);
  } catch (const cv::Exception& e) {
    throw ConfigError(path, std::string("malformed YAML: ") + e.what());
  }
  if (!fs.isOpened()) throw ConfigError(path, "malformed YAML");
  return fs;
}

namespace {
std::string join(const std::string& path, const std::string& key) {
  return path.empty() ? key : path + "." + key;
}

double readNumber(const cv::FileNode& node, const std::string& key, const std::string& path) {
  const cv::FileNode n = node[key];
  if (n.empty() || n.isNone()) throw ConfigError(join(path, key), "missing");
  if (!n.isReal() && !n.isInt()) throw ConfigError(join(path, key), "must be a number");
  const double v = static_cast<double>(n);
  if (!std::isfinite(v)) throw ConfigError(join(path, key), "must be finite");
  return v;
}
}  // namespace

double readPositive(const cv::FileNode& node, const std::string& key, const std::string& path) {
  const double v = readNumber(node, key, path);
  if (!(v > 0)) throw ConfigError(join(path, key), "must be > 0 (got " + std::to_string(v) + ")");
  return v;
}

double readDouble(const cv::FileNode& node, const std::string& key, const std::string& path,
                  double fallback) {
  const cv::FileNode n = node[key];
  if (n.empty() || n.isNone()) return fallback;
  return readNumber(node, key, path);
}

Eigen::Vector3d readVector3(const cv::FileNode& node, const std::string& key,
                            const std::string& path) {
  const cv::FileNode n = node[key];
  if (n.empty() || n.isNone()) throw ConfigError(join(path, key), "missing");
  if (!n.isSeq() || n.size() != 3) throw ConfigError(join(path, key), "must be a list of 3 numbers");
  Eigen::Vector3d v;
  for (int i = 0; i < 3; ++i) {
    if (!n[i].isReal() && !n[i].isInt()) throw ConfigError(join(path, key), "must be a list of 3 numbers");
    v[i] = static_cast<double>(n[i]);
    if (!std::isfinite(v[i])) throw ConfigError(join(path, key), "must be finite");
  }
  return v;
}

PinholeCamera loadCamera(const cv::FileNode& node, const std::string& path) {
  if (node.empty() || !node.isMap()) throw ConfigError(path, "missing camera section");
  PinholeCamera c;
  c.width = static_cast<int>(readPositive(node, "width", path));
  c.height = static_cast<int>(readPositive(node, "height", path));
  c.fx = readPositive(node, "fx", path);
  c.fy = readPositive(node, "fy", path);
  c.cx = readNumber(node, "cx", path);
  c.cy = readNumber(node, "cy", path);
  c.skew = readDouble(node, "skew", path, 0.0);
  const cv::FileNode d = node["distortion"];
  if (!d.empty() && !d.isNone()) {
    if (!d.isSeq() || d.size() > 5)
      throw ConfigError(join(path, "distortion"), "must be a list of up to 5 numbers [k1,k2,p1,p2,k3]");
    for (size_t i = 0; i < d.size(); ++i) c.dist[i] = static_cast<double>(d[static_cast<int>(i)]);
  }
  const std::string problem = c.validate();
  if (!problem.empty()) throw ConfigError(path, problem);
  return c;
}

Eigen::Isometry3d loadPose(const cv::FileNode& node, const std::string& path) {
  if (node.empty() || !node.isMap()) throw ConfigError(path, "missing pose (rotation_deg, translation_m)");
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = rotationFromVectorDeg(readVector3(node, "rotation_deg", path));
  t.translation() = readVector3(node, "translation_m", path);
  return t;
}

StereoRig loadStereoRig(const cv::FileNode& node, const std::string& path) {
  if (node.empty() || !node.isMap()) throw ConfigError(path, "missing rig section");
  StereoRig rig;
  rig.left = loadCamera(node["left"], join(path, "left"));
  rig.right = loadCamera(node["right"], join(path, "right"));
  rig.right_from_left = loadPose(node["right_from_left"], join(path, "right_from_left"));
  const std::string problem = rig.validate();
  if (!problem.empty()) throw ConfigError(path, problem);
  return rig;
}

namespace {

// Runs `read` on the opened file; whatever it throws becomes ConfigError(parameter, ...).
template <typename Read>
auto readDeviceFile(const std::string& file, const std::string& parameter, Read read) {
  try {
    cv::FileStorage fs = openYaml(file);
    return read(fs);
  } catch (const std::exception& e) {
    throw ConfigError(parameter, "'" + file + "': " + e.what());
  }
}

std::optional<StereoRig> nominalRig(const cv::FileStorage& fs) {
  if (fs["rig"].empty()) return std::nullopt;
  return loadStereoRig(fs["rig"], "rig");
}

}  // namespace

DeviceDescription loadDeviceDescription(const std::string& file, const std::string& parameter) {
  return readDeviceFile(file, parameter, [](const cv::FileStorage& fs) {
    return DeviceDescription{loadDevice(fs["device"], "device"), nominalRig(fs)};
  });
}

std::optional<StereoRig> loadNominalRig(const std::string& file, const std::string& parameter) {
  return readDeviceFile(file, parameter, nominalRig);
}

CalibrationDevice loadDevice(const cv::FileNode& node, const std::string& path) {
  if (node.empty() || !node.isMap()) throw ConfigError(path, "missing device section");
  CalibrationDevice dev;
  const cv::FileNode boards = node["boards"];
  if (boards.empty() || !boards.isSeq()) throw ConfigError(join(path, "boards"), "must be a list");
  for (int i = 0; i < static_cast<int>(boards.size()); ++i) {
    const std::string bp = join(path, "boards[" + std::to_string(i) + "]");
    Chessboard b;
    b.id = i;
    b.cols = static_cast<int>(readPositive(boards[i], "cols", bp));
    b.rows = static_cast<int>(readPositive(boards[i], "rows", bp));
    b.square = readPositive(boards[i], "square_m", bp);
    b.device_from_board = loadPose(boards[i]["pose"], join(bp, "pose"));
    dev.boards.push_back(b);
  }
  dev.rig_from_device = loadPose(node["pose"], join(path, "pose"));
  const cv::FileNode copies = node["copies"];
  if (copies.empty() || !copies.isSeq()) throw ConfigError(join(path, "copies"), "must be a list of mirror chains");
  for (int c = 0; c < static_cast<int>(copies.size()); ++c) {
    const std::string cp = join(path, "copies[" + std::to_string(c) + "]");
    if (!copies[c].isSeq()) throw ConfigError(cp, "must be a list of mirror planes");
    std::vector<MirrorPlane> chain;
    for (int m = 0; m < static_cast<int>(copies[c].size()); ++m) {
      const std::string mp = cp + "[" + std::to_string(m) + "]";
      MirrorPlane plane;
      plane.normal = readVector3(copies[c][m], "normal", mp);
      if (plane.normal.norm() < 1e-9) throw ConfigError(join(mp, "normal"), "must be non-zero");
      plane.normal.normalize();
      plane.distance = readNumber(copies[c][m], "distance_m", mp);
      chain.push_back(plane);
    }
    dev.copies.push_back(chain);
  }
  const std::string problem = dev.validate();
  if (!problem.empty()) throw ConfigError(path, problem);
  return dev;
}

}  // namespace embedded_calibration_stereo::core
