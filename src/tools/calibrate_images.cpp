// Ordinary stereo calibration from saved images of a flat chessboard (ROS-free), the headless
// counterpart of ROS camera_calibration's stereo calibrator:
//
//   calibrate_images --board COLSxROWS --square METRES --left 'GLOB' --right 'GLOB' --out DIR
//                    [--detector subpix|sb] [--no-tangential] [--k3] [--loss none|huber|cauchy]
//                    [--loss-scale PX] [--min-pairs N] [--alpha A]
//                    [--left-name NAME] [--right-name NAME]
//
// Images are paired in sorted file-name order. DIR (created if missing) receives left.yaml and
// right.yaml (camera_calibration_parsers format, with the stereo rectification R and P),
// report.yaml and residuals.png, each written atomically. A pair whose board is not found in
// both images is skipped with a warning. Exit codes: 0 calibrated, 1 calibration failed (too
// few usable pairs, solver failure), 2 usage or input error, 3 output not writable.
#include <glob.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/board_calibration.h"
#include "embedded_calibration_stereo/core/calibration/board_calibration_report.h"
#include "embedded_calibration_stereo/core/io/camera_info_yaml.h"

using namespace embedded_calibration_stereo::core;

namespace {

const char* kUsage =
    "usage: calibrate_images --board COLSxROWS --square METRES --left 'GLOB' --right 'GLOB'\n"
    "                        --out DIR [--detector subpix|sb] [--no-tangential] [--k3]\n"
    "                        [--loss none|huber|cauchy] [--loss-scale PX] [--min-pairs N]\n"
    "                        [--alpha A] [--left-name NAME] [--right-name NAME]\n"
    "  COLSxROWS: inner corners (e.g. 9x6); quote the globs so the shell does not expand them.\n"
    "  Images pair in sorted name order. Defaults: subpix detector (findChessboardCorners, else\n"
    "  findChessboardCornersSB, then cornerSubPix; sb = findChessboardCornersSB alone, less\n"
    "  accurate), k1 k2 p1 p2 estimated, least\n"
    "  squares, 5 pairs minimum, alpha 0, camera names left and right.\n"
    "  Exit codes: 0 calibrated, 1 calibration failed, 2 usage/input error, 3 output error.\n";

constexpr int kCalibrationFailed = 1, kInputError = 2, kOutputError = 3;

int fail(int code, const std::string& message) {
  std::fprintf(stderr, "calibrate_images: %s\n", message.c_str());
  if (code == kInputError) std::fprintf(stderr, "(calibrate_images --help for the usage)\n");
  return code;
}

bool parseDouble(const std::string& text, double* value) {
  char* end = nullptr;
  *value = std::strtod(text.c_str(), &end);
  return !text.empty() && *end == '\0' && std::isfinite(*value);
}

std::vector<std::string> expandGlob(const std::string& pattern) {
  std::vector<std::string> files;
  glob_t g{};
  if (::glob(pattern.c_str(), 0, nullptr, &g) == 0)  // sorted by default
    for (size_t i = 0; i < g.gl_pathc; ++i) files.emplace_back(g.gl_pathv[i]);
  ::globfree(&g);
  return files;
}

struct PairOutcome {
  StereoBoardDetection detection;
  cv::Size left_size, right_size;
  std::string problem;  // unreadable image or board not found
  bool unreadable = false;
};

// What the command line asks for.
struct Arguments {
  ChessboardSpec board;
  BoardCalibrationOptions options;
  CornerDetector detector = CornerDetector::kCornerSubPix;
  std::string left_glob, right_glob, out_dir;
  std::string left_name = "left", right_name = "right";
};

// Returned by the stages below when the program goes on (otherwise: its exit code).
constexpr int kContinue = -1;

// The options in `args` (valued ones) and `options` (flags); kContinue, or 0 after --help.
int readCommandLine(int argc, char** argv, std::map<std::string, std::string>* args,
                    BoardCalibrationOptions* options) {
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    if (key == "--help" || key == "-h") {
      std::printf("%s", kUsage);
      return 0;
    }
    if (key == "--k3") {
      options->estimate_k3 = true;
      continue;
    }
    if (key == "--no-tangential") {
      options->estimate_tangential = false;
      continue;
    }
    static const char* kValued[] = {"--board",     "--square",   "--left",      "--right",
                                    "--out",       "--detector", "--loss",      "--loss-scale",
                                    "--min-pairs", "--alpha",    "--left-name", "--right-name"};
    bool known = false;
    for (const char* k : kValued) known = known || key == k;
    if (!known) return fail(kInputError, "unknown option '" + key + "'");
    if (i + 1 >= argc) return fail(kInputError, "option " + key + " needs a value");
    (*args)[key] = argv[++i];
  }
  for (const char* required : {"--board", "--square", "--left", "--right", "--out"})
    if (!args->count(required)) return fail(kInputError, std::string("missing ") + required);
  return kContinue;
}

