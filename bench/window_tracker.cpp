// WindowTracker timing on the moving drive_photo scenario: windows of light-on frames at 30 fps
// between a light-off frame before and one after (as test_window_tracker), each tracked
// `repeats` times by one tracker (the boards' state follows from window to window).
//   bench_window_tracker [--config FILE] [--windows N] [--repeats R] [--scene 0|1] [--frames F]
//                        [--flow-scale S] [--flow-stride P] [--flow-pair-step K] [--flow-iterations I]
// (default: $ECS_SOURCE_DIR/config/drive_photo.yaml, 6 windows 2 s apart, 3 repeats, no scene
// correspondences, 10 light-on frames (the launch files' bursts have 30), the learner's flow at
// its default finest scale, patch stride, pair step and refinement iterations). Prints per window the
// wall-clock ms of track(), the process CPU time it took (both cameras' threads; on a loaded
// machine the wall time is inflated by other processes, the CPU time much less), the resident
// memory that track() took at its peak above what the process held before it (the kernel's
// peak is reset first), and the corners' RMS against the truth; then the medians.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"
#include "embedded_calibration_stereo/test_support/corner_score.h"
#include "embedded_calibration_stereo/test_support/rendered_window.h"
#include "embedded_calibration_stereo/test_support/process_memory.h"
#include "embedded_calibration_stereo/test_support/sim_prior.h"

using namespace embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

namespace {

double cpuMs() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return 1e3 * ts.tv_sec + 1e-6 * ts.tv_nsec;
}

// The process's resident memory now ("VmRSS") or its peak since resetPeakMemory() ("VmHWM"), MB.
double residentMb(const char* key) { return test_support::processStatusKb(0, key) / 1024.0; }

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  const char* source = std::getenv("ECS_SOURCE_DIR");
  std::string config = source ? std::string(source) + "/config/drive_photo.yaml" : "";
  int windows = 6, repeats = 3, scene = 0, lit_frames = 10;
  WindowTrackerOptions options;
  for (int i = 1; i < argc; ++i) {
    const auto value = [&]() -> const char* { return i + 1 < argc ? argv[++i] : ""; };
    if (!std::strcmp(argv[i], "--config")) config = value();
    else if (!std::strcmp(argv[i], "--windows")) windows = std::atoi(value());
    else if (!std::strcmp(argv[i], "--repeats")) repeats = std::atoi(value());
    else if (!std::strcmp(argv[i], "--scene")) scene = std::atoi(value());
    else if (!std::strcmp(argv[i], "--frames")) lit_frames = std::atoi(value());
    else if (!std::strcmp(argv[i], "--flow-scale")) options.learner.flow_finest_scale = std::atoi(value());
    else if (!std::strcmp(argv[i], "--flow-stride")) options.learner.flow_patch_stride = std::atoi(value());
    else if (!std::strcmp(argv[i], "--flow-pair-step")) options.learner.flow_pair_step = std::atoi(value());
    else if (!std::strcmp(argv[i], "--flow-iterations"))
      options.learner.flow_refinement_iterations = std::atoi(value());
    else {
      std::fprintf(stderr, "bench_window_tracker: unknown argument %s\n", argv[i]);
      return 2;
    }
  }
  if (config.empty() || windows < 1 || repeats < 1 || lit_frames < 2 || lit_frames > 50) {
    std::fprintf(stderr,
                 "bench_window_tracker: need --config (or ECS_SOURCE_DIR), windows and repeats >= 1, frames 2..50\n");
    return 2;
  }
  constexpr double kFps = 30.0;
  const SimRigConfig rig_config = loadSimRigConfig(config);
  SimRig sim(rig_config);
  const PatternPrior prior = teachSimPrior(sim, 1.0);
  options.scene_matches = scene != 0;
  WindowTracker tracker(prior, TrackerOptions(), options, rig_config.rig);
  std::vector<double> wall_all, cpu_all, rms_all, memory_all;
  for (int w = 0; w < windows; ++w) {
    const int j = 45 + std::max(60, 2 * lit_frames + 30) * w;  // the light-off frame before the window
    const RenderedWindow window = renderWindow(sim, j, lit_frames);
    const WindowFrames &left = window.left, &right = window.right;
    const SimFrame& lit = window.lit.back();
    std::vector<double> wall, cpu;
    double memory = 0.0;
    CornerScore score;
    for (int r = 0; r < repeats; ++r) {
      test_support::resetPeakMemory();
      const double before_mb = residentMb("VmRSS");
      const auto t0 = std::chrono::steady_clock::now();
      const double c0 = cpuMs();
      const WindowTrack track = tracker.track(left, right, (j + lit_frames) / kFps);
      cpu.push_back(cpuMs() - c0);
      wall.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      memory = std::max(memory, residentMb("VmHWM") - before_mb);
      if (r == 0) score.add(track.observation, lit.observations);
    }
    std::printf("window %d (t %.1f s, %d light-on frames): %.0f ms wall, %.0f ms CPU (median of %d), "
                "peak memory +%.0f MB; %s\n",
                w, j / kFps, lit_frames, median(wall), median(cpu), repeats, memory, score.str().c_str());
    wall_all.push_back(median(wall));
    cpu_all.push_back(median(cpu));
    rms_all.push_back(score.rms());
    memory_all.push_back(memory);
  }
  std::printf("median over %d windows of %d light-on frames: %.0f ms wall, %.0f ms CPU, peak memory +%.0f MB "
              "(the largest +%.0f MB), %.4f px RMS\n",
              windows, lit_frames, median(wall_all), median(cpu_all), median(memory_all),
              *std::max_element(memory_all.begin(), memory_all.end()), median(rms_all));
  return 0;
}
