// Pattern tracker timing and detection rates on simulated stereo frames, against OpenCV's
// chessboard detectors on the same frames.
//   bench_tracker [sim_rig.yaml | drive_photo.yaml | ...] [frames]
// (default: $ECS_SOURCE_DIR/config/sim_rig.yaml, 40 frames). Runs: with a light-off frame taken
// at t = 0 (a still world: the fresh background; a moving one: stale), with light-off frames
// 3-10 frames old (windows of 8), and without any. Prints wall-clock ms per stereo
// pair and the process CPU time per pair (all threads; on a loaded machine the wall time is
// inflated by other processes, the CPU time much less).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <map>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/sim/trajectory.h"
#include "embedded_calibration_stereo/test_support/corner_score.h"
#include "embedded_calibration_stereo/test_support/sim_prior.h"

using namespace embedded_calibration_stereo::core;
using Clock = std::chrono::steady_clock;

namespace {

double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

struct Stats {
  std::vector<double> ms;
  void print(const char* what) const {
    std::vector<double> s = ms;
    std::sort(s.begin(), s.end());
    double mean = 0;
    for (double v : s) mean += v / s.size();
    std::printf("%-46s mean %7.2f  median %7.2f  p95 %7.2f  max %7.2f ms  (n=%zu)\n", what, mean,
                s[s.size() / 2], s[std::min(s.size() - 1, static_cast<size_t>(0.95 * s.size()))], s.back(),
                s.size());
  }
};

// backgrounds[k]: the light-off frame set before tracking frame k (nullptr: keep the one set).
void trackRun(const char* name, const PatternPrior& prior, const std::vector<const SimFrame*>& backgrounds,
              const std::vector<SimFrame>& frames) {
  PatternTracker tracker(prior, TrackerOptions());
  Stats time, cpu;
  CornerScore acc;
  for (size_t k = 0; k < frames.size(); ++k) {
    if (backgrounds[k]) tracker.setBackground(backgrounds[k]->left, backgrounds[k]->right);
    const Clock::time_point t0 = Clock::now();
    const std::clock_t c0 = std::clock();
    const StereoObservation obs = tracker.trackStereo(frames[k].left, frames[k].right, k / 30.0);
    const double ms = msSince(t0);
    const double cpu_ms = 1000.0 * (std::clock() - c0) / CLOCKS_PER_SEC;
    if (k >= 3) {  // steady state: after the first frames from the prior
      time.ms.push_back(ms);
      cpu.ms.push_back(cpu_ms);
    }
    acc.add(obs.left, frames[k].observations.left);
    acc.add(obs.right, frames[k].observations.right);
  }
  time.print((std::string(name) + ": ms per stereo pair").c_str());
  cpu.print((std::string(name) + ": CPU ms per pair (all threads)").c_str());
  std::printf("%-46s %s\n", (std::string(name) + ": accuracy").c_str(), acc.str().c_str());
}

}  // namespace

int main(int argc, char** argv) {
  std::string path;
  if (argc > 1) {
    path = argv[1];
  } else if (const char* dir = std::getenv("ECS_SOURCE_DIR")) {
    path = std::string(dir) + "/config/sim_rig.yaml";
  } else {
    std::fprintf(stderr, "usage: bench_tracker SIM_RIG.yaml [frames]   (or set ECS_SOURCE_DIR)\n");
    return 2;
  }
  const int frame_count = argc > 2 ? std::max(5, std::atoi(argv[2])) : 40;
  const SimRigConfig config = loadSimRigConfig(path);
  const SimRig sim(config);
  std::printf("sim: %s, %dx%d %s, t=%.2f r=%.2f noise %.1f, %zu virtual boards; OpenCV threads %d, CPUs %d\n",
              path.c_str(), config.rig.left.width, config.rig.left.height, config.encoding.c_str(),
              config.optics.transmittance, config.optics.reflectance, config.noise_sigma,
              sim.virtualBoards().size(), cv::getNumThreads(), cv::getNumberOfCPUs());

  const SimFrame on = sim.render(0.0, 1.0, 1), off = sim.render(0.0, 0.0, 2);
  std::vector<SimFrame> frames;
  for (int k = 0; k < frame_count; ++k) frames.push_back(sim.render(0.1 + k / 30.0, 1.0, 1000 + k));

  Stats teach_time;
  PatternPrior prior;
  for (int k = 0; k < 3; ++k) {
    const Clock::time_point t0 = Clock::now();
    prior = teachSimPrior(sim, on, off);
    teach_time.ms.push_back(msSince(t0));
  }
  teach_time.print("teach (on/off pair, both cameras)");

  // A fresh light-off frame of a still world (the teaching one), as the driver takes before every
  // light-on burst; in a moving scenario it is stale from the first frame on.
  std::vector<const SimFrame*> teach_off(frames.size(), nullptr), none(frames.size(), nullptr);
  teach_off[0] = &off;
  trackRun(config.trajectory.kind == SimTrajectory::Kind::kStatic ? "track with background"
                                                                   : "track with the t=0 light-off frame",
           prior, teach_off, frames);
  // Windows of 8 light-on frames, each after a light-off frame taken 3 frames before the first.
  std::vector<SimFrame> offs;
  offs.reserve(frames.size());
  std::vector<const SimFrame*> stale(frames.size(), nullptr);
  for (size_t k = 0; k < frames.size(); k += 8) {
    offs.push_back(sim.render(0.1 + (static_cast<double>(k) - 3) / 30.0, 0.0, 5000 + k));
    stale[k] = &offs.back();
  }
  trackRun("track with a light-off frame 3-10 frames old", prior, stale, frames);
  trackRun("track without background", prior, none, frames);

  // OpenCV's detectors on the same light-on frames (one 8x6 board searched per image; each
  // image holds six). Detection rate = images where a board was found.
  const cv::Size pattern(sim.virtualBoards().front().cols, sim.virtualBoards().front().rows);
  const int opencv_frames = std::min(frame_count, 10);
  for (int detector = 0; detector < 2; ++detector) {
    Stats time;
    int found = 0, images = 0;
    for (int k = 0; k < opencv_frames; ++k) {
      for (const cv::Mat* image : {&frames[k].left, &frames[k].right}) {
        std::vector<cv::Point2f> corners;
        const Clock::time_point t0 = Clock::now();
        const bool ok =
            detector == 0
                ? cv::findChessboardCorners(*image, pattern, corners,
                                            cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE)
                : cv::findChessboardCornersSB(*image, pattern, corners, cv::CALIB_CB_NORMALIZE_IMAGE);
        time.ms.push_back(msSince(t0));
        found += ok;
        ++images;
      }
    }
    const char* name = detector == 0 ? "cv::findChessboardCorners" : "cv::findChessboardCornersSB";
    std::printf("%-46s found a board in %d/%d light-on images\n", name, found, images);
    time.print((std::string(name) + ": ms per image").c_str());
  }
  return 0;
}
