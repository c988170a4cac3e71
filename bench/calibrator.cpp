// Bundle adjuster bench: solve time and accuracy against the truth for 1, 10 and 30 frames of
// simulated corner observations (a rig like the sim's, six virtual 8x6 boards at 1.2 m, 0.2 px
// corner noise), for every board-pose mode and both initialisations.
//
// Usage: bench_calibrator [--trials N=10] [--threads N=1] [--noise PX=0.2] [--tangential 0|1]
//                        [--rig sim_rig.yaml] [--frames 1,10,30] [--per-frame 0|1]
//                        [--zero-tangential 0|1] [--prior-deg D=50] [--prior-m M=0.1]
//                        [--device-error-mm MM=1] [--device-error-deg D=0.5]
//   --rig: take the truth rig and the device (virtual boards) from a sim_rig.yaml instead of the
//          built-in layout (makeSimLikeStereoRig + makeSpreadVirtualBoards, 25 mm squares).
//          Only then is the device model run: its nominal device is the true one moved by
//          manufacturing tolerances (perturbDevice: 1 mm, 0.5 deg, new seed per trial).
//   --zero-tangential 1: set the truth's p1 p2 to zero (the sim's has them; the default model
//          k1 k2 would be biased). --prior-*: the device model's prior tolerances.
//   --device-error-*: how far the nominal device is from the truth.
//   cover: fraction of the 14 errors fx fy cx cy k1 k2 (both cameras), baseline and rotation
//          within 3 reported standard deviations, over all trials.
// Budget (DESIGN.md): calibration solve, 10 frames <= 200 ms on 2 cores.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <optional>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/test_support/solution_errors.h"
#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

