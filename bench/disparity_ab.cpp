// Two builds of the core library's disparity, call by call: each frame goes to build A, then to
// build B, and the ratio of their CPU times is taken per pair of calls. On a VM whose speed
// drifts by tens of percent within minutes (docs/depth.md, "Speed"), runs of whole benchmarks
// interleaved by process still scatter more than most changes gain; pairs of calls a few
// milliseconds apart see the same machine. Each build is loaded with dlopen (RTLD_LOCAL |
// RTLD_DEEPBIND), so each calls its own code.
//
//   bench_disparity_ab LIB_A LIB_B [frames] [threads] [paths] [KERNEL_A KERNEL_B]
//
// LIB_A, LIB_B: libembedded_calibration_stereo_core.so of two builds (e.g. copy devel/lib's
// before a change; the same file twice to compare kernels). Both must have this build's
// DisparityOptions, DisparityComputer and CensusSgmParams layout. Without kernels: the whole
// DisparityComputer::compute; with them: the census_sgm matcher alone
// (computeCensusSgmDisparity16) with the named kernel of each build.
// Prints each build's median CPU per frame, the per-pair ratio B / A (median and quartiles; the
// two calls of a pair alternate in order from one frame to the next), and
// whether both gave the same disparities. Input: Teddy resized to 752x480, 64 disparities, the
// default options (census_sgm, 8 paths, median, speckle filter, filling).
#include <dlfcn.h>
#include <time.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/disparity.h"

namespace core = embedded_calibration_stereo::core;

namespace {

// The two members called, by their mangled names (GCC / Clang, Itanium ABI).
constexpr const char* kConstructor =
    "_ZN27embedded_calibration_stereo4core17DisparityComputerC1ERKNS0_16DisparityOptionsE";
constexpr const char* kCompute =
    "_ZN27embedded_calibration_stereo4core17DisparityComputer7computeERKN2cv3MatES5_PS3_S6_";
constexpr const char* kMatcher =
    "_ZN27embedded_calibration_stereo4core27computeCensusSgmDisparity16ERKN2cv3MatES4_RKNS0_"
    "15CensusSgmParamsEPS2_S8_";
using Constructor = void (*)(void*, const core::DisparityOptions&);
using Compute = void (*)(void*, const cv::Mat&, const cv::Mat&, cv::Mat*, cv::Mat*);
using Matcher = void (*)(const cv::Mat&, const cv::Mat&, const core::CensusSgmParams&, cv::Mat*, cv::Mat*);

struct Build {
  std::string path;
  Compute compute = nullptr;
  void* computer = nullptr;  // a DisparityComputer of that build (never destroyed: the process ends)
  Matcher matcher = nullptr;
  core::CensusSgmParams params;  // the matcher's, kernel included
  cv::Mat disparity;
  std::vector<double> cpu_ms;

  void run(const cv::Mat& left, const cv::Mat& right) {
    if (params.kernel.empty())
      compute(computer, left, right, &disparity, nullptr);
    else
      matcher(left, right, params, &disparity, nullptr);
  }
};

bool load(const std::string& path, const core::DisparityOptions& options, Build* build) {
  void* library = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL | RTLD_DEEPBIND);
  if (!library) {
    std::fprintf(stderr, "bench_disparity_ab: cannot load %s: %s\n", path.c_str(), dlerror());
    return false;
  }
  const auto construct = reinterpret_cast<Constructor>(dlsym(library, kConstructor));
  build->compute = reinterpret_cast<Compute>(dlsym(library, kCompute));
  build->matcher = reinterpret_cast<Matcher>(dlsym(library, kMatcher));
  if (!construct || !build->compute || !build->matcher) {
    std::fprintf(stderr, "bench_disparity_ab: %s has no DisparityComputer of this build's signature\n",
                 path.c_str());
    return false;
  }
  build->path = path;
  build->computer = ::operator new(sizeof(core::DisparityComputer));
  construct(build->computer, options);
  return true;
}

