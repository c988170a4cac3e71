// Calibration while the world moves, core only (no ROS), deterministic: the simulated head of a
// scenario (default config/drive_photo.yaml: driving through a photographed corridor, movers)
// runs for a given time; every `period` seconds a light window of `frames` light-on frames is
// tracked by the pattern tracker (no background: the world moves) and solved by the bundle
// adjuster, the quality gate decides against the calibration in force (as the OnlineCalibrator
// does), and an accepted calibration is committed. A drift script changes the rig: a 5 % zoom
// step, a thermal rotation of the right camera (ramp, then held), a knock, then the same again
// around the first state, cycling. Every window prints its gate decision and, for every commit,
// the new and the replaced calibration's accuracy for depth against the truth of the window's
// last frame (core/calibration/stereo_accuracy.h), and whether the commit is worse.
//   bench_calibrate_moving [--config FILE] [--minutes M] [--period S] [--frames N] [--fps F]
//                          [--teach-frames K] [--min-change X] [--min-improvement R]
//                          [--align 0|1] [--free-poses 0|1]
//                          [--truth-background 0|1] [--truth-noise SIGMA] [--saddle 0|1]
//                          [--learn-window 0|1|2] [--off-frames K] [--scene 0|1] [--filter 0|1]
//                          [--refine R] [--scene-test P] [--event-at-burst 0|1] [--scene-sides 0|1]
//                          [--learn-iterations N] [--flow-iterations I] [--flow-pair-step K]
// --min-change / --min-improvement: the gate's min_change_in_predicted / min_rms_improvement_rel;
// what limits the accuracy (docs/figures.md): --align 0 reports cornerSubPix corners instead of the whole-board
// alignment's, --free-poses 1 solves with one free pose per virtual board instead of the rigid
// device model, --truth-background 1 gives the tracker the simulator's scene of each frame as its
// background (a still-world reference), --truth-noise S replaces tracking by the true corners
// plus S px of Gaussian noise, --saddle 1 refines the tracked corners by the saddle-model fit
// (on the difference with --truth-background 1). --learn-window 2 tracks each window as a whole
// (window_tracker.h: the device image learned from the window's light-off frames, K on each side,
// and its light-on frames; one observation per window), 1 the same with light-off frames before
// the window only; --light-off-gap G: the nearest light-off frames lie G frame periods from the
// window's first and last light-on frames (default 1; the live driver: settle_frames + 1).
// --event-at-burst 1 (with --learn-window) fires each drift event between the light-off frames
// before a window and its first light-on frame, as a knock can come on a real head (and as the
// demo's script can fire one just before a burst): the window's light-off frames before it and
// their scene matches show the rig of before the event. --scene-sides 0 keeps a window's scene
// matches when its two sides disagree (WindowTrackerOptions::check_scene_sides).
// --learn-iterations, --flow-iterations and --flow-pair-step set the window learner's alignment
// passes, the flow's variational refinement iterations and its pair step
// (DeviceLearnerOptions::iterations, flow_refinement_iterations, flow_pair_step; default: the
// product's, windowLearnerOptions()). Each
// window also prints the tracked corners' RMS error against the truth and the part of it common
// to the window's frames.
// The scene moves with the frame index (time = frame / fps), the noise seeds are the frame
// index: two runs print the same figures. The prior is taught at t = 0 from light-on frames
// minus the simulator's scene of the same frame (a bench of the calibration, not of teaching).
// The summary also gives the calibration in force after each window's decision against the truth:
// its median misalignment and how many windows left it out of a target.
// Exit code: 0, or 1 when a commit was worse than the calibration it replaced.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iterator>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/calibration/calibration_filter.h"
#include "embedded_calibration_stereo/core/calibration/quality_gate.h"
#include "embedded_calibration_stereo/core/calibration/scene_comparison.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/tracker/board_teacher.h"
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"
#include "embedded_calibration_stereo/core/tracker/saddle_refinement.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"
#include "embedded_calibration_stereo/test_support/corner_score.h"
#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

using namespace embedded_calibration_stereo::core;

