// Calibration health monitor on drive_photo (config/drive_photo.yaml): its cost per frame at
// 752x480 and its detection delays.
//   bench_calibration_monitor [--cost-only | --no-drift-only] [--minutes M]
// Prints:
//   - cost: setCalibration, one depth-mode measurement (wall p50/p90 and process CPU over 3 x 60
//     pre-rendered light-off frames, images in memory), the same per 30 fps frame at the default
//     depth_frame_stride, and addVerification (tracker excluded);
//   - detection: a 0.05 deg knock of the right camera about x, y, z and a 1 % zoom, each at t = 3 s
//     into a 30 fps run (depth mode every frame, one verification every 2 s, corners from the
//     PatternTracker); thermal ramps of 0.01 deg/s about x, y, z: the turn at detection;
//   - with --minutes M (default 0: skipped): M minutes of the undrifted drive with its movers
//     (fixed seeds, motion by frame index), the number of frames not GOOD and the worst figures;
//     --no-drift-only runs that alone (default 1 minute) and exits 1 when a frame was not GOOD.
// Run from anywhere with ECS_SOURCE_DIR set to the package folder, or from the package folder.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/calibration_monitor.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"
#include "embedded_calibration_stereo/test_support/sim_prior.h"

using namespace embedded_calibration_stereo::core;
using Clock = std::chrono::steady_clock;

namespace {

std::string configDir() {
  const char* dir = std::getenv("ECS_SOURCE_DIR");
  return std::string(dir ? dir : ".") + "/config/";
}

double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }
double cpuMs() { return 1000.0 * static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

double percentile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(p * (v.size() - 1) + 0.5))];
}

bool leftGood(const HealthReport& r) {
  return r.state == CalibrationHealth::kDegraded || r.state == CalibrationHealth::kBad;
}

void costs() {
  SimRig sim(loadSimRigConfig(configDir() + "drive_photo.yaml"));
  CalibrationMonitorOptions options;
  const int stride = options.depth_frame_stride;
  options.depth_frame_stride = 1;  // time every measurement
  CalibrationMonitor monitor{options};
  auto t0 = Clock::now();
  monitor.setCalibration(sim.config().rig, 1, sim.virtualBoards(), true);
  std::printf("setCalibration: %.1f ms (once per calibration)\n", msSince(t0));
  std::vector<SimFrame> frames;
  for (int k = 0; k < 60; ++k) frames.push_back(sim.render(k / 30.0, 0.0, 10 + k));
  std::vector<double> wall;
  const double cpu0 = cpuMs();
  for (int pass = 0; pass < 3; ++pass)
    for (size_t k = 0; k < frames.size(); ++k) {
      t0 = Clock::now();
      monitor.addDepthFrame(pass * 2.0 + k / 30.0, frames[k].left, frames[k].right);
      wall.push_back(msSince(t0));
    }
  const double cpu = (cpuMs() - cpu0) / wall.size();
  std::printf("depth-mode measurement (752x480, %d matches): wall p50 %.2f ms, p90 %.2f ms; CPU %.2f ms "
              "(all threads)\n",
              monitor.report().matches, percentile(wall, 0.5), percentile(wall, 0.9), cpu);
  std::printf("per frame at 30 fps with depth_frame_stride %d (the default): CPU %.2f ms\n", stride, cpu / stride);
  PatternTracker tracker(teachSimPrior(sim, 0.0), TrackerOptions());
  const SimFrame on = sim.render(2.0, 1.0, 7);
  const StereoObservation obs = tracker.trackStereo(on.left, on.right, 2.0);
  wall.clear();
  for (int k = 0; k < 20; ++k) {
    t0 = Clock::now();
    monitor.addVerification(2.0 + k, obs);
    wall.push_back(msSince(t0));
  }
  std::printf("verification (%zu corners, tracker excluded): wall p50 %.2f ms\n", obs.cornerCount(),
              percentile(wall, 0.5));
}

// One 30 fps run with a verification every `period` s; `drift(t)` before each frame.
struct Run {
  SimRig sim;
  CalibrationMonitor monitor;
  PatternTracker tracker;
  double t = 0.0, period;
  int k = 0, lit = 0;
  explicit Run(double verification_period)
      : sim(loadSimRigConfig(configDir() + "drive_photo.yaml")),
        monitor(CalibrationMonitorOptions()),
        tracker(teachSimPrior(sim, 0.0), TrackerOptions()),
        period(verification_period) {
    monitor.setCalibration(sim.config().rig, 1, sim.virtualBoards(), true);
  }
  HealthReport step() {
    t = ++k / 30.0;
    const int every = static_cast<int>(std::lround(period * 30.0));
    if (k % every == 1) {
      const SimFrame on = sim.render(t, 1.0, 1000 + k);
      monitor.addVerification(t, tracker.trackStereo(on.left, on.right, t));
      ++lit;
    } else {
      const SimFrame off = sim.render(t, 0.0, 1000 + k);
      monitor.addDepthFrame(t, off.left, off.right);
    }
    return monitor.report();
  }
  double turnDeg() const {
    return rotationAngleDeg(sim.truthAt(t).right_from_left.linear(), sim.config().rig.right_from_left.linear());
  }
};

