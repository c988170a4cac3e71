#include "embedded_calibration_stereo/core/tracker/board_prior.h"

#include <cmath>

#include "embedded_calibration_stereo/core/io/atomic_file.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/io/config_io.h"

namespace embedded_calibration_stereo::core {

std::vector<cv::Point2f> BoardPrior::meanOuterCorners() const {
  std::vector<cv::Point2f> out(4);
  for (int i = 0; i < 4; ++i)
    out[i] = cv::Point2f(static_cast<float>(outer_mean.at<double>(0, 2 * i)),
                         static_cast<float>(outer_mean.at<double>(0, 2 * i + 1)));
  return out;
}

std::vector<cv::Point2f> BoardPrior::outerGridPoints() const {
  const float c = static_cast<float>(cols - 1), r = static_cast<float>(rows - 1);
  return {{0.f, 0.f}, {c, 0.f}, {c, r}, {0.f, r}};
}

std::string BoardPrior::validate() const {
  const std::string key = "board " + std::to_string(board_id);
  if (cols < 2 || rows < 2) return key + ": cols and rows must be >= 2";
  if (outer_mean.rows != 1 || outer_mean.cols != 8 || outer_mean.type() != CV_64F)
    return key + ": outer_mean must hold 8 numbers";
  if (!outer_modes.empty() && (outer_modes.cols != 8 || outer_modes.type() != CV_64F))
    return key + ": outer_modes must be a k x 8 matrix";
  if (outer_sigma.total() != static_cast<size_t>(outer_modes.rows))
    return key + ": outer_sigma must have one entry per mode";
  if (static_cast<int>(offsets.size()) != cornerCount())
    return key + ": offsets: expected " + std::to_string(cornerCount()) + " corners";
  if (sign != 1 && sign != -1) return key + ": sign must be 1 or -1";
  if (!(contrast > 0)) return key + ": contrast must be > 0";
  if (!(square_px > 0)) return key + ": square_px must be > 0";
  return "";
}

std::string CameraPrior::validate() const {
  if (width <= 0 || height <= 0) return "camera " + name + ": width and height must be > 0";
  if (boards.empty()) return "camera " + name + ": no boards";
  for (const BoardPrior& b : boards) {
    const std::string e = b.validate();
    if (!e.empty()) return "camera " + name + ", " + e;
  }
  return "";
}

std::string PatternPrior::validate() const {
  if (cameras.empty()) return "no cameras";
  for (const CameraPrior& c : cameras) {
    const std::string e = c.validate();
    if (!e.empty()) return e;
  }
  return "";
}

void writePatternPrior(const std::string& path, const PatternPrior& prior) {
  const std::string problem = prior.validate();
  if (!problem.empty()) throw ConfigError(path, "refusing to write an invalid prior: " + problem);
  // Serialised in memory, then written atomically: a reader never sees half a prior.
  cv::FileStorage fs(".yaml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
  fs << "format"
     << "ecs_pattern_prior"
     << "version" << 1 << "cameras"
     << "[";
  for (const CameraPrior& cam : prior.cameras) {
    fs << "{"
       << "name" << cam.name << "width" << cam.width << "height" << cam.height << "taught_frames"
       << cam.taught_frames << "boards"
       << "[";
    for (const BoardPrior& b : cam.boards) {
      std::vector<double> mean(b.outer_mean.begin<double>(), b.outer_mean.end<double>());
      std::vector<double> sigma;
      if (!b.outer_sigma.empty()) sigma.assign(b.outer_sigma.begin<double>(), b.outer_sigma.end<double>());
      std::vector<float> offsets;
      for (const cv::Point2f& o : b.offsets) {
        offsets.push_back(o.x);
        offsets.push_back(o.y);
      }
      fs << "{"
         << "board_id" << b.board_id << "cols" << b.cols << "rows" << b.rows << "outer_mean" << mean
         << "outer_modes" << (b.outer_modes.empty() ? cv::Mat(0, 8, CV_64F) : b.outer_modes) << "outer_sigma"
         << sigma << "offsets" << offsets << "sign" << b.sign << "contrast" << b.contrast << "square_px"
         << b.square_px << "device_pattern" << static_cast<int>(b.device_pattern) << "edge_blur_px" << b.edge_blur_px << "}";
    }
    fs << "]"
       << "}";
  }
  fs << "]";
  try {
    writeFileAtomically(path, fs.releaseAndGetString());
  } catch (const std::exception& e) {
    throw ConfigError(path, std::string("cannot write: ") + e.what());
  }
}

namespace {

std::vector<double> readNumbers(const cv::FileNode& node, const std::string& key, const std::string& path) {
  const cv::FileNode n = node[key];
  if (n.empty() || n.isNone()) throw ConfigError(path + "." + key, "missing");
  if (!n.isSeq()) throw ConfigError(path + "." + key, "must be a list of numbers");
  std::vector<double> out;
  for (size_t i = 0; i < n.size(); ++i) {
    if (!n[i].isReal() && !n[i].isInt()) throw ConfigError(path + "." + key, "must be a list of numbers");
    out.push_back(static_cast<double>(n[i]));
  }
  return out;
}

int readInt(const cv::FileNode& node, const std::string& key, const std::string& path) {
  const cv::FileNode n = node[key];
  if (!n.isInt()) throw ConfigError(path + "." + key, "missing or not an integer");
  return static_cast<int>(n);
}

BoardPrior readBoard(const cv::FileNode& node, const std::string& path) {
  BoardPrior b;
  b.board_id = readInt(node, "board_id", path);
  b.cols = readInt(node, "cols", path);
  b.rows = readInt(node, "rows", path);
  const std::vector<double> mean = readNumbers(node, "outer_mean", path);
  if (mean.size() != 8) throw ConfigError(path + ".outer_mean", "must hold 8 numbers");
  b.outer_mean = cv::Mat(mean, true).reshape(1, 1);
  node["outer_modes"] >> b.outer_modes;
  if (b.outer_modes.empty()) b.outer_modes = cv::Mat(0, 8, CV_64F);
  b.outer_modes.convertTo(b.outer_modes, CV_64F);
  const std::vector<double> sigma = readNumbers(node, "outer_sigma", path);
  b.outer_sigma = sigma.empty() ? cv::Mat(1, 0, CV_64F) : cv::Mat(sigma, true).reshape(1, 1);
  const std::vector<double> offsets = readNumbers(node, "offsets", path);
  if (offsets.size() % 2 != 0) throw ConfigError(path + ".offsets", "must hold u,v pairs");
  for (size_t i = 0; i + 1 < offsets.size(); i += 2)
    b.offsets.emplace_back(static_cast<float>(offsets[i]), static_cast<float>(offsets[i + 1]));
  b.sign = readInt(node, "sign", path);
  b.contrast = readPositive(node, "contrast", path);
  b.square_px = readPositive(node, "square_px", path);
  // Optional (priors written before it are the device's): 1 for the device's boards, 0 for a
  // printed chessboard.
  const cv::FileNode device = node["device_pattern"];
  if (!device.empty() && !device.isNone()) {
    if (!device.isInt() || (static_cast<int>(device) != 0 && static_cast<int>(device) != 1))
      throw ConfigError(path + ".device_pattern", "must be 0 or 1");
    b.device_pattern = static_cast<int>(device) == 1;
  }
  const cv::FileNode blur = node["edge_blur_px"];
  if (!blur.empty() && !blur.isNone()) {
    if (!(blur.isReal() || blur.isInt()) || !(static_cast<double>(blur) >= 0))
      throw ConfigError(path + ".edge_blur_px", "must be a number >= 0");
    b.edge_blur_px = static_cast<double>(blur);
  }
  const std::string problem = b.validate();
  if (!problem.empty()) throw ConfigError(path, problem);
  return b;
}

}  // namespace

PatternPrior readPatternPrior(const std::string& path) {
  cv::FileStorage fs = openYaml(path);
  if (static_cast<std::string>(fs["format"]) != "ecs_pattern_prior")
    throw ConfigError(path + ":format", "must be ecs_pattern_prior");
  if (static_cast<int>(fs["version"]) != 1) throw ConfigError(path + ":version", "must be 1");
  const cv::FileNode cameras = fs["cameras"];
  if (!cameras.isSeq() || cameras.size() == 0)
    throw ConfigError(path + ":cameras", "must be a non-empty list");
  PatternPrior prior;
  for (size_t c = 0; c < cameras.size(); ++c) {
    const std::string key = path + ":cameras[" + std::to_string(c) + "]";
    const cv::FileNode node = cameras[c];
    CameraPrior cam;
    cam.name = static_cast<std::string>(node["name"]);
    cam.width = readInt(node, "width", key);
    cam.height = readInt(node, "height", key);
    cam.taught_frames = readInt(node, "taught_frames", key);
    const cv::FileNode boards = node["boards"];
    if (!boards.isSeq()) throw ConfigError(key + ".boards", "must be a list");
    for (size_t i = 0; i < boards.size(); ++i)
      cam.boards.push_back(readBoard(boards[i], key + ".boards[" + std::to_string(i) + "]"));
    const std::string problem = cam.validate();
    if (!problem.empty()) throw ConfigError(key, problem);
    prior.cameras.push_back(cam);
  }
  return prior;
}

}  // namespace embedded_calibration_stereo::core