namespace {

// A commit is worse when its combined error, hypot(misalignment RMS, bias RMS), is larger than
// the replaced one's by more than this (px), as in drive_photo_live.test.
constexpr double kWorsePx = 0.01;
double combined(const StereoAccuracy& a) { return std::hypot(a.misalignment_px.rms, a.disparity_bias_px.rms); }

struct Args {
  std::string config;
  double minutes = 10.0, period_s = 10.0, fps = 10.0;
  int frames = 10, teach_frames = 5;
  int align = 1;    // whole-board alignment of the tracker (TrackerOptions::whole_board_alignment)
  double min_improvement = GateOptions().min_rms_improvement_rel;
  double min_change = 0.0;  // GateOptions::min_change_in_predicted
  int free_poses = 0;       // 1: one free pose per virtual board instead of the rigid device model
  int truth_background = 0;  // 1: the simulator's scene of each frame as its background (a still-world reference)
  // 1: learn the device image from the window's light pairs (light-off frames before it) and
  // track it (WindowTracker); 2: light-off frames before and after it
  int learn_window = 0;
  int off_frames = 1;        // light-off frames on each side of the window for --learn-window
  int saddle = 0;            // 1: refine the tracked corners by the saddle-model fit
  int light_off_gap = 1;     // --learn-window: frame periods from the light-off frames to the window's ends
  double truth_noise = -1;  // >= 0: the simulator's true corners plus this Gaussian noise instead of tracking
  int scene = 0;  // 1: the window observation carries its light-off frames' scene correspondences
  int filter = 0;  // 1: earlier windows' solves as the prior of the groups a window does not contradict
  double refine = 0.0;  // GateOptions::refine_ratio
  double scene_test = 0.0;  // GateOptions::scene_test_probability
  int scene_sides = 1;     // WindowTrackerOptions::check_scene_sides
  int event_at_burst = 0;  // 1: drift events between a window's light-off frames before it and its light-on frames
  // The window learner's options (-1: the product's, windowLearnerOptions()).
  int learn_iterations = -1, flow_iterations = -1, flow_pair_step = -1;
};

// Distances of scene correspondences to their true epipolar lines (the Sampson distance under
// the true calibration, px), sorted.
std::vector<double> epipolarDistances(const std::vector<SceneMatch>& matches, const StereoRig& truth) {
  std::vector<double> distances = sceneEpipolarDistances(matches, truth, truth.right.fy);
  std::sort(distances.begin(), distances.end());
  return distances;
}

// The drift script: one event per `every` windows, cycling.
struct DriftScript {
  int step = 0;
  double thermal_rate = 0.0, held_deg = 0.0, thermal_start = 0.0;
  bool zoomed = false;
  Eigen::Vector3d knock_rot = Eigen::Vector3d::Zero(), knock_trans = Eigen::Vector3d::Zero();

