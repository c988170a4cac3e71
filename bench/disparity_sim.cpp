// Disparity on the simulated head's moving, photographed world (drive_photo) against the
// simulator's depth truth, per matcher: light-off frames and light-on frames separated by the
// product's Separator, which learns its device image from the light bursts as the Separator
// nodelet does (no covered scene, no truth; test/support sim_disparity_eval.h). Rectified with
// the true calibration: a measurement of the matchers, not of the calibration.
//
// For each algorithm name (default: every name parseDisparityAlgorithm accepts among sad, bm,
// sgbm, census_sgm) it runs our defaults (DisparityOptions{} with the algorithm set) and, for bm
// and sgbm, stock stereo_image_proc's configuration too; it prints bad > 2 px (invalid counted
// bad), invalid, the RMS error of the matches within 2 px, the lit minus light-off difference,
// and the wall and CPU time per frame beside the machine. With --out DIR it writes one lit
// frame's images and each matcher's disparity on one colour scale, and a labelled montage.
//
// Usage: bench_disparity_sim [--config FILE] [--algorithms a,b,...] [--seed N] [--bursts N]
//          [--lit N] [--off N] [--period S] [--burst-frames N] [--settle N] [--threads N]
//          [--out DIR] [--frame K] [--raw] [--ideal | --ideal-clipped]
//   --config  default $ECS_SOURCE_DIR/config/drive_photo.yaml, else config/drive_photo.yaml
//   --bursts  light bursts scored (one more is rendered first, to learn the device image from)
//   --lit, --off  frames scored per burst (settled light-on; light-off around it)
//   --period, --burst-frames, --settle  the light schedule: s between bursts (1.3), settled
//             light-on frames per burst (10, the driver's default) and settle frames (2)
//   --frame   index of the lit frame written with --out (default: the middle one)
//   --raw     the lit frames unseparated (what the Separator saves us from)
//   --ideal   a diagnosis, not the product: the lit frames as an ideal separation would give
//             them (the true scene plus the lit frame's own sensor noise); --ideal-clipped the
//             same except at the pixels the raw frame clipped, which keep the Separator's output
#include <sched.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <exception>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/test_support/sim_disparity_eval.h"

namespace core = embedded_calibration_stereo::core;

namespace {

using core::DisparityScore;
using core::RectifiedSample;

struct Args {
  std::string config, out_dir;
  std::vector<std::string> algorithms;
  core::SimDisparitySetOptions set;
  int frame = -1;
};

std::vector<std::string> splitCommas(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

const char* litKind(const core::SimDisparitySetOptions& set) {
  using Ideal = core::SimDisparitySetOptions::Ideal;
  if (set.ideal == Ideal::kIdeal) return "IDEALLY separated (the true scene plus the lit frame's sensor noise)";
  if (set.ideal == Ideal::kIdealClipped)
    return "IDEALLY separated except where clipped (the true scene plus the lit frame's sensor noise; the "
           "Separator's output at the clipped pixels)";
  return set.separate ? "separated" : "RAW (not separated)";
}

// The options without a value; false for any other argument.
bool parseFlag(const std::string& arg, core::SimDisparitySetOptions* set) {
  using Ideal = core::SimDisparitySetOptions::Ideal;
  if (arg == "--raw") set->separate = false;
  else if (arg == "--ideal") set->ideal = Ideal::kIdeal;
  else if (arg == "--ideal-clipped") set->ideal = Ideal::kIdealClipped;
  else return false;
  return true;
}

Args parseArgs(int argc, char** argv) {
  Args a;
  a.set.scored_bursts = 3;
  a.set.lit_per_burst = 2;
  a.set.off_per_burst = 2;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const bool has_value = i + 1 < argc;
    const std::string value = has_value ? argv[i + 1] : "";
    if (parseFlag(arg, &a.set)) continue;
    if (!has_value) throw std::invalid_argument("unknown option or missing value: " + arg);
    ++i;
    if (arg == "--config") a.config = value;
    else if (arg == "--algorithms") a.algorithms = splitCommas(value);
    else if (arg == "--seed") a.set.seed = std::strtoull(value.c_str(), nullptr, 10);
    else if (arg == "--bursts") a.set.scored_bursts = std::atoi(value.c_str());
    else if (arg == "--lit") a.set.lit_per_burst = std::atoi(value.c_str());
    else if (arg == "--off") a.set.off_per_burst = std::atoi(value.c_str());
    else if (arg == "--period") a.set.period_s = std::atof(value.c_str());
    else if (arg == "--burst-frames") a.set.burst_frames = std::atoi(value.c_str());
    else if (arg == "--settle") a.set.settle_frames = std::atoi(value.c_str());
    else if (arg == "--threads") cv::setNumThreads(std::atoi(value.c_str()));
    else if (arg == "--out") a.out_dir = value;
    else if (arg == "--frame") a.frame = std::atoi(value.c_str());
    else throw std::invalid_argument("unknown option: " + arg);
  }
  if (a.config.empty()) {
    const char* src = std::getenv("ECS_SOURCE_DIR");
    a.config = std::string(src ? src : ".") + "/config/drive_photo.yaml";
  }
  a.set.config_path = a.config;
  if (a.algorithms.empty()) a.algorithms = core::acceptedDisparityAlgorithms();
  return a;
}

// "<CPU model>, nproc <n>" (the cores this process may use), for the figures' record.
std::string machineName() {
  std::ifstream in("/proc/cpuinfo");
  std::string line, model = "unknown CPU";
  while (std::getline(in, line))
    if (line.rfind("model name", 0) == 0 && line.find(':') != std::string::npos) {
      model = line.substr(line.find(':') + 2);
      break;
    }
  cpu_set_t cpus;
  const int usable = sched_getaffinity(0, sizeof cpus, &cpus) == 0 ? CPU_COUNT(&cpus) : 0;
  return model + ", nproc " + std::to_string(usable);
}

double processCpuMs() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}

