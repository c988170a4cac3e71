// Disparity of one rectified image pair, written as a Middlebury PFM (float32 disparity in
// pixels of the left image, +inf = invalid, rows bottom to top, little endian), optionally
// scored against a ground-truth image (bad > 2 px, invalid counted as bad).
#include <cstdio>
#include <cstdlib>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"
#include "embedded_calibration_stereo/core/geometry/pfm_io.h"

namespace {

const char* kUsage =
    "usage: disparity_images --left FILE --right FILE --out FILE.pfm\n"
    "                        [--algorithm sad|bm|sgbm] [--num-disparities N] [--min-disparity N]\n"
    "                        [--window N] [--sgbm-mode sgbm|hh|sgbm_3way|hh4] [--no-fill]\n"
    "                        [--gt FILE --gt-scale S]\n"
    "  Images are read as 8-bit gray and must be rectified. Defaults: the library's tuned\n"
    "  options (algorithm sad, 64 disparities). --gt prints the percentage of pixels with\n"
    "  ground truth (value / S > 0) whose disparity is off by more than 2 px.\n";

int usageError(const std::string& message) {
  std::fprintf(stderr, "disparity_images: %s\n%s", message.c_str(), kUsage);
  return 2;
}

bool parseInt(const std::string& text, int* value) {
  char* end = nullptr;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0') return false;
  *value = static_cast<int>(v);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  std::map<std::string, std::string> args;
  bool fill = true;
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    if (key == "--help" || key == "-h") {
      std::printf("%s", kUsage);
      return 0;
    }
    if (key == "--no-fill") {
      fill = false;
      continue;
    }
    static const char* kValued[] = {"--left", "--right", "--out", "--algorithm",
                                    "--num-disparities", "--min-disparity", "--window",
                                    "--sgbm-mode", "--gt", "--gt-scale"};
    bool known = false;
    for (const char* k : kValued) known = known || key == k;
    if (!known) return usageError("unknown option '" + key + "'");
    if (i + 1 >= argc) return usageError("option " + key + " needs a value");
    args[key] = argv[++i];
  }
  for (const char* required : {"--left", "--right", "--out"})
    if (!args.count(required)) return usageError(std::string("missing ") + required);
  if (args.count("--gt") != args.count("--gt-scale"))
    return usageError("--gt and --gt-scale go together");

  ecs::DisparityOptions options;
  options.fill_holes = fill;
  if (args.count("--algorithm")) options.algorithm = args["--algorithm"];
  if (args.count("--sgbm-mode")) options.sgbm_mode = args["--sgbm-mode"];
  if (args.count("--num-disparities") &&
      !parseInt(args["--num-disparities"], &options.disparity_range))
    return usageError("--num-disparities needs an integer");
  if (args.count("--min-disparity") && !parseInt(args["--min-disparity"], &options.min_disparity))
    return usageError("--min-disparity needs an integer");
  if (args.count("--window") && !parseInt(args["--window"], &options.correlation_window_size))
    return usageError("--window needs an integer");
  double gt_scale = 0;
  if (args.count("--gt-scale")) {
    char* end = nullptr;
    gt_scale = std::strtod(args["--gt-scale"].c_str(), &end);
    if (*end != '\0' || !(gt_scale > 0)) return usageError("--gt-scale needs a number > 0");
  }
  const std::string problem = options.Check();
  if (!problem.empty()) return usageError("invalid options: " + problem);

  const cv::Mat left = cv::imread(args["--left"], cv::IMREAD_GRAYSCALE);
  const cv::Mat right = cv::imread(args["--right"], cv::IMREAD_GRAYSCALE);
  if (left.empty()) {
    std::fprintf(stderr, "disparity_images: cannot read image '%s'\n", args["--left"].c_str());
    return 1;
  }
  if (right.empty()) {
    std::fprintf(stderr, "disparity_images: cannot read image '%s'\n", args["--right"].c_str());
    return 1;
  }
  try {
    ecs::DisparityComputer computer(options);
    const cv::Mat disparity = computer.compute(left, right);
    ecs::writePfm(args["--out"], disparity);
    std::printf("%s: %dx%d, algorithm %s, %d disparities from %d, written to %s\n",
                args["--left"].c_str(), left.cols, left.rows, options.algorithm.c_str(),
                options.disparity_range, options.min_disparity, args["--out"].c_str());
    if (args.count("--gt")) {
      const cv::Mat gt = ecs::loadScaledGroundTruth(args["--gt"], gt_scale);
      const ecs::BadPixelStats stats = ecs::evaluateBadPixels(disparity, gt, 2.0);
      std::printf("bad>2px: %.2f %% of %d pixels with ground truth (%d invalid)\n",
                  stats.badPercent(), stats.evaluated, stats.invalid);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "disparity_images: %s\n", e.what());
    return 1;
  }
  return 0;
}