void detection(const char* what, const DriftRequest& drift) {
  Run run(2.0);
  while (run.t < 3.0 - 1e-9) run.step();
  run.sim.setDrift(drift, run.t);
  const double t0 = run.t;
  HealthReport r;
  while (run.t < t0 + 6.0 && !leftGood(r = run.step())) {
  }
  if (leftGood(r))
    std::printf("%-24s %s after %.2f s (%.0f frames); bias %.3f px, misalignment %.3f px, depth error at "
                "10 m %.2f %%\n",
                what, toString(r.state), run.t - t0, (run.t - t0) * 30.0, r.disparity_bias_px, r.misalignment_px,
                r.predicted_depth_error_pct[3]);
  else
    std::printf("%-24s not detected within 6 s\n", what);
}

void ramp(int axis) {
  Run run(2.0);
  while (run.t < 3.0 - 1e-9) run.step();
  const double t0 = run.t, rate = 0.01;
  if (axis == 1) {
    DriftRequest thermal;
    thermal.thermal_rate_deg_per_s = rate;
    run.sim.setDrift(thermal, t0);
  }
  HealthReport r;
  while (run.t < t0 + 10.0) {
    if (axis != 1) {
      DriftRequest turn;
      turn.right_rotation_deg[axis] = rate * (run.t + 1.0 / 30.0 - t0);
      run.sim.setDrift(turn, run.t + 1.0 / 30.0);
    }
    if (leftGood(r = run.step())) break;
  }
  std::printf("thermal 0.01 deg/s about %c: %s after %.2f s, at %.4f deg\n", "xyz"[axis], toString(r.state),
              run.t - t0, run.turnDeg());
}

// Returns the frames not GOOD.
int soak(double minutes) {
  Run run(2.0);
  const int frames = static_cast<int>(minutes * 60.0 * 30.0);
  int not_good = 0;
  double worst_m = 0, worst_b = 0, worst_r = 0;
  for (int i = 0; i < frames; ++i) {
    const HealthReport r = run.step();
    not_good += r.state != CalibrationHealth::kGood;
    worst_m = std::max(worst_m, r.misalignment_px);
    worst_b = std::max(worst_b, r.disparity_bias_px);
    worst_r = std::max(worst_r, r.board_residual_px);
  }
  std::printf("no drift, %.1f min (%d frames, %d lit = %.2f %%): %d frames not GOOD; worst misalignment %.3f px, "
              "bias %.3f px, board residual %.3f px\n",
              minutes, frames, run.lit, 100.0 * run.lit / frames, not_good, worst_m, worst_b, worst_r);
  return not_good;
}

}  // namespace

int main(int argc, char** argv) {
  bool cost_only = false, no_drift_only = false;
  double minutes = 0.0;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--cost-only")) {
      cost_only = true;
    } else if (!std::strcmp(argv[i], "--no-drift-only")) {
      no_drift_only = true;
    } else if (!std::strcmp(argv[i], "--minutes") && i + 1 < argc) {
      minutes = std::atof(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: bench_calibration_monitor [--cost-only | --no-drift-only] [--minutes M]\n");
      return 2;
    }
  }
  // The no-drift run alone (CI's minute): exit status 1 when a frame was not GOOD.
  if (no_drift_only) return soak(minutes > 0 ? minutes : 1.0) > 0 ? 1 : 0;
  costs();
  if (cost_only) return 0;
  std::printf("verification every 2 s (one lit frame in 60: 1.67 %% of frames)\n");
  DriftRequest knock;
  knock.knock_rotation_deg = Eigen::Vector3d(0.05, 0, 0);
  detection("knock 0.05 deg about x:", knock);
  knock.knock_rotation_deg = Eigen::Vector3d(0, 0, 0.05);
  detection("knock 0.05 deg about z:", knock);
  knock.knock_rotation_deg = Eigen::Vector3d(0, 0.05, 0);
  detection("knock 0.05 deg about y:", knock);
  DriftRequest zoom;
  zoom.focal_scale = 1.01;
  detection("zoom 1 %:", zoom);
  for (int axis = 0; axis < 3; ++axis) ramp(axis);
  if (minutes > 0) soak(minutes);
  return 0;
}