// One matcher configuration and what it measured.
struct Matcher {
  std::string label;
  core::DisparityOptions options;
  DisparityScore off, lit;
  double wall_ms = 0.0, cpu_ms = 0.0;  // per frame, over both kinds
  cv::Mat shown;                       // its disparity of the lit frame written with --out
};

std::vector<Matcher> matchersFor(const std::vector<std::string>& names) {
  std::vector<Matcher> out;
  const std::string default_name = core::DisparityOptions().algorithm;
  for (const std::string& name : names) {
    Matcher ours;
    ours.options.algorithm = name;
    ours.label = name + (name == default_name ? " (default)" : " (ours)");
    out.push_back(ours);
    if (name == "bm" || name == "sgbm") {
      Matcher stock;
      stock.options = core::DisparityOptions::stereoImageProcDefaults(name);
      stock.label = name + " (stereo_image_proc)";
      out.push_back(stock);
    }
  }
  return out;
}

// Runs the matcher over the light-off and lit samples (after one warm-up frame: buffers and
// threads), timing every frame, and keeps its disparity of lit frame `shown`.
void run(const core::SimDisparitySet& set, int shown, Matcher* m) {
  core::DisparityComputer computer(m->options);
  computer.compute(set.light_off[0].left, set.light_off[0].right);
  double wall = 0.0;
  const double cpu0 = processCpuMs();
  const auto pass = [&](const std::vector<RectifiedSample>& samples, DisparityScore* score, bool lit) {
    for (size_t i = 0; i < samples.size(); ++i) {
      const auto t0 = std::chrono::steady_clock::now();
      const cv::Mat d = computer.compute(samples[i].left, samples[i].right);
      wall += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      score->add(core::scoreDisparity(d, samples[i].truth));
      if (lit && static_cast<int>(i) == shown) m->shown = d.clone();
    }
  };
  pass(set.light_off, &m->off, false);
  pass(set.lit, &m->lit, true);
  const double frames = static_cast<double>(set.light_off.size() + set.lit.size());
  // The CPU time includes scoring, a single-threaded pass much cheaper than any matcher.
  m->cpu_ms = (processCpuMs() - cpu0) / frames;
  m->wall_ms = wall / frames;
}

void printTable(const std::vector<Matcher>& matchers, const core::SimDisparitySet& set, bool separated) {
  std::printf("\n%-28s %-14s %9s %9s %9s %10s %9s %9s\n", "algorithm", "frames", "bad>2px", "invalid",
              "rms px", "lit-off", "wall ms", "CPU ms");
  const char* lit_kind = separated ? "separated lit" : "raw lit";
  for (const Matcher& m : matchers) {
    std::printf("%-28s %-14s %8.2f%% %8.2f%% %9.3f %10s %9.1f %9.1f\n", m.label.c_str(), "light-off",
                m.off.badPercent(), m.off.invalidPercent(), m.off.inlierRmsPx(), "", m.wall_ms, m.cpu_ms);
    std::printf("%-28s %-14s %8.2f%% %8.2f%% %9.3f %+7.2f pt\n", "", lit_kind, m.lit.badPercent(),
                m.lit.invalidPercent(), m.lit.inlierRmsPx(), m.lit.badPercent() - m.off.badPercent());
  }
  std::printf("\n(%zu light-off and %zu lit frames; bad and invalid over the pixels with truth; rms over the "
              "valid pixels within 2 px; lit-off: bad>2px, percentage points; wall and CPU per frame, "
              "all threads)\n",
              set.light_off.size(), set.lit.size());
}

// Disparity to colour on one scale for every image: JET from 0 (blue, far) to `max_d` (red,
// near), invalid and unknown black, as the demo's overview.
cv::Mat colourDisparity(const cv::Mat& d, double max_d) {
  cv::Mat scaled(d.size(), CV_8UC1), valid(d.size(), CV_8UC1);
  for (int v = 0; v < d.rows; ++v)
    for (int u = 0; u < d.cols; ++u) {
      const float x = d.at<float>(v, u);
      const bool ok = std::isfinite(x) && x > 0.0f;
      valid.at<uchar>(v, u) = ok ? 255 : 0;
      scaled.at<uchar>(v, u) = ok ? cv::saturate_cast<uchar>(255.0 * std::min<double>(x, max_d) / max_d) : 0;
    }
  cv::Mat colour;
  cv::applyColorMap(scaled, colour, cv::COLORMAP_JET);
  cv::Mat out(d.size(), CV_8UC3, cv::Scalar::all(0));
  colour.copyTo(out, valid);
  return out;
}