  // Applies the next event at time t; returns its name.
  std::string next(SimRig* sim, double t) {
    DriftRequest r;
    std::string what;
    switch (step % 5) {
      case 0:
        zoomed = !zoomed;
        what = zoomed ? "5 % zoom in" : "5 % zoom out";
        break;
      case 1:
        thermal_rate = (step / 5) % 2 == 0 ? 0.01 : -0.01;
        thermal_start = t;
        what = "thermal rotation starts";
        break;
      case 2:
        held_deg += thermal_rate * (t - thermal_start);
        thermal_rate = 0.0;
        what = "thermal rotation stops";
        break;
      case 3: {
        const double s = (step / 5) % 2 == 0 ? 1.0 : -1.0;
        knock_rot = Eigen::Vector3d(0.04, -0.03, 0.05) * s;
        knock_trans = Eigen::Vector3d(0.0008, 0.0003, -0.0005) * s;
        what = "knock";
        break;
      }
      default:
        what = "nothing";
    }
    r.focal_scale = zoomed ? 1.05 : 1.0;
    r.thermal_rate_deg_per_s = thermal_rate;
    // Held rotation (y, as the thermal rotation) of the ramps so far.
    r.right_rotation_deg = Eigen::Vector3d(0.0, held_deg, 0.0);
    if (step % 5 == 3) {
      r.knock_rotation_deg = knock_rot;
      r.knock_translation_m = knock_trans;
    }
    ++step;
    const std::string refusal = sim->setDrift(r, t);
    if (!refusal.empty()) std::fprintf(stderr, "drift refused: %s\n", refusal.c_str());
    return what;
  }
};

// Refines every corner by the saddle fit on the image, or on image minus background.
void refineBySaddle(const cv::Mat& image, const CameraPrior& prior, std::vector<BoardCorners>* boards,
                    const cv::Mat& background = cv::Mat()) {
  cv::Mat diff;
  image.convertTo(diff, CV_32F);
  if (!background.empty()) {
    cv::Mat b;
    background.convertTo(b, CV_32F);
    diff -= b;
  }
  refineCornersBySaddleFit(diff, prior, WindowTrackerOptions(), boards);
}

void print(const char* what, const StereoAccuracy& a) {
  std::printf("    %s misalignment %.4f px, bias %.4f px, depth error %.3f / %.3f / %.3f / %.3f %% at 1/2/5/10 m\n",
              what, a.misalignment_px.rms, a.disparity_bias_px.rms, a.at_depth[0].depth_error_pct.rms,
              a.at_depth[1].depth_error_pct.rms, a.at_depth[2].depth_error_pct.rms, a.at_depth[3].depth_error_pct.rms);
}

PatternPrior teach(const SimRig& sim, double fps, int frames) {
  std::vector<TeachFrame> left, right;
  for (int k = 0; k < frames; ++k) {
    const SimFrame f = sim.render(k / fps, 1.0, 900000 + k);
    left.push_back({f.left, f.left_scene});
    right.push_back({f.right, f.right_scene});
  }
  const StereoRig& rig = sim.config().rig;
  PatternPrior prior;
  prior.cameras.push_back(
      teachCamera(left, BoardLayout::device(sim.virtualBoards(), rig.left, Eigen::Isometry3d::Identity()), "left").prior);
  prior.cameras.push_back(
      teachCamera(right, BoardLayout::device(sim.virtualBoards(), rig.right, rig.right_from_left), "right").prior);
  return prior;
}

// The command line; nothing (and *status the exit code) when it is not usable.
std::optional<Args> parseArgs(int argc, char** argv, int* status) {
  Args args;
  if (const char* dir = std::getenv("ECS_SOURCE_DIR")) args.config = std::string(dir) + "/config/drive_photo.yaml";
  *status = 2;
  using Set = void (*)(Args*, const char*);
  static const std::pair<const char*, Set> kOptions[] = {
      {"--config", [](Args* a, const char* v) { a->config = v; }},
      {"--minutes", [](Args* a, const char* v) { a->minutes = std::atof(v); }},
      {"--period", [](Args* a, const char* v) { a->period_s = std::atof(v); }},
      {"--frames", [](Args* a, const char* v) { a->frames = std::atoi(v); }},
      {"--fps", [](Args* a, const char* v) { a->fps = std::atof(v); }},
      {"--teach-frames", [](Args* a, const char* v) { a->teach_frames = std::atoi(v); }},
      {"--align", [](Args* a, const char* v) { a->align = std::atoi(v); }},
      {"--truth-noise", [](Args* a, const char* v) { a->truth_noise = std::atof(v); }},
      {"--min-improvement", [](Args* a, const char* v) { a->min_improvement = std::atof(v); }},
      {"--min-change", [](Args* a, const char* v) { a->min_change = std::atof(v); }},
      {"--free-poses", [](Args* a, const char* v) { a->free_poses = std::atoi(v); }},
      {"--truth-background", [](Args* a, const char* v) { a->truth_background = std::atoi(v); }},
      {"--learn-window", [](Args* a, const char* v) { a->learn_window = std::atoi(v); }},
      {"--off-frames", [](Args* a, const char* v) { a->off_frames = std::max(1, std::atoi(v)); }},
      {"--saddle", [](Args* a, const char* v) { a->saddle = std::atoi(v); }},
      {"--light-off-gap", [](Args* a, const char* v) { a->light_off_gap = std::atoi(v); }},
      {"--scene", [](Args* a, const char* v) { a->scene = std::atoi(v); }},
      {"--filter", [](Args* a, const char* v) { a->filter = std::atoi(v); }},
      {"--refine", [](Args* a, const char* v) { a->refine = std::atof(v); }},
      {"--scene-test", [](Args* a, const char* v) { a->scene_test = std::atof(v); }},
      {"--event-at-burst", [](Args* a, const char* v) { a->event_at_burst = std::atoi(v); }},
      {"--scene-sides", [](Args* a, const char* v) { a->scene_sides = std::atoi(v); }},
      {"--learn-iterations", [](Args* a, const char* v) { a->learn_iterations = std::atoi(v); }},
      {"--flow-iterations", [](Args* a, const char* v) { a->flow_iterations = std::atoi(v); }},
      {"--flow-pair-step", [](Args* a, const char* v) { a->flow_pair_step = std::atoi(v); }},
  };
  for (int i = 1; i < argc; ++i) {
    const auto option = std::find_if(std::begin(kOptions), std::end(kOptions),
                                     [&](const auto& o) { return !std::strcmp(argv[i], o.first); });
    if (option == std::end(kOptions)) {
      std::fprintf(stderr, "usage: bench_calibrate_moving [--config FILE] [--minutes M] [--period S] [--frames N] "
                           "[--fps F] [--teach-frames K]   (default config: $ECS_SOURCE_DIR/config/drive_photo.yaml)\n");
      return std::nullopt;
    }
    if (i + 1 >= argc) {
      std::fprintf(stderr, "%s needs a value\n", argv[i]);
      return std::nullopt;
    }
    option->second(&args, argv[++i]);
  }
  if (args.light_off_gap < 1) {
    std::fprintf(stderr, "bench_calibrate_moving: --light-off-gap must be >= 1\n");
    return std::nullopt;
  }
  if (args.config.empty() || args.frames < 1 || !(args.period_s > args.frames / args.fps)) {
    std::fprintf(stderr, "bench_calibrate_moving: need --config (or ECS_SOURCE_DIR), frames >= 1 and a period longer "
                         "than a window\n");
    return std::nullopt;
  }
  *status = 0;
  return args;
}

// A window's observations, with their tracked and true corner counts and errors.
struct WindowObservations {
  std::vector<StereoObservation> frames;
  SimFrame last;  // the window's last light-on frame (its truth scores the calibrations)
  int corners = 0, truth_corners = 0;
  WindowCornerErrors errors;

