// Rectification cost at 752x480 mono8 for both methods: map build time (done off the image
// thread) and remap time per stereo pair (budget <= 3 ms).
// Usage: bench_rectify [iterations] [threads]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <opencv2/core.hpp>
#include <vector>

#include "embedded_calibration_stereo/core/depth/rectification.h"

namespace core = embedded_calibration_stereo::core;

namespace {

core::StereoRig rig752() {
  core::StereoRig rig;
  for (core::PinholeCamera* c : {&rig.left, &rig.right}) {
    c->width = 752;
    c->height = 480;
    c->fx = c->fy = 650;
    c->cx = 375;
    c->cy = 240;
    c->dist = {-0.28, 0.07, 0, 0, 0};
  }
  rig.right.fx = 655;
  rig.right_from_left.linear() = core::rotationFromVectorDeg(Eigen::Vector3d(0.3, -0.8, 0.4));
  rig.right_from_left.translation() = Eigen::Vector3d(-0.12, 0.001, 0.0);
  return rig;
}

// CPU time of this process (all threads): the cost itself when other processes share the cores.
double processCpuMs() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}

// Median wall time of f in ms; *cpu_ms receives the mean CPU time per call.
template <typename F>
double medianMs(int iterations, F&& f, double* cpu_ms) {
  std::vector<double> ms;
  const double cpu0 = processCpuMs();
  for (int i = 0; i < iterations; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    f();
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                     .count());
  }
  *cpu_ms = (processCpuMs() - cpu0) / iterations;
  std::sort(ms.begin(), ms.end());
  return ms[ms.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  const int iterations = argc > 1 ? std::max(1, std::atoi(argv[1])) : 100;
  const int threads = argc > 2 ? std::max(1, std::atoi(argv[2])) : 2;
  cv::setNumThreads(threads);
  const core::StereoRig rig = rig752();
  cv::Mat left(480, 752, CV_8U), right(480, 752, CV_8U), left_rect, right_rect;
  cv::randu(left, 0, 255);
  cv::randu(right, 0, 255);
  std::printf("bench_rectify: 752x480 mono8, %d threads, median of %d runs\n", threads, iterations);
  for (const auto method : {core::RectificationMethod::kBouguet, core::RectificationMethod::kFusiello}) {
    core::RectificationOptions options;
    options.method = method;
    double build_cpu, pair_cpu;
    const double build_ms = medianMs(
        std::max(1, iterations / 10), [&] { core::RectificationMaps::build(rig, options); },
        &build_cpu);
    const core::RectificationMaps maps = core::RectificationMaps::build(rig, options);
    maps.rectify(left, right, &left_rect, &right_rect);  // allocate outputs once
    const double pair_ms = medianMs(
        iterations, [&] { maps.rectify(left, right, &left_rect, &right_rect); }, &pair_cpu);
    std::printf("%-9s map build %6.2f ms (cpu %6.2f)   rectify pair %5.2f ms (cpu %5.2f; budget 3 ms)\n",
                core::toString(method).c_str(), build_ms, build_cpu, pair_ms, pair_cpu);
  }
  return 0;
}