// The smallest PNG files (the montage goes into docs/images).
const std::vector<int> kPng = {cv::IMWRITE_PNG_COMPRESSION, 9};

// A half-size tile with its label on a black strip above it.
cv::Mat tile(const cv::Mat& image, const std::string& label) {
  cv::Mat bgr, small;
  if (image.channels() == 1) cv::cvtColor(image, bgr, cv::COLOR_GRAY2BGR);
  else bgr = image;
  cv::resize(bgr, small, cv::Size(bgr.cols / 2, bgr.rows / 2), 0, 0, cv::INTER_AREA);
  cv::Mat out(small.rows + 22, small.cols, CV_8UC3, cv::Scalar::all(0));
  small.copyTo(out(cv::Rect(0, 22, small.cols, small.rows)));
  cv::putText(out, label, cv::Point(4, 16), cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar::all(255), 1, cv::LINE_AA);
  return out;
}

std::string fileName(std::string label) {
  for (char& c : label)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  label.erase(std::unique(label.begin(), label.end(), [](char a, char b) { return a == '_' && b == '_'; }),
              label.end());
  while (!label.empty() && label.back() == '_') label.pop_back();
  return label;
}

cv::Mat montage(const std::vector<cv::Mat>& tiles, int columns) {
  const int rows = (static_cast<int>(tiles.size()) + columns - 1) / columns;
  const cv::Size t = tiles[0].size();
  cv::Mat out(rows * t.height, columns * t.width, CV_8UC3, cv::Scalar::all(0));
  for (size_t i = 0; i < tiles.size(); ++i)
    tiles[i].copyTo(out(cv::Rect((i % columns) * t.width, (i / columns) * t.height, t.width, t.height)));
  return out;
}

void writeImages(const std::string& dir, const RectifiedSample& sample, const std::vector<Matcher>& matchers,
                 bool separated) {
  ::mkdir(dir.c_str(), 0755);
  double max_truth = 0.0;
  cv::minMaxLoc(sample.truth, nullptr, &max_truth);
  const double max_d = std::max(8.0, 8.0 * std::ceil(max_truth / 8.0));
  std::vector<cv::Mat> tiles;
  const auto add = [&](const cv::Mat& image, const std::string& name, const std::string& label) {
    if (!cv::imwrite(dir + "/" + name + ".png", image, kPng)) throw std::runtime_error("cannot write " + dir + "/" + name);
    tiles.push_back(tile(image, label));
  };
  add(sample.raw_left, "left_lit_raw", "frame " + std::to_string(sample.frame) + ", light on: raw left");
  add(sample.left, "left_matched", separated ? "separated left (matched)" : "raw left (matched, not separated)");
  add(colourDisparity(sample.truth, max_d), "disparity_truth",
      "truth (0.." + std::to_string(static_cast<int>(max_d)) + " px)");
  for (const Matcher& m : matchers)
    add(colourDisparity(m.shown, max_d), "disparity_" + fileName(m.label), m.label);
  const std::string path = dir + "/montage.png";
  if (!cv::imwrite(path, montage(tiles, 4), kPng)) throw std::runtime_error("cannot write " + path);
  std::printf("wrote %s (and each image alone beside it)\n", path.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const Args args = parseArgs(argc, argv);
    if (args.algorithms.empty()) throw std::invalid_argument("no disparity algorithm to run");
    std::printf("bench_disparity_sim: %s\n", machineName().c_str());
    std::printf("config %s, seed %llu, %d scored bursts x (%d light-off + %d lit), bursts of %d lit frames every "
                "%.1f s (%d settle), cv threads %d, lit %s\n",
                args.config.c_str(), static_cast<unsigned long long>(args.set.seed), args.set.scored_bursts,
                args.set.off_per_burst, args.set.lit_per_burst, args.set.burst_frames, args.set.period_s,
                args.set.settle_frames, cv::getNumThreads(),
                litKind(args.set));
    const auto t0 = std::chrono::steady_clock::now();
    const core::SimDisparitySet set = core::renderSimDisparitySet(args.set);
    std::printf("rendered, learned, separated, rectified in %.1f s\n",
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    for (const std::string& line : set.log) std::printf("  separator %s\n", line.c_str());
    const int shown = args.frame >= 0 ? std::min<int>(args.frame, set.lit.size() - 1) : set.lit.size() / 2;
    std::vector<Matcher> matchers = matchersFor(args.algorithms);
    for (Matcher& m : matchers) run(set, shown, &m);
    printTable(matchers, set, args.set.separate);
    if (!args.out_dir.empty()) writeImages(args.out_dir, set.lit[shown], matchers, args.set.separate);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_disparity_sim: %s\n", e.what());
    return 1;
  }
  return 0;
}