namespace {

using namespace embedded_calibration_stereo::core;

struct Accumulated {
  std::vector<double> ms, cpu_ms;
  double ceres_ms = 0, covariance_ms = 0, iterations = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0, k1 = 0, baseline = 0, rotation = 0;  // worst case
  double fx_sum = 0, baseline_sum = 0, rotation_sum = 0;                      // for means
  double fx_sd = 0, baseline_sd = 0, rotation_sd = 0;  // mean reported stddevs
  double c_sum = 0, c_sd = 0, k1_sum = 0, k1_sd = 0;   // means over both cameras
  int failures = 0, not_converged = 0, runs = 0, covered = 0, compared = 0;
};

struct Setup {
  StereoRig truth;
  std::vector<VirtualBoard> boards;
  std::optional<CalibrationDevice> device;  // the truth; only with --rig
  int trials = 10, threads = 1;
  double noise = 0.2;
  bool tangential = false;
  double prior_deg = BundleAdjustmentOptions{}.device_prior_angle_deg;
  double prior_m = BundleAdjustmentOptions{}.device_prior_position_m;
  double device_error_m = 0.001, device_error_deg = 0.5;
};

// Adds one successful solve's errors against the truth and its reported deviations.
void accumulate(const BundleAdjustmentSummary& s, const StereoRig& truth, Accumulated* acc) {
  Accumulated& a = *acc;
  const RigErrors e = compareRigs(s.rig, truth);
  a.fx = std::max({a.fx, e.fx_rel[0], e.fx_rel[1]});
  a.fy = std::max({a.fy, e.fy_rel[0], e.fy_rel[1]});
  a.cx = std::max({a.cx, e.cx_px[0], e.cx_px[1]});
  a.cy = std::max({a.cy, e.cy_px[0], e.cy_px[1]});
  a.k1 = std::max({a.k1, e.k1[0], e.k1[1]});
  a.baseline = std::max(a.baseline, e.baseline_rel);
  a.rotation = std::max(a.rotation, e.rotation_deg);
  a.fx_sum += 0.5 * (e.fx_rel[0] + e.fx_rel[1]);
  a.baseline_sum += e.baseline_rel;
  a.rotation_sum += e.rotation_deg;
  a.fx_sd += 0.5 * (s.left_stddev.fx / s.rig.left.fx + s.right_stddev.fx / s.rig.right.fx);
  a.baseline_sd += s.baseline_stddev_m / s.rig.baseline();
  a.rotation_sd += s.rotation_stddev_deg;
  a.c_sum += 0.25 * (e.cx_px[0] + e.cx_px[1] + e.cy_px[0] + e.cy_px[1]);
  a.c_sd += 0.25 * (s.left_stddev.cx + s.right_stddev.cx + s.left_stddev.cy + s.right_stddev.cy);
  a.k1_sum += 0.5 * (e.k1[0] + e.k1[1]);
  a.k1_sd += 0.5 * (s.left_stddev.dist[0] + s.right_stddev.dist[0]);
  if (s.covariance_ok)
    for (double z : errorsInReportedStddevs(s, truth)) {
      ++a.compared;
      if (z <= 3.0) ++a.covered;
    }
}

void run(const char* label, BoardPoseMode mode, bool from_in_force, int frames,
         const Setup& setup) {
  const StereoRig& truth = setup.truth;
  const std::vector<VirtualBoard>& boards = setup.boards;
  const int trials = setup.trials;
  BundleAdjustmentOptions options;
  options.board_pose_mode = mode;
  options.initialization =
      from_in_force ? InitializationMode::kFromInForce : InitializationMode::kZhang;
  options.num_threads = setup.threads;
  options.device_prior_angle_deg = setup.prior_deg;
  options.device_prior_position_m = setup.prior_m;
  BundleAdjustmentConfig config;
  config.estimate_tangential = setup.tangential;
  const BundleAdjuster adjuster(options, config);
  Accumulated a;
  for (int t = 0; t < trials; ++t) {
    SyntheticObservationOptions so;
    so.frames = frames;
    so.noise_sigma_px = setup.noise;
    so.seed = 1000 + t;
    const std::vector<StereoObservation> obs = generateSyntheticObservations(truth, boards, so);
    CalibrationInput input;
    input.frames = &obs;
    input.boards = &boards;
    input.image_width = truth.left.width;
    input.image_height = truth.left.height;
    // The calibration in force after a 5 % zoom and a 0.3 deg right-camera rotation.
    if (from_in_force) input.in_force = driftedRig(truth, 1.05, Eigen::Vector3d(0.0, 0.3, 0.0));
    std::optional<CalibrationDevice> nominal;
    if (mode == BoardPoseMode::kDeviceModel) {
      nominal =
          perturbDevice(*setup.device, setup.device_error_m, setup.device_error_deg, 5000 + t);
      input.device = &*nominal;
    }
    const std::clock_t cpu_start = std::clock();
    const BundleAdjustmentSummary s = adjuster.Solve(input);
    a.cpu_ms.push_back(1000.0 * (std::clock() - cpu_start) / CLOCKS_PER_SEC);
    ++a.runs;
    if (!s.success) {
      ++a.failures;
      continue;
    }
    if (!s.converged) ++a.not_converged;
    a.ms.push_back(s.solve_ms);
    a.ceres_ms += s.ceres_ms;
    a.covariance_ms += s.covariance_ms;
    a.iterations += s.iterations;
    accumulate(s, truth, &a);
  }
  const int ok = static_cast<int>(a.ms.size());
  if (ok == 0) {
    std::printf("%-34s %3d frames: all %d solves failed\n", label, frames, a.runs);
    return;
  }
  std::sort(a.ms.begin(), a.ms.end());
  std::sort(a.cpu_ms.begin(), a.cpu_ms.end());
  std::printf(
      "%-34s %3d fr | ms med %6.1f max %6.1f cpu-ms med %6.1f (ceres %.1f cov %.1f, %.1f it) | "
      "worst: fx %.4f%% fy %.4f%% cx %.3f cy %.3f px "
      "k1 %.5f base %.4f%% rot %.4f deg | mean: fx %.4f%% (sd %.4f%%) base %.4f%% (sd %.4f%%) "
      "rot %.4f (sd %.4f) deg c %.3f (sd %.3f) px k1 %.5f (sd %.5f) | cover %.3f | fail %d "
      "nonconv %d\n",
      label, frames, a.ms[a.ms.size() / 2], a.ms.back(), a.cpu_ms[a.cpu_ms.size() / 2],
      a.ceres_ms / ok, a.covariance_ms / ok, a.iterations / ok, 100 * a.fx, 100 * a.fy, a.cx, a.cy,
      a.k1, 100 * a.baseline, a.rotation, 100 * a.fx_sum / ok, 100 * a.fx_sd / ok,
      100 * a.baseline_sum / ok, 100 * a.baseline_sd / ok, a.rotation_sum / ok, a.rotation_sd / ok,
      a.c_sum / ok, a.c_sd / ok, a.k1_sum / ok, a.k1_sd / ok,
      a.compared ? static_cast<double>(a.covered) / a.compared : 0.0, a.failures, a.not_converged);
}

// The command line's options.
struct Options {
  Setup setup;
  std::string rig_path;
  std::vector<int> frame_counts{1, 10, 30};
  bool per_frame = true, zero_tangential = false;
};

// "1,10,30" as numbers (the positive ones).
std::vector<int> frameCounts(const char* text) {
  std::vector<int> counts;
  for (const char* p = text; *p;) {
    char* end = nullptr;
    const long n = std::strtol(p, &end, 10);
    if (end == p) break;
    if (n > 0) counts.push_back(static_cast<int>(n));
    p = *end == ',' ? end + 1 : end;
  }
  return counts;
}

// Sets the option `key` to `value`; false for an unknown key.
bool setOption(const std::string& key, const char* value, Options* o) {
  Setup& setup = o->setup;
  if (key == "--trials")
    setup.trials = std::max(1, std::atoi(value));
  else if (key == "--threads")
    setup.threads = std::max(1, std::atoi(value));
  else if (key == "--noise")
    setup.noise = std::atof(value);
  else if (key == "--tangential")
    setup.tangential = std::atoi(value) != 0;
  else if (key == "--rig")
    o->rig_path = value;
  else if (key == "--zero-tangential")
    o->zero_tangential = std::atoi(value) != 0;
  else if (key == "--prior-deg")
    setup.prior_deg = std::atof(value);
  else if (key == "--prior-m")
    setup.prior_m = std::atof(value);
  else if (key == "--device-error-mm")
    setup.device_error_m = 1e-3 * std::atof(value);
  else if (key == "--device-error-deg")
    setup.device_error_deg = std::atof(value);
  else if (key == "--per-frame")
    o->per_frame = std::atoi(value) != 0;
  else if (key == "--frames")
    o->frame_counts = frameCounts(value);
  else
    return false;
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  Options options;
  for (int i = 1; i + 1 < argc; i += 2)
    if (!setOption(argv[i], argv[i + 1], &options)) {
      std::fprintf(stderr, "unknown option %s\n", argv[i]);
      return 2;
    }
  Setup& setup = options.setup;
  const std::string& rig_path = options.rig_path;
  const bool zero_tangential = options.zero_tangential;
  if (rig_path.empty()) {
    setup.truth = makeSimLikeStereoRig();
    setup.boards = makeSpreadVirtualBoards(setup.truth.left, {});
  } else {
    try {
      cv::FileStorage fs = openYaml(rig_path);
      setup.truth = loadStereoRig(fs["rig"], "rig");
      setup.device = loadDevice(fs["device"], "device");
      setup.boards = setup.device->virtualBoards();
    } catch (const std::exception& e) {
      std::fprintf(stderr, "cannot load %s: %s\n", rig_path.c_str(), e.what());
      return 1;
    }
  }
  if (zero_tangential)
    for (PinholeCamera* c : {&setup.truth.left, &setup.truth.right}) c->dist[2] = c->dist[3] = 0.0;
  std::printf(
      "bench_calibrator: %s, %zu virtual boards, %d trials, %d solver thread(s), corner "
      "noise %.2f px, p1 p2 %s%s; nominal device off by %.2f mm %.2f deg, device prior %.1f deg "
      "%.0f mm; errors vs truth (worst over trials, both cameras); solve ms = "
      "wall time of Solve() incl. validation, initialisation and covariance, cpu-ms its "
      "process CPU time\n",
      rig_path.empty() ? "built-in layout" : rig_path.c_str(), setup.boards.size(), setup.trials,
      setup.threads, setup.noise, setup.tangential ? "estimated" : "held",
      zero_tangential ? " (zero in the truth)" : "", 1e3 * setup.device_error_m,
      setup.device_error_deg, setup.prior_deg, 1e3 * setup.prior_m);
  for (int frames : options.frame_counts) {
    if (setup.device) {
      run("device model, init in-force(5%,0.3d)", BoardPoseMode::kDeviceModel, true, frames, setup);
      run("device model, init Zhang", BoardPoseMode::kDeviceModel, false, frames, setup);
    }
    run("shared poses, init in-force(5%,0.3d)", BoardPoseMode::kSharedAcrossFrames, true, frames,
        setup);
    run("shared poses, init Zhang", BoardPoseMode::kSharedAcrossFrames, false, frames, setup);
    if (!options.per_frame) continue;
    run("per-frame poses, init in-force", BoardPoseMode::kPerFrame, true, frames, setup);
    run("per-frame poses, init Zhang", BoardPoseMode::kPerFrame, false, frames, setup);
  }
  return 0;
}