int boardArguments(std::map<std::string, std::string>& args, Arguments* a) {
  ChessboardSpec& board = a->board;
  std::string problem;
  if (!parseBoardSize(args["--board"], &board.cols, &board.rows, &problem))
    return fail(kInputError, problem);
  if (!parseDouble(args["--square"], &board.square_m) || !(board.square_m > 0))
    return fail(kInputError, "--square must be the square size in metres, e.g. 0.025");
  problem = board.validate();
  if (!problem.empty()) return fail(kInputError, problem);
  if (args.count("--detector")) {
    if (args["--detector"] == "sb")
      a->detector = CornerDetector::kSectorBased;
    else if (args["--detector"] != "subpix")
      return fail(kInputError, "--detector must be subpix or sb");
  }
  return kContinue;
}

int solverArguments(std::map<std::string, std::string>& args, BoardCalibrationOptions* options) {
  if (args.count("--loss")) {
    const std::string& loss = args["--loss"];
    if (loss == "huber")
      options->loss = RobustLoss::kHuber;
    else if (loss == "cauchy")
      options->loss = RobustLoss::kCauchy;
    else if (loss != "none")
      return fail(kInputError, "--loss must be none, huber or cauchy");
  }
  if (args.count("--loss-scale") &&
      (!parseDouble(args["--loss-scale"], &options->loss_scale_px) || !(options->loss_scale_px > 0)))
    return fail(kInputError, "--loss-scale must be a positive number of pixels");
  if (args.count("--min-pairs")) {
    double n = 0;
    if (!parseDouble(args["--min-pairs"], &n) || n < 3 || n != std::floor(n))
      return fail(kInputError, "--min-pairs must be an integer >= 3");
    options->min_pairs = static_cast<int>(n);
  }
  if (args.count("--alpha") &&
      (!parseDouble(args["--alpha"], &options->rectification.alpha) ||
       options->rectification.alpha < -1 || options->rectification.alpha > 1))
    return fail(kInputError, "--alpha must be in [0, 1] (or -1 for OpenCV's default)");
  return kContinue;
}

int parseArguments(int argc, char** argv, Arguments* a) {
  std::map<std::string, std::string> args;
  int code = readCommandLine(argc, argv, &args, &a->options);
  if (code == kContinue) code = boardArguments(args, a);
  if (code == kContinue) code = solverArguments(args, &a->options);
  if (code != kContinue) return code;
  if (args.count("--left-name")) a->left_name = args["--left-name"];
  if (args.count("--right-name")) a->right_name = args["--right-name"];
  a->left_glob = args["--left"];
  a->right_glob = args["--right"];
  a->out_dir = args["--out"];
  return kContinue;
}