  // `obs` tracked on a frame whose true corners are `truth`'s.
  void add(StereoObservation obs, const SimFrame& truth) {
    for (const auto& b : obs.left) corners += b.size();
    for (const auto& b : obs.right) corners += b.size();
    for (const auto& b : truth.observations.left) truth_corners += b.size();
    for (const auto& b : truth.observations.right) truth_corners += b.size();
    errors.add(0, obs.left, truth.observations.left);
    errors.add(1, obs.right, truth.observations.right);
    frames.push_back(std::move(obs));
  }
};

TrackerOptions trackerOptions(const Args& args) {
  TrackerOptions o;
  o.whole_board_alignment = args.align != 0;
  return o;
}

WindowTrackerOptions windowTrackerOptions(const Args& args) {
  WindowTrackerOptions o;
  if (args.learn_iterations >= 0) o.learner.iterations = args.learn_iterations;
  if (args.flow_iterations >= 0) o.learner.flow_refinement_iterations = args.flow_iterations;
  if (args.flow_pair_step >= 0) o.learner.flow_pair_step = args.flow_pair_step;
  o.scene_matches = args.scene != 0;
  o.check_scene_sides = args.scene_sides != 0;
  return o;
}

BundleAdjuster adjusterFor(const Args& args) {
  BundleAdjustmentConfig terms;
  terms.estimate_tangential = true;  // the scenario's lenses have p1, p2
  BundleAdjustmentOptions adjustment;
  if (args.free_poses) adjustment.board_pose_mode = BoardPoseMode::kSharedAcrossFrames;
  return BundleAdjuster(adjustment, terms);
}

GateOptions gateOptions(const Args& args) {
  GateOptions o;
  o.min_rms_improvement_rel = args.min_improvement;
  o.min_change_in_predicted = args.min_change;
  o.refine_ratio = args.refine;
  o.scene_test_probability = args.scene_test;
  return o;
}

// The windows of a run, in time order: each one observed (tracked frame by frame, or as a whole),
// solved, judged by the gate against the calibration in force, and committed when accepted.
class MovingCalibration {
 public:
  MovingCalibration(const Args& args, const SimRigConfig& config, SimRig* sim, const PatternPrior& prior)
      : args_(args),
        config_(config),
        sim_(sim),
        prior_(prior),
        tracker_(prior, trackerOptions(args)),
        // The scene matching is guided by the nominal calibration, as the tracker nodelet's.
        window_tracker_(prior, trackerOptions(args), windowTrackerOptions(args), config.rig),
        adjuster_(adjusterFor(args)),
        gate_(gateOptions(args)),
        boards_(config.device.virtualBoards()),
        in_force_(config.rig) {}  // the head starts calibrated