double processCpuMs() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}

double quantile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v[static_cast<size_t>(q * (v.size() - 1) + 0.5)];
}

bool loadTeddy(cv::Mat* left, cv::Mat* right) {
  const char* env = std::getenv("ECS_SHARED_DATA_DIR");
  const std::string dir = std::string(env ? env : "/work/shared/data") + "/middlebury/teddy/";
  const cv::Mat l = cv::imread(dir + "im2.png", cv::IMREAD_GRAYSCALE);
  const cv::Mat r = cv::imread(dir + "im6.png", cv::IMREAD_GRAYSCALE);
  if (l.empty() || r.empty()) return false;
  cv::resize(l, *left, cv::Size(752, 480), 0, 0, cv::INTER_AREA);
  cv::resize(r, *right, cv::Size(752, 480), 0, 0, cv::INTER_AREA);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: bench_disparity_ab LIB_A LIB_B [frames] [threads] [paths] [KERNEL_A KERNEL_B]\n");
    return 2;
  }
  const int frames = argc > 3 ? std::max(10, std::atoi(argv[3])) : 200;
  const int threads = argc > 4 ? std::max(1, std::atoi(argv[4])) : 2;
  core::DisparityOptions options;
  if (argc > 5) options.sgm_paths = std::atoi(argv[5]);
  cv::Mat left, right;
  if (!loadTeddy(&left, &right)) {
    std::fprintf(stderr, "bench_disparity_ab: Teddy not found (ECS_SHARED_DATA_DIR)\n");
    return 1;
  }
  Build builds[2];
  for (int b = 0; b < 2; ++b) {
    if (!load(argv[1 + b], options, &builds[b])) return 1;
    builds[b].params.kernel.clear();
    if (argc > 7) {
      builds[b].params = options.censusSgmParams();
      builds[b].params.kernel = argv[6 + b];
    }
  }
  cv::setNumThreads(threads);
  std::vector<double> ratios;
  for (int i = 0; i < frames; ++i) {
    for (int k = 0; k < 2; ++k) {  // A first on even frames, B first on odd ones: the second call
      Build& b = builds[(i + k) % 2];  // of a pair is a little faster (caches, clocks)
      const double t0 = processCpuMs();
      b.run(left, right);
      b.cpu_ms.push_back(processCpuMs() - t0);
    }
    if (i >= 6) ratios.push_back(builds[1].cpu_ms.back() / builds[0].cpu_ms.back());  // 6 warm-up pairs
  }
  std::printf("bench_disparity_ab: 752x480, 64 disparities, %s, %d paths, %d threads, %d frames each\n",
              argc > 7 ? "the census_sgm matcher alone" : "the default disparity", options.sgm_paths,
              threads, frames);
  for (int b = 0; b < 2; ++b)
    std::printf("  %c %s%s%s: CPU per frame median %.2f ms\n", 'A' + b, builds[b].path.c_str(),
                argc > 7 ? ", kernel " : "", builds[b].params.kernel.c_str(), quantile(builds[b].cpu_ms, 0.5));
  std::printf("  B / A per pair of calls: median %.3f (quartiles %.3f .. %.3f)\n", quantile(ratios, 0.5),
              quantile(ratios, 0.25), quantile(ratios, 0.75));
  // Compared as bytes: NaN (no disparity) differs from itself as a float.
  const auto bytes = [](const cv::Mat& m) { return cv::Mat(1, static_cast<int>(m.total() * m.elemSize()), CV_8U, m.data); };
  const bool same = builds[0].disparity.size() == builds[1].disparity.size() &&
                    builds[0].disparity.type() == builds[1].disparity.type() &&
                    cv::countNonZero(bytes(builds[0].disparity) != bytes(builds[1].disparity)) == 0;
  std::printf("  disparities: %s\n", same ? "the same bits" : "DIFFERENT");
  return 0;
}