// Output directory first: fail before minutes of detection, not after.
int prepareOutputDirectory(const std::string& out_dir) {
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (!std::filesystem::is_directory(out_dir) || ::access(out_dir.c_str(), W_OK | X_OK) != 0)
    return fail(kOutputError, "output directory '" + out_dir + "' cannot be created or written" +
                                  (ec ? " (" + ec.message() + ")" : ""));
  return kContinue;
}

// The image files, paired in sorted order.
struct ImageFiles {
  std::vector<std::string> left, right;
};

int listImages(const Arguments& a, ImageFiles* files) {
  files->left = expandGlob(a.left_glob);
  files->right = expandGlob(a.right_glob);
  if (files->left.empty()) return fail(kInputError, "no file matches --left '" + a.left_glob + "'");
  if (files->right.empty()) return fail(kInputError, "no file matches --right '" + a.right_glob + "'");
  if (files->left.size() != files->right.size())
    return fail(kInputError, std::to_string(files->left.size()) + " left image(s) but " +
                                 std::to_string(files->right.size()) +
                                 " right image(s): they pair in sorted order and must match");
  return kContinue;
}

PairOutcome detectPair(const std::string& left_file, const std::string& right_file, const Arguments& a) {
  PairOutcome o;
  o.detection.name = std::filesystem::path(left_file).filename().string() + " | " +
                     std::filesystem::path(right_file).filename().string();
  const cv::Mat left = cv::imread(left_file, cv::IMREAD_GRAYSCALE);
  const cv::Mat right = cv::imread(right_file, cv::IMREAD_GRAYSCALE);
  if (left.empty() || right.empty()) {
    o.unreadable = true;
    o.problem = "cannot read image " + (left.empty() ? left_file : right_file);
    return o;
  }
  o.left_size = left.size();
  o.right_size = right.size();
  const int cols = a.board.cols, rows = a.board.rows;
  const bool left_found = detectChessboard(left, cols, rows, a.detector, &o.detection.left);
  const bool right_found = detectChessboard(right, cols, rows, a.detector, &o.detection.right);
  if (!left_found || !right_found)
    o.problem = std::string("board not found in the ") + (!left_found && !right_found ? "left and right images"
                                                          : !left_found                ? "left image"
                                                                                       : "right image");
  return o;
}

// Detection, pairs in parallel.
std::vector<PairOutcome> detectPairs(const ImageFiles& files, const Arguments& a) {
  std::vector<PairOutcome> outcomes(files.left.size());
  cv::parallel_for_(cv::Range(0, static_cast<int>(outcomes.size())), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) outcomes[i] = detectPair(files.left[i], files.right[i], a);
  });
  return outcomes;
}

// The pairs to calibrate from, the image size they share, and the skipped pairs with why.
struct UsablePairs {
  cv::Size image_size;
  std::vector<StereoBoardDetection> detections;
  std::vector<std::string> skipped;
};

int usablePairs(const std::vector<PairOutcome>& outcomes, UsablePairs* pairs) {
  cv::Size& image_size = pairs->image_size;
  for (const PairOutcome& o : outcomes) {
    if (o.unreadable) return fail(kInputError, o.problem);
    if (image_size.empty()) image_size = o.left_size;
    if (o.left_size != image_size || o.right_size != image_size)
      return fail(kInputError, "pair " + o.detection.name + ": images of " +
                                   std::to_string(o.left_size.width) + "x" +
                                   std::to_string(o.left_size.height) + " and " +
                                   std::to_string(o.right_size.width) + "x" +
                                   std::to_string(o.right_size.height) + ", expected " +
                                   std::to_string(image_size.width) + "x" +
                                   std::to_string(image_size.height) + " for every image");
    if (!o.problem.empty()) {
      pairs->skipped.push_back(o.detection.name + ": " + o.problem);
      std::fprintf(stderr, "calibrate_images: warning: pair %s: %s, skipped\n",
                   o.detection.name.c_str(), o.problem.c_str());
      continue;
    }
    pairs->detections.push_back(o.detection);
  }
  return kContinue;
}