  // Window w (from 1), starting at w periods.
  void window(int w) {
    const double t_start = w * args_.period_s;
    // One drift event every other window, half a period before the window (the light is off).
    std::string event;
    const bool event_due = w % 2 == 0;
    const bool at_burst = event_due && args_.event_at_burst && args_.learn_window;
    if (event_due && !at_burst) event = drift_.next(sim_, t_start - 0.5 * args_.period_s);
    WindowObservations observed;
    if (args_.learn_window)
      observeWholeWindow(t_start, &observed, at_burst ? &event : nullptr);
    else
      observeFrames(t_start, &observed);
    ++windows_;
    std::string prior_note;
    const BundleAdjustmentSummary candidate = solve(observed.frames, t_start, &prior_note);
    const GateDecision decision = judge(candidate, observed.frames);
    const StereoAccuracy old_a = evaluateStereoAccuracy(in_force_, observed.last.truth);
    std::printf("t %6.1f s%s%s: %d of %d corners tracked (%.3f px RMS, %.3f px common to the window); %s\n", t_start,
                event.empty() ? "" : ", after ", event.c_str(), observed.corners, observed.truth_corners,
                observed.errors.rms(), observed.errors.sharedRms(), decision.reason.c_str());
    if (!prior_note.empty()) std::printf("    filter: %s\n", prior_note.c_str());
    if (const SceneComparison& s = candidate.scene_vs_in_force; s.matches > 0)
      std::printf("    scene against the calibration in force: %d matches at %.4f px (in force %.4f px), test %.1f\n",
                  s.matches, s.candidate_rms_px, s.in_force_rms_px, s.statistic);
    if (args_.filter && candidate.success && candidate.covariance_ok && (decision.accepted || decision.in_force_confirmed))
      filter_.setState(candidate.rig, candidate.rig_covariance, t_start);
    if (!decision.accepted) {
      ++rejected_;
      print("in force:", old_a);
      afterDecision(old_a);
      return;
    }
    commit(candidate, observed.last.truth, old_a);
  }

  // The calibration in force after a window's decision, against the truth of its last frame.
  void afterDecision(const StereoAccuracy& a) {
    misalignment_after_.push_back(a.misalignment_px.rms);
    out_of_target_ += a.misalignment_px.rms > 0.05 || a.at_depth[3].depth_error_pct.rms > 0.7;
  }

  // Prints the summary line; the exit code (1 when a commit was worse).
  int summary(double wall_minutes) const {
    std::printf("%d windows, %d commits, %d rejected, %d commits worse than the calibration they replaced; worst "
                "committed misalignment %.4f px, bias %.4f px (%.1f min wall)\n",
                windows_, commits_, rejected_, worse_, worst_after_mis_, worst_after_bias_, wall_minutes);
    if (!misalignment_after_.empty()) {
      std::vector<double> sorted = misalignment_after_;
      std::sort(sorted.begin(), sorted.end());
      std::printf("after each window's decision, the calibration in force against the truth: misalignment median "
                  "%.4f px, max %.4f px; out of a target (misalignment 0.05 px, depth error at 10 m 0.7 %%) after %d "
                  "of %zu windows\n",
                  sorted[sorted.size() / 2], sorted.back(), out_of_target_, sorted.size());
    }
    return worse_ > 0 ? 1 : 0;
  }

 private:
  uint64_t frameIndex(double t) const { return static_cast<uint64_t>(std::llround(t * args_.fps)); }

  // Every light-on frame tracked on its own.
  void observeFrames(double t_start, WindowObservations* out) {
    for (int k = 0; k < args_.frames; ++k) {
      const double t = t_start + k / args_.fps;
      out->last = sim_->render(t, 1.0, frameIndex(t));
      out->add(trackFrame(out->last, t), out->last);
    }
  }

  StereoObservation trackFrame(const SimFrame& frame, double t) {
    if (args_.truth_background) tracker_.setBackground(frame.left_scene, frame.right_scene);
    StereoObservation obs = tracker_.trackStereo(frame.left, frame.right, t);
    if (args_.saddle) {
      refineBySaddle(frame.left, prior_.cameras[0], &obs.left, args_.truth_background ? frame.left_scene : cv::Mat());
      refineBySaddle(frame.right, prior_.cameras[1], &obs.right,
                     args_.truth_background ? frame.right_scene : cv::Mat());
    }
    if (args_.truth_noise < 0) return obs;
    obs = frame.observations;
    cv::RNG rng(frameIndex(t));
    for (auto* side : {&obs.left, &obs.right})
      for (BoardCorners& b : *side)
        for (size_t i = 0; i < b.size(); ++i) {
          b.u[i] += static_cast<float>(rng.gaussian(args_.truth_noise));
          b.v[i] += static_cast<float>(rng.gaussian(args_.truth_noise));
        }
    return obs;
  }

