// Benchmark of the Separator: ms per stereo frame (both images, separateStereo: one camera per
// worker thread) for both methods at the simulated rig's size, against the design budget
// (<= 3 ms per stereo frame at 752x480 on 2 cores). Also prints each method's PSNR against the
// scene-only ground truth on the benchmarked frames, so speed and quality are read together.
//
// Usage: bench_separator path/to/sim_rig.yaml [iterations]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <exception>
#include <numeric>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/separator.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace core = embedded_calibration_stereo::core;

namespace {

constexpr double kBudgetMs = 3.0;
constexpr int kTeachFrames = 8;
constexpr int kFrames = 4;  // distinct frames cycled through (noise differs)

double cpuMs() { return 1000.0 * static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

struct Templates {
  core::DeviceTemplate left, right;
};

Templates teach(const core::SimRigConfig& config) {
  core::SimRigConfig dark = config;
  dark.scene.enabled = false;
  const core::SimRig dark_rig(dark);
  std::vector<cv::Mat> left, right;
  for (int i = 0; i < kTeachFrames; ++i) {
    const core::SimFrame f = dark_rig.render(0.0, 1.0, 100 + i);
    left.push_back(f.left);
    right.push_back(f.right);
  }
  Templates t{core::teachDeviceImage(left), core::teachDeviceImage(right)};
  const core::SimRig rig(config);
  const core::SimFrame off = rig.render(0.0, 0.0, 200);
  std::vector<core::AlphaSample> left_samples, right_samples;
  for (int i = 1; i <= 5; ++i) {
    const core::SimFrame on = rig.render(0.0, 0.2 * i, 200 + i);
    left_samples.push_back(core::measureAlphaSample(t.left, on.left, off.left));
    right_samples.push_back(core::measureAlphaSample(t.right, on.right, off.right));
  }
  t.left.alpha_curve = core::fitAlphaCurve(left_samples);
  t.right.alpha_curve = core::fitAlphaCurve(right_samples);
  return t;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s path/to/sim_rig.yaml [iterations]\n", argv[0]);
    return 2;
  }
  const int iterations = argc > 2 ? std::max(10, std::atoi(argv[2])) : 300;
  try {
    const core::SimRigConfig config = core::loadSimRigConfig(argv[1]);
    const Templates templates = teach(config);
    const core::SimRig rig(config);
    std::vector<core::SimFrame> frames;
    for (int i = 0; i < kFrames; ++i) frames.push_back(rig.render(0.0, 1.0, 300 + i));
    std::printf("separator bench: %dx%d %s, %d iterations, cv threads %d\n", frames[0].left.cols,
                frames[0].left.rows, config.encoding.c_str(), iterations, cv::getNumThreads());

    for (core::SeparationMethod method :
         {core::SeparationMethod::kRegionalAlpha, core::SeparationMethod::kPaperGlobalAlpha}) {
      core::SeparatorOptions options;
      options.method = method;
      const core::ImageSeparator left(options, templates.left), right(options, templates.right);
      cv::Mat left_scene, right_scene;
      double psnr_sum = 0.0;
      for (const core::SimFrame& f : frames) {
        core::separateStereo(left, right, f.left, f.right, &left_scene, &right_scene);
        psnr_sum += 0.5 * (cv::PSNR(left_scene, f.left_scene) + cv::PSNR(right_scene, f.right_scene));
      }
      std::vector<double> ms;
      const double cpu0 = cpuMs();
      for (int i = 0; i < iterations; ++i) {
        const core::SimFrame& f = frames[i % kFrames];
        const auto t0 = std::chrono::steady_clock::now();
        core::separateStereo(left, right, f.left, f.right, &left_scene, &right_scene);
        ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      }
      const double cpu_per_frame = (cpuMs() - cpu0) / iterations;
      std::sort(ms.begin(), ms.end());
      const double mean = std::accumulate(ms.begin(), ms.end(), 0.0) / ms.size();
      const double p50 = ms[ms.size() / 2], p95 = ms[std::min(ms.size() - 1, ms.size() * 95 / 100)];
      std::printf("%-20s wall ms/stereo frame: mean %.3f p50 %.3f p95 %.3f max %.3f | CPU %.3f ms "
                  "(%.3f ms per core on 2) | PSNR %.2f dB | budget %.1f ms: %s\n",
                  core::toString(method).c_str(), mean, p50, p95, ms.back(), cpu_per_frame,
                  cpu_per_frame / 2, psnr_sum / kFrames, kBudgetMs,
                  p50 <= kBudgetMs ? "met" : "MISSED");
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_separator: %s\n", e.what());
    return 1;
  }
  return 0;
}
