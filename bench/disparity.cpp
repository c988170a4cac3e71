// Disparity throughput at 752x480 with 64 disparity levels on 2 threads, for the default
// configuration (census_sgm), its five-path mode, the census_sgm and sad matchers alone per
// kernel (instruction set), the sad fast mode, and OpenCV StereoBM/StereoSGBM configured as
// stereo_image_proc's defaults. Input: Teddy
// (ECS_SHARED_DATA_DIR) resized to 752x480 when it is found (in DATA_DIR, else
// $ECS_SHARED_DATA_DIR, else /work/shared/data), else a synthetic random-texture pair with a
// slanted disparity ramp.
// Wall times suffer when other processes share the cores; the CPU time per frame (all threads)
// shows the computing cost itself.
// Usage: bench_disparity [iterations] [threads] [DATA_DIR]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <functional>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/core/depth/census_sgm_matcher.h"
#include "embedded_calibration_stereo/core/depth/sad_matcher.h"

namespace core = embedded_calibration_stereo::core;

namespace {

const cv::Size kSize(752, 480);

bool loadTeddy(const char* data_dir, cv::Mat* left, cv::Mat* right) {
  const char* env = std::getenv("ECS_SHARED_DATA_DIR");
  std::vector<std::string> dirs;
  if (data_dir) dirs.push_back(data_dir);
  if (env) dirs.push_back(env);
  dirs.push_back("/work/shared/data");
  for (const auto& d : dirs) {
    const cv::Mat l = cv::imread(d + "/middlebury/teddy/im2.png", cv::IMREAD_GRAYSCALE);
    const cv::Mat r = cv::imread(d + "/middlebury/teddy/im6.png", cv::IMREAD_GRAYSCALE);
    if (l.empty() || r.empty()) continue;
    cv::resize(l, *left, kSize, 0, 0, cv::INTER_AREA);
    cv::resize(r, *right, kSize, 0, 0, cv::INTER_AREA);
    return true;
  }
  return false;
}

void syntheticPair(cv::Mat* left, cv::Mat* right) {
  cv::Mat texture(kSize, CV_8U);
  cv::randu(texture, 0, 255);
  cv::GaussianBlur(texture, texture, cv::Size(3, 3), 0.8);
  *left = texture;
  cv::Mat map_x(kSize, CV_32F), map_y(kSize, CV_32F);
  for (int y = 0; y < kSize.height; ++y)
    for (int x = 0; x < kSize.width; ++x) {
      map_x.at<float>(y, x) = x + 8.0f + 40.0f * x / kSize.width;  // disparity 8..48
      map_y.at<float>(y, x) = static_cast<float>(y);
    }
  cv::remap(texture, *right, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REFLECT);
}

// CPU time of this process (all threads), to tell computing cost from waiting on a loaded host.
double processCpuMs() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}

// Times f() (after 3 warm-up calls: buffers and threads) and prints one line.
void timeIt(const std::string& label, const std::function<void()>& f, int iterations) {
  for (int i = 0; i < 3; ++i) f();
  std::vector<double> ms;
  const double cpu0 = processCpuMs();
  for (int i = 0; i < iterations; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    f();
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                     .count());
  }
  const double cpu_ms = (processCpuMs() - cpu0) / iterations;
  std::sort(ms.begin(), ms.end());
  const double median = ms[ms.size() / 2];
  std::printf("%-46s wall median %6.2f ms (%6.1f fps)  best %6.2f ms (%6.1f fps)  cpu %6.2f ms/frame\n",
              label.c_str(), median, 1000.0 / median, ms[0], 1000.0 / ms[0], cpu_ms);
}

void run(const std::string& label, const core::DisparityOptions& options, const cv::Mat& left,
         const cv::Mat& right, int iterations) {
  core::DisparityComputer computer(options);
  timeIt(label, [&] { computer.compute(left, right); }, iterations);
}

}  // namespace

int main(int argc, char** argv) {
  const int iterations = argc > 1 ? std::max(1, std::atoi(argv[1])) : 30;
  const int threads = argc > 2 ? std::max(1, std::atoi(argv[2])) : 2;
  cv::setNumThreads(threads);
  cv::Mat left, right;
  const bool teddy = loadTeddy(argc > 3 ? argv[3] : nullptr, &left, &right);
  if (!teddy) syntheticPair(&left, &right);
  std::printf("bench_disparity: %dx%d, 64 disparities, %d threads, %d iterations, input %s\n",
              kSize.width, kSize.height, threads, iterations,
              teddy ? "Teddy resized" : "synthetic texture");

  core::DisparityOptions defaults;
  run("default (" + defaults.algorithm + ", " + std::to_string(defaults.sgm_paths) +
          " paths, lr, median, speckle, fill)",
      defaults, left, right, iterations);
  core::DisparityOptions five = defaults;
  five.sgm_paths = 5;
  run("census_sgm, 5 paths (lr, median, speckle, fill)", five, left, right, iterations);
  // The census_sgm matcher alone (lr and uniqueness on) per kernel and path count.
  for (const std::string& kernel : core::censusSgmKernelNames())
    for (const int paths : {8, 5}) {
      core::CensusSgmParams p = defaults.censusSgmParams();
      p.kernel = kernel;
      p.paths = paths;
      cv::Mat out;
      timeIt("census_sgm kernel " + kernel + ", " + std::to_string(paths) + " paths",
             [&] { core::computeCensusSgmDisparity16(left, right, p, &out); }, iterations);
    }
  core::DisparityOptions sad = defaults;
  sad.algorithm = "sad";
  run("sad 11x11 (lr, speckle, fill), the fast mode", sad, left, right, iterations);
  core::DisparityOptions sad_only = sad;
  sad_only.left_right_check = false;
  sad_only.fill_holes = false;
  sad_only.speckle_size = 0;
  run("sad matcher alone (no lr, speckle, fill)", sad_only, left, right, iterations);
  // The sad matcher (lr and uniqueness on, no speckle filter or filling) per kernel.
  for (const std::string& kernel : core::sadKernelNames()) {
    core::SadMatcherParams p = sad.sadMatcherParams();
    p.kernel = kernel;
    timeIt("sad kernel " + kernel + " (lr, uniqueness)",
           [&] { core::computeSadDisparity16(left, right, p); }, iterations);
  }
  core::DisparityOptions sgbm3 = defaults;
  sgbm3.algorithm = "sgbm";
  sgbm3.sgbm_mode = "sgbm_3way";
  sgbm3.correlation_window_size = 3;
  sgbm3.P1 = 72;
  sgbm3.P2 = 288;
  run("sgbm 3x3 sgbm_3way tuned (lr, speckle, fill)", sgbm3, left, right, iterations);
  using Stock = core::DisparityOptions;
  run("OpenCV StereoBM, stereo_image_proc defaults", Stock::stereoImageProcDefaults("bm"), left,
      right, iterations);
  run("OpenCV StereoSGBM, stereo_image_proc defaults", Stock::stereoImageProcDefaults("sgbm"),
      left, right, iterations);
  return 0;
}
