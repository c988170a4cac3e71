// Benchmark of the simulated rig's renderer: CPU time per stereo frame (all threads) of each
// scenario at 752x480 against the design budget of 8 ms, still or moving, with the wall time
// beside it and the machine it ran on. Cases: light on, light off, the frame after a zoom step
// (ray maps and every layer rebuilt), and a thermal drift (the right camera's device layer
// re-rendered every frame, as during the demo's thermal ramp).
//
// Usage: bench_sim_render [--kernel NAME] [--threads N] [config.yaml ...] [frames]
//   --kernel: the scene renderer's row kernel (SimRig::sceneKernelNames(); default the widest).
//   --threads: OpenCV's worker threads (cv::setNumThreads; default as OpenCV chooses).
//   Without a path, $ECS_SOURCE_DIR/config/{sim_rig,drive_photo,handheld_photo}.yaml are used.
#include <algorithm>
#include <chrono>
#include <fstream>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <memory>
#include <numeric>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace core = embedded_calibration_stereo::core;

namespace {

constexpr double kCpuBudgetMs = 8.0;  // per stereo frame, all threads, still or moving

struct Stats {
  double mean, p50, p95, max;
};

Stats summarize(std::vector<double> ms) {
  std::sort(ms.begin(), ms.end());
  const auto at = [&](double q) { return ms[std::min(ms.size() - 1, static_cast<size_t>(q * ms.size()))]; };
  return {std::accumulate(ms.begin(), ms.end(), 0.0) / ms.size(), at(0.5), at(0.95), ms.back()};
}

// Process CPU time (all threads): what a frame costs the machine, whatever else runs on it.
double cpuMs() { return 1000.0 * static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

double elapsedMs(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - since).count();
}

// "<CPU model>, <n> cores" from /proc/cpuinfo (Linux), for the figures' record.
std::string machineName() {
  std::ifstream in("/proc/cpuinfo");
  std::string line, model = "unknown CPU";
  int cores = 0;
  while (std::getline(in, line)) {
    if (line.rfind("model name", 0) == 0 && line.find(':') != std::string::npos) model = line.substr(line.find(':') + 2);
    if (line.rfind("processor", 0) == 0) ++cores;
  }
  return model + ", " + std::to_string(cores) + " cores";
}

struct Run {
  std::vector<double> wall_ms;
  double cpu_ms_per_frame;
};

void report(const char* what, const Run& run) {
  const Stats s = summarize(run.wall_ms);
  std::printf("%-40s CPU %6.2f ms/stereo frame [%s budget %.0f ms]   wall mean %6.2f  p95 %6.2f  max %6.2f ms\n",
              what, run.cpu_ms_per_frame, run.cpu_ms_per_frame <= kCpuBudgetMs ? "within" : "OVER", kCpuBudgetMs,
              s.mean, s.p95, s.max);
}

int benchScenario(const std::string& path, int frames, const std::string& kernel) {
  core::SimRigConfig config;
  try {
    config = core::loadSimRigConfig(path);
  } catch (const core::ConfigError& e) {
    std::fprintf(stderr, "cannot load %s: %s\n", path.c_str(), e.what());
    return 1;
  }
  const bool moving = !config.trajectory.isStatic() || !config.scene.movers.empty();
  std::printf("\nsim render benchmark: %s\n", path.c_str());
  std::printf("image %dx%d, %zu scene planes, %zu movers, head %s, motion blur samples %d, %zu virtual boards, "
              "encoding %s, cv::getNumThreads() = %d; %s\n",
              config.rig.left.width, config.rig.left.height, config.scene.planes.size(), config.scene.movers.size(),
              core::trajectoryKindName(config.trajectory.kind),
              config.motion_blur.exposure_s > 0 ? config.motion_blur.samples : 1,
              config.device.virtualBoards().size(), config.encoding.c_str(), cv::getNumThreads(),
              machineName().c_str());

  auto start = std::chrono::steady_clock::now();
  std::unique_ptr<core::SimRig> rig_ptr;
  try {
    rig_ptr = std::make_unique<core::SimRig>(config);
  } catch (const core::ConfigError& e) {
    std::fprintf(stderr, "cannot build %s: %s\n", path.c_str(), e.what());
    return 1;
  }
  core::SimRig& rig = *rig_ptr;
  if (!kernel.empty() && !rig.useSceneKernel(kernel)) {
    std::fprintf(stderr, "this build or CPU has no scene kernel '%s'\n", kernel.c_str());
    return 1;
  }
  std::printf("scene kernel: %s\n", rig.sceneKernel().c_str());
  std::printf("construction (scene textures): %.1f ms\n", elapsedMs(start));

  const double dt = 1.0 / config.fps;
  double t = 0.0;
  uint64_t seed = 1;
  start = std::chrono::steady_clock::now();
  rig.render(t, 1.0, seed++);
  std::printf("first frame (ray maps + all layers): %.1f ms\n", elapsedMs(start));

  auto run = [&](double light, int n) {
    Run r;
    const double cpu0 = cpuMs();
    for (int i = 0; i < n; ++i) {
      t += dt;
      const auto s = std::chrono::steady_clock::now();
      const core::SimFrame f = rig.render(t, light, seed++);
      r.wall_ms.push_back(elapsedMs(s));
      if (f.left.empty() || f.right.empty()) std::abort();
    }
    r.cpu_ms_per_frame = (cpuMs() - cpu0) / n;
    return r;
  };

  const char* kind = moving ? "moving" : "still";
  report((std::string("steady state (") + kind + "), light on").c_str(), run(1.0, frames));
  report((std::string("steady state (") + kind + "), light off").c_str(), run(0.0, frames));

  // Zoom: both cameras' ray maps and layers are rebuilt once, then cached again.
  core::DriftRequest zoom;
  zoom.focal_scale = 1.03;
  rig.setDrift(zoom);
  start = std::chrono::steady_clock::now();
  const double cpu0 = cpuMs();
  rig.render(t += dt, 1.0, seed++);
  std::printf("%-40s CPU %6.2f ms (one frame)   wall %6.2f ms\n", "after a zoom step (rays + layers rebuilt)",
              cpuMs() - cpu0, elapsedMs(start));

  // Thermal drift: the right camera moves every frame, so its device layer is re-rendered per frame.
  core::DriftRequest thermal;
  thermal.thermal_rate_deg_per_s = 0.01;
  rig.setDrift(thermal);
  report("thermal drift (right device every frame)", run(1.0, frames));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> paths;
  int frames = 100;
  std::string kernel;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--kernel" && i + 1 < argc)
      kernel = argv[++i];
    else if (arg == "--threads" && i + 1 < argc)
      cv::setNumThreads(std::atoi(argv[++i]));
    else if (!arg.empty() && arg.find_first_not_of("0123456789") == std::string::npos)
      frames = std::max(10, std::atoi(arg.c_str()));
    else
      paths.push_back(arg);
  }
  if (paths.empty()) {
    const char* src = std::getenv("ECS_SOURCE_DIR");
    if (!src) {
      std::fprintf(stderr,
                   "usage: %s [--kernel NAME] [--threads N] [config.yaml ...] [frames]\n"
                   "       (or set ECS_SOURCE_DIR to the package source directory)\n",
                   argv[0]);
      return 2;
    }
    for (const char* name : {"sim_rig", "drive_photo", "handheld_photo"})
      paths.push_back(std::string(src) + "/config/" + name + ".yaml");
  }
  int status = 0;
  for (const std::string& path : paths) status |= benchScenario(path, frames, kernel);
  return status;
}
