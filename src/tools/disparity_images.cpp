// Disparity of one rectified image pair, written as a Middlebury PFM (float32 disparity in
// pixels of the left image, +inf = invalid, rows bottom to top, little endian), optionally
// scored against a ground-truth image (bad > 2 px, invalid counted as bad).
#include <cstdio>
#include <cstdlib>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <utility>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"
#include "embedded_calibration_stereo/core/io/pfm_io.h"

namespace core = embedded_calibration_stereo::core;

namespace {

const char* kUsage =
    "usage: disparity_images --left FILE --right FILE --out FILE.pfm\n"
    "                        [--algorithm census_sgm|sad|bm|sgbm] [--num-disparities N]\n"
    "                        [--min-disparity N] [--paths 8|5] [--window N]\n"
    "                        [--sgbm-mode sgbm|hh|sgbm_3way|hh4] [--no-fill]\n"
    "                        [--gt FILE --gt-scale S]\n"
    "  Images are read as 8-bit gray and must be rectified. Defaults: the library's tuned\n"
    "  options (algorithm census_sgm, 8 paths, 64 disparities). --paths: census_sgm's paths;\n"
    "  --window: sad, bm and sgbm's. --gt (an image, or a PFM of float disparities) prints the\n"
    "  percentage of pixels with ground truth (value / S > 0) whose disparity is off by more\n"
    "  than 2 px.\n";

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

struct Request {
  std::map<std::string, std::string> args;
  core::DisparityOptions options;
  double gt_scale = 0;
  bool help = false;
};

// The command line's options into *args; an empty string, or the problem.
std::string readArgs(int argc, char** argv, Request* r) {
  static const char* kValued[] = {"--left", "--right", "--out", "--algorithm",
                                  "--num-disparities", "--min-disparity", "--window",
                                  "--paths", "--sgbm-mode", "--gt", "--gt-scale"};
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    if (key == "--help" || key == "-h") {
      r->help = true;
      return "";
    }
    if (key == "--no-fill") {
      r->options.fill_holes = false;
      continue;
    }
    bool known = false;
    for (const char* k : kValued) known = known || key == k;
    if (!known) return "unknown option '" + key + "'";
    if (i + 1 >= argc) return "option " + key + " needs a value";
    r->args[key] = argv[++i];
  }
  for (const char* required : {"--left", "--right", "--out"})
    if (!r->args.count(required)) return std::string("missing ") + required;
  if (r->args.count("--gt") != r->args.count("--gt-scale")) return "--gt and --gt-scale go together";
  return "";
}

// The disparity options and ground-truth scale the arguments give; an empty string, or the
// problem.
std::string readOptions(Request* r) {
  std::map<std::string, std::string>& args = r->args;
  core::DisparityOptions& options = r->options;
  if (args.count("--algorithm")) options.algorithm = args["--algorithm"];
  if (args.count("--sgbm-mode")) options.sgbm_mode = args["--sgbm-mode"];
  const std::pair<const char*, int*> integers[] = {{"--num-disparities", &options.disparity_range},
                                                   {"--min-disparity", &options.min_disparity},
                                                   {"--window", &options.correlation_window_size},
                                                   {"--paths", &options.sgm_paths}};
  for (const auto& [name, field] : integers)
    if (args.count(name) && !parseInt(args[name], field)) return std::string(name) + " needs an integer";
  if (args.count("--gt-scale")) {
    char* end = nullptr;
    r->gt_scale = std::strtod(args["--gt-scale"].c_str(), &end);
    if (*end != '\0' || !(r->gt_scale > 0)) return "--gt-scale needs a number > 0";
  }
  const std::string problem = options.validate();
  return problem.empty() ? "" : "invalid options: " + problem;
}

int run(Request& r) {
  std::map<std::string, std::string>& args = r.args;
  const cv::Mat left = cv::imread(args["--left"], cv::IMREAD_GRAYSCALE);
  const cv::Mat right = cv::imread(args["--right"], cv::IMREAD_GRAYSCALE);
  for (const auto& [name, image] : {std::make_pair("--left", &left), std::make_pair("--right", &right)})
    if (image->empty()) {
      std::fprintf(stderr, "disparity_images: cannot read image '%s'\n", args[name].c_str());
      return 1;
    }
  const core::DisparityOptions& options = r.options;
  core::DisparityComputer computer(options);
  const cv::Mat disparity = computer.compute(left, right);
  core::writePfm(args["--out"], disparity);
  std::printf("%s: %dx%d, algorithm %s, %d disparities from %d, written to %s\n",
              args["--left"].c_str(), left.cols, left.rows, options.algorithm.c_str(),
              options.disparity_range, options.min_disparity, args["--out"].c_str());
  if (args.count("--gt")) {
    const cv::Mat gt = core::loadScaledGroundTruth(args["--gt"], r.gt_scale);
    const core::BadPixelStats stats = core::evaluateBadPixels(disparity, gt, 2.0);
    std::printf("bad>2px: %.2f %% of %d pixels with ground truth (%d invalid)\n",
                stats.badPercent(), stats.evaluated, stats.invalid);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Request request;
  std::string problem = readArgs(argc, argv, &request);
  if (problem.empty() && request.help) {
    std::printf("%s", kUsage);
    return 0;
  }
  if (problem.empty()) problem = readOptions(&request);
  if (!problem.empty()) return usageError(problem);
  try {
    return run(request);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "disparity_images: %s\n", e.what());
    return 1;
  }
}