// left.yaml, right.yaml, report.yaml and residuals.png, each written atomically.
int writeOutputs(const BoardCalibrationResult& result, const Arguments& a, const UsablePairs& pairs) {
  const auto [left_info, right_info] =
      stereoCameraInfoFiles(result.rig, result.rectification, a.left_name, a.right_name);
  std::vector<uchar> png;
  try {
    cv::imencode(".png", residualPlot(result), png);
    const std::filesystem::path dir(a.out_dir);
    writeFileAtomically((dir / "left.yaml").string(), cameraInfoYaml(left_info));
    writeFileAtomically((dir / "right.yaml").string(), cameraInfoYaml(right_info));
    writeFileAtomically((dir / "report.yaml").string(),
                        boardCalibrationReportYaml(result, a.board, pairs.skipped));
    writeFileAtomically((dir / "residuals.png").string(), std::string(png.begin(), png.end()));
  } catch (const std::exception& e) {
    return fail(kOutputError, e.what());
  }
  return kContinue;
}

void printSummary(const BoardCalibrationResult& result, const UsablePairs& pairs, const std::string& out_dir) {
  const BundleAdjustmentSummary& s = result.summary;
  const PinholeCamera& l = result.rig.left;
  const PinholeCamera& r = result.rig.right;
  std::printf(
      "calibrated from %zu pair(s) (%zu skipped): rms %.4f px (left %.4f, right %.4f), "
      "epipolar rms %.4f px, OpenCV start %.4f px\n"
      "left:  fx %.3f +- %.3f  fy %.3f +- %.3f  cx %.3f +- %.3f  cy %.3f +- %.3f  k1 %.5f +- %.5f\n"
      "right: fx %.3f +- %.3f  fy %.3f +- %.3f  cx %.3f +- %.3f  cy %.3f +- %.3f  k1 %.5f +- %.5f\n"
      "baseline %.6f +- %.6f m, rotation +- %.4f deg; files in %s\n",
      pairs.detections.size(), pairs.skipped.size(), result.rms_px, s.rms_left_px, s.rms_right_px,
      s.epipolar_rms_px, result.opencv_initial_rms_px, l.fx, s.left_stddev.fx, l.fy,
      s.left_stddev.fy, l.cx, s.left_stddev.cx, l.cy, s.left_stddev.cy, l.dist[0],
      s.left_stddev.dist[0], r.fx, s.right_stddev.fx, r.fy, s.right_stddev.fy, r.cx,
      s.right_stddev.cx, r.cy, s.right_stddev.cy, r.dist[0], s.right_stddev.dist[0],
      result.rig.baseline(), s.baseline_stddev_m, s.rotation_stddev_deg, out_dir.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  Arguments a;
  int code = parseArguments(argc, argv, &a);
  if (code == kContinue) code = prepareOutputDirectory(a.out_dir);
  ImageFiles files;
  if (code == kContinue) code = listImages(a, &files);
  if (code != kContinue) return code;

  const std::vector<PairOutcome> outcomes = detectPairs(files, a);
  UsablePairs pairs;
  code = usablePairs(outcomes, &pairs);
  if (code != kContinue) return code;
  std::fprintf(stderr, "calibrate_images: board found in %zu of %zu pair(s)\n", pairs.detections.size(),
               outcomes.size());
  if (static_cast<int>(pairs.detections.size()) < a.options.min_pairs)
    return fail(kCalibrationFailed,
                "only " + std::to_string(pairs.detections.size()) + " usable pair(s), at least " +
                    std::to_string(a.options.min_pairs) + " needed (--min-pairs)");

  const BoardCalibrationResult result = calibrateStereoBoard(a.board, pairs.image_size, pairs.detections, a.options);
  if (!result.ok) return fail(kCalibrationFailed, result.message);
  code = writeOutputs(result, a, pairs);
  if (code != kContinue) return code;
  printSummary(result, pairs, a.out_dir);
  return 0;
}