  // The window tracked as a whole, with its light-off frames (before it; with --learn-window 2
  // after it too), rendered in time order where it matters: the simulated auto-exposure carries
  // state from frame to frame.
  // *event (not null): the next drift event fires after the light-off frames before the window,
  // just before its first light-on frame; its name goes there.
  void observeWholeWindow(double t_start, WindowObservations* out, std::string* event = nullptr) {
    WindowFrames window[2];
    if (event) {
      renderLightOff(t_start, true, window);
      *event = drift_.next(sim_, t_start - 0.5 / args_.fps) + " (just before the burst)";
    }
    for (int k = 0; k < args_.frames; ++k) {
      const double t = t_start + k / args_.fps;
      out->last = sim_->render(t, 1.0, frameIndex(t));
      // The same order as ever without an event: the simulated auto-exposure carries state from
      // frame to frame, and another order gives other figures.
      if (k == 0 && !event) renderLightOff(t_start, true, window);
      window[0].light_on.push_back(out->last.left);
      window[1].light_on.push_back(out->last.right);
      if (args_.learn_window == 2 && k + 1 == args_.frames) renderLightOff(t_start, false, window);
    }
    const double t = t_start + (args_.frames - 1) / args_.fps;
    const auto w0 = std::chrono::steady_clock::now();
    const WindowTrack tracked = window_tracker_.track(window[0], window[1], t);
    std::printf("    window tracked in %.0f ms, %d saddle fits failed\n",
                std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - w0).count(),
                tracked.saddle_failures);
    const StereoObservation& obs = tracked.observation;
    if (tracked.scene_sides.compared)
      std::printf("    scene before and after the window: %s, change %.3f px (+- %.3f px)\n",
                  tracked.scene_sides.consistent ? "consistent" : "CHANGED, not used", tracked.scene_sides.change_px,
                  tracked.scene_sides.change_stddev_px);
    if (!obs.scene.empty()) {
      const std::vector<double> scene_distances = epipolarDistances(obs.scene, out->last.truth);
      const size_t n = scene_distances.size();
      std::printf("    %zu scene matches; distance to the true epipolar line: median %.3f px, 90 %% %.3f px, "
                  "max %.2f px\n",
                  n, scene_distances[n / 2], scene_distances[n * 9 / 10], scene_distances.back());
    }
    out->add(obs, out->last);
  }

  // The light-off frames on one side of the window. The live driver's settle_frames unsettled
  // frames lie between: gap = settle_frames + 1.
  void renderLightOff(double t_start, bool before, WindowFrames* window) {
    for (int o = before ? args_.off_frames : 1; before ? o >= 1 : o <= args_.off_frames; o += before ? -1 : 1) {
      const double t = before ? t_start - (args_.light_off_gap + o - 1) / args_.fps
                              : t_start + (args_.frames - 1 + args_.light_off_gap + o - 1) / args_.fps;
      const SimFrame f = sim_->render(t, 0.0, frameIndex(t));
      (before ? window[0].light_off_before : window[0].light_off_after).push_back(f.left);
      (before ? window[1].light_off_before : window[1].light_off_after).push_back(f.right);
    }
  }

  // The window's solve; with --filter, again with what earlier windows taught as the prior of
  // the groups this window does not contradict (*prior_note says which).
  BundleAdjustmentSummary solve(const std::vector<StereoObservation>& frames, double t_start, std::string* prior_note) {
    CalibrationInput input;
    input.frames = &frames;
    input.device = args_.free_poses ? nullptr : &config_.device;
    input.boards = &boards_;
    input.image_width = config_.rig.left.width;
    input.image_height = config_.rig.left.height;
    input.in_force = in_force_;
    BundleAdjustmentSummary candidate = adjuster_.Solve(input);
    if (!args_.filter || !candidate.success) return candidate;
    std::vector<std::string> changed;
    if (const std::optional<RigPrior> prior = filter_.priorFor(candidate, t_start, &changed)) {
      input.rig_prior = prior;
      const BundleAdjustmentSummary alone = candidate;
      input.weights_from = &alone;
      candidate = adjuster_.Solve(input);
      *prior_note = "prior on " + std::to_string(prior->activeCount()) + " parameters";
    } else {
      *prior_note = filter_.hasState() ? "no prior" : "no state yet";
    }
    if (!changed.empty()) {
      *prior_note += "; changed:";
      for (const std::string& g : changed) *prior_note += " " + g + ",";
      prior_note->pop_back();
    }
    return candidate;
  }

  GateDecision judge(const BundleAdjustmentSummary& candidate, const std::vector<StereoObservation>& frames) const {
    GateDecision decision;
    if (!candidate.success) {
      decision.reason = "solve failed: " + candidate.message;
      return decision;
    }
    const BundleAdjustmentSummary in_force_fit = evaluateFixedCalibration(
        in_force_, frames, boards_, adjuster_.options(), args_.free_poses ? nullptr : &config_.device);
    return gate_.evaluate(candidate, &in_force_fit, in_force_predicted_);
  }

  // The accepted calibration replaces the one in force; prints both against the truth.
  void commit(const BundleAdjustmentSummary& candidate, const StereoRig& truth, const StereoAccuracy& old_a) {
    ++commits_;
    const StereoAccuracy new_a = evaluateStereoAccuracy(candidate.rig, truth);
    const bool is_worse = combined(new_a) > combined(old_a) + kWorsePx;
    worse_ += is_worse;
    print("replaced:", old_a);
    print(is_worse ? "new (WORSE):" : "new:", new_a);
    if (candidate.covariance_ok) print("predicted:", predictStereoAccuracy(candidate.rig, candidate.rig_covariance));
    const RigErrors e = compareRigs(candidate.rig, truth);
    std::printf("    new: fx %.4f / %.4f %%, baseline %.4f %%%s\n", 100 * e.fx_rel[0], 100 * e.fx_rel[1],
                100 * e.baseline_rel,
                candidate.scene_matches_used
                    ? (", " + std::to_string(candidate.scene_matches_used) + " scene matches at " +
                       std::to_string(candidate.scene_sigma_px).substr(0, 5) + " px")
                          .c_str()
                    : "");
    worst_after_mis_ = std::max(worst_after_mis_, new_a.misalignment_px.rms);
    worst_after_bias_ = std::max(worst_after_bias_, new_a.disparity_bias_px.rms);
    afterDecision(new_a);
    in_force_ = candidate.rig;
    in_force_predicted_ = QualityGate::predictedPx(candidate);
  }

  const Args& args_;
  const SimRigConfig& config_;
  SimRig* sim_;
  const PatternPrior prior_;
  PatternTracker tracker_;
  WindowTracker window_tracker_;
  const BundleAdjuster adjuster_;
  const QualityGate gate_;
  const std::vector<VirtualBoard> boards_;
  StereoRig in_force_;
  std::optional<double> in_force_predicted_;  // of a committed solve (the start's is not known)
  DriftScript drift_;
  CalibrationFilter filter_;
  int windows_ = 0, commits_ = 0, worse_ = 0, rejected_ = 0;
  double worst_after_mis_ = 0, worst_after_bias_ = 0;
  std::vector<double> misalignment_after_;  // of the calibration in force after each window's decision
  int out_of_target_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  int status = 0;
  const std::optional<Args> parsed = parseArgs(argc, argv, &status);
  if (!parsed) return status;
  const Args& args = *parsed;
  const SimRigConfig config = loadSimRigConfig(args.config);
  SimRig sim(config);
  const auto t0 = std::chrono::steady_clock::now();
  const PatternPrior prior = teach(sim, args.fps, args.teach_frames);
  std::printf("%s: %zu movers; taught %zu + %zu boards from %d frames; window of %d frames at %.0f fps every %.0f s "
              "for %.1f min\n",
              args.config.c_str(), config.scene.movers.size(), prior.cameras[0].boards.size(),
              prior.cameras[1].boards.size(), args.teach_frames, args.frames, args.fps, args.period_s, args.minutes);
  MovingCalibration run(args, config, &sim, prior);
  const int window_count = static_cast<int>(args.minutes * 60.0 / args.period_s);
  for (int w = 1; w <= window_count; ++w) run.window(w);
  return run.summary(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / 60.0);
}
