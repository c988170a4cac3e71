// The Separator's device image learned during normal operation on `drive_photo` (the head drives
// through a photographed corridor with a person crossing and a door swinging; real-head optics:
// auto-exposure, the light's response, ghost, vignetting, shot noise), with the driver's light
// schedule: no covered scene and no simulator truth go into the learning. The truth only scores
// the result: the separated light-on frames against the ground-truth scene-only images (PSNR),
// and disparity (the sad matcher, with the Disparity nodelet's settings) from separated light-on
// frames against disparity from the light-off frames around them, both against the true
// disparity. The matcher is fixed so that the test measures the learner: census_sgm, the
// default, sees more of what separation leaves of the boards (docs/depth_quality.md).
// Scored on light windows not used for learning. Then a 5 % zoom (a new calibration epoch):
// the old template against raw frames, and the template re-learned from the new epoch's windows.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/core/depth/device_image_learner.h"
#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/depth/separator.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kConfigPath = std::string(ECS_SOURCE_DIR) + "/config/drive_photo.yaml";
constexpr double kFps = 30.0;
// A light window every 1.3 s: distinct stretches of the corridor (the demo's 10 s would
// need minutes of rendering for the same number of windows).
constexpr double kPeriodS = 1.3;
constexpr int kSettleFrames = 2, kCalibrationFrames = 10;

// One light window's frames, as the Separator nodelet pairs them: the last settled light-off
// frame before the window with the first two settled light-on frames, the last two settled
// light-on frames with the first settled light-off frame after it.
struct Window {
  int first_on = 0;  // frame index of the first commanded light-on frame
  SimFrame off_before, off_after;
  std::map<int, SimFrame> on;  // settled light-on frames kept, by offset from first_on
};

// The driver's stream: every frame steps the light schedule; only the frames around the light
// windows asked for are rendered, in order (the auto-exposure and the light's response carry
// state from one rendered frame to the next).
class DriverStream {
 public:
  explicit DriverStream(SimRig* sim) : sim_(sim), schedule_(scheduleConfig()) {}

  static LightScheduleConfig scheduleConfig() {
    LightScheduleConfig c;
    c.period_s = kPeriodS;
    c.settle_frames = kSettleFrames;
    c.calibration_frames = kCalibrationFrames;
    return c;
  }

  // Renders the next light window (skipping the first: no light-off frame before it), keeping
  // the settled light-on frames at `keep_on` offsets.
  Window nextWindow(const std::vector<int>& keep_on) {
    Window w;
    // Step the schedule until the frame before the next burst.
    while (true) {
      const LightState s = peek(frame_);
      if (s.light_on && s.switched && frame_ > 0) break;
      advance(false);
    }
    w.first_on = frame_;
    // The light-off frame before it was stepped without rendering: render it now (the scene's
    // time is its frame index, as in the driver; only the auto-exposure misses the skipped frames).
    w.off_before = renderAt(frame_ - 1, current_);
    const int last = frame_ + kSettleFrames + kCalibrationFrames + kSettleFrames;  // first settled off
    while (frame_ <= last) {
      const int offset = frame_ - w.first_on;
      SimFrame f = advance(true);
      if (frame_ - 1 == last) {
        EXPECT_FALSE(current_.light_on);
        EXPECT_TRUE(current_.settled);
        w.off_after = std::move(f);
      } else if (current_.light_on && current_.settled &&
                 std::find(keep_on.begin(), keep_on.end(), offset) != keep_on.end()) {
        w.on[offset] = std::move(f);
      }
    }
    return w;
  }

  int frame() const { return frame_; }

 private:
  // The state the schedule will give frame f (steps a copy).
  LightState peek(int f) {
    LightSchedule copy = schedule_;
    return copy.step(f / kFps);
  }

  SimFrame renderAt(int f, const LightState& s) {
    SimRenderRequest r;
    r.time_s = f / kFps;
    r.light_level = s.light_level;
    r.noise_seed = static_cast<uint64_t>(f) + 1;
    r.has_light_command = true;
    r.light_command.on = s.light_on;
    r.light_command.switch_time_s = switch_time_s_;
    return sim_->render(r);
  }

  SimFrame advance(bool render) {
    current_ = schedule_.step(frame_ / kFps);
    if (current_.switched) switch_time_s_ = frame_ / kFps;
    SimFrame f;
    if (render) f = renderAt(frame_, current_);
    ++frame_;
    return f;
  }

  SimRig* sim_;
  LightSchedule schedule_;
  LightState current_;  // the state of the last frame stepped
  int frame_ = 0;
  double switch_time_s_ = -1e300;
};

constexpr int kFirstOn = kSettleFrames;                           // offset of the first settled on frame
constexpr int kLastOn = kSettleFrames + kCalibrationFrames - 1;   // and of the last
const std::vector<int> kPairOffsets = {kFirstOn, kFirstOn + 1, kLastOn - 1, kLastOn};
const std::vector<int> kScoreOffsets = {kFirstOn, kFirstOn + 2, kFirstOn + 4, kFirstOn + 6, kLastOn};

void addPairs(const Window& w, LightPairSet* left, LightPairSet* right) {
  for (int offset : kPairOffsets) {
    const SimFrame& off = offset < kFirstOn + 2 ? w.off_before : w.off_after;
    left->add(off.left, w.on.at(offset).left);
    right->add(off.right, w.on.at(offset).right);
  }
}

struct Scores {
  double min_psnr = 1e9, sum_psnr = 0;
  int psnr_count = 0;
  double bad_on = 0, bad_off = 0;  // mean bad > 2 px, percent
  int on_count = 0, off_count = 0;
  double worst_gap = 0;  // per window: |mean bad of separated on - mean bad of its off frames|
  void addPsnr(double p) {
    min_psnr = std::min(min_psnr, p);
    sum_psnr += p;
    ++psnr_count;
  }
};

double badPercent(const SimFrame& f, const cv::Mat& left, const cv::Mat& right) {
  const RectificationMaps maps = RectificationMaps::build(f.truth, RectificationOptions());
  const cv::Mat truth = rectifiedDisparityFromDepth(f.left_depth, maps);
  DisparityOptions sad;
  sad.algorithm = "sad";
  DisparityComputer matcher{sad};
  const auto rect = maps.rectify(left, right);
  return evaluateBadPixels(matcher.compute(rect.first, rect.second), truth, 2.0).badPercent();
}

// Scores a window's kept light-on frames; `separate` empty: the raw light-on frames.
void score(const Window& w, const ImageSeparator* left, const ImageSeparator* right, Scores* s) {
  double on_sum = 0, off_sum = 0;
  for (const auto& [offset, f] : w.on) {
    cv::Mat l = f.left, r = f.right;
    if (left) {
      l = cv::Mat();
      r = cv::Mat();
      separateStereo(*left, *right, f.left, f.right, &l, &r);
    }
    s->addPsnr(cv::PSNR(l, f.left_scene));
    s->addPsnr(cv::PSNR(r, f.right_scene));
    on_sum += badPercent(f, l, r);
  }
  for (const SimFrame* f : {&w.off_before, &w.off_after}) off_sum += badPercent(*f, f->left, f->right);
  const double on_mean = on_sum / w.on.size(), off_mean = off_sum / 2;
  s->bad_on += on_sum;
  s->on_count += static_cast<int>(w.on.size());
  s->bad_off += off_sum;
  s->off_count += 2;
  s->worst_gap = std::max(s->worst_gap, std::abs(on_mean - off_mean));
}

void print(const char* what, const Scores& s) {
  std::printf("  %-44s PSNR min %.2f mean %.2f dB; bad>2px separated-on %.2f %%, light-off %.2f %%, "
              "worst window gap %.2f points\n",
              what, s.min_psnr, s.sum_psnr / s.psnr_count, s.bad_on / s.on_count, s.bad_off / s.off_count,
              s.worst_gap);
}

double secondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

struct Learned {
  LearnedDevice left, right;
};

// Learns from windows of `stream` until both cameras are ready (at most max_windows).
Learned learnUntilReady(DriverStream* stream, uint32_t epoch, int max_windows, const char* what) {
  const DeviceLearnerOptions options;  // the Separator nodelet's defaults
  LightPairSet left(options.max_pairs), right(options.max_pairs);
  left.reset(epoch);
  right.reset(epoch);
  Learned learned;
  for (int w = 0; w < max_windows; ++w) {
    addPairs(stream->nextWindow(kPairOffsets), &left, &right);
    if (left.size() < options.min_pairs) continue;
    const auto t0 = std::chrono::steady_clock::now();
    learned = {learnDeviceImage(left.snapshot(), options, epoch), learnDeviceImage(right.snapshot(), options, epoch)};
    std::printf("  %s, after %d windows: left %s, right %s (learning %.2f s)\n", what, w + 1,
                learned.left.summary().c_str(), learned.right.summary().c_str(), secondsSince(t0));
    if (learned.left.ready && learned.right.ready) break;
  }
  return learned;
}

TEST(DeviceImageLearner, LearnsOnDrivePhotoWithoutTruthAndFollowsAZoom) {
  const auto t0 = std::chrono::steady_clock::now();
  SimRig sim(loadSimRigConfig(kConfigPath));
  DriverStream stream(&sim);
  const SeparatorOptions separator_options;  // regional alpha, the nodelet's default

  const Learned learned = learnUntilReady(&stream, 0, 8, "drive_photo");
  ASSERT_TRUE(learned.left.ready && learned.right.ready);
  const ImageSeparator left(separator_options, learned.left.device_template),
      right(separator_options, learned.right.device_template);

  // Scored on the next two windows (not learned from).
  Scores separated, raw;
  for (int w = 0; w < 2; ++w) {
    const Window win = stream.nextWindow(kScoreOffsets);
    score(win, &left, &right, &separated);
    score(win, nullptr, nullptr, &raw);
  }
  print("learned template:", separated);
  print("raw light-on frames (not separated):", raw);
  EXPECT_GE(separated.min_psnr, 35.0);
  EXPECT_LE(separated.worst_gap, 2.0);

  // A 5 % zoom: a new calibration epoch; the boards moved in the image.
  DriftRequest zoom;
  zoom.focal_scale = 1.05;
  ASSERT_EQ(sim.setDrift(zoom, stream.frame() / kFps), "");
  Scores stale, raw_after;
  const Window after = stream.nextWindow(kScoreOffsets);
  score(after, &left, &right, &stale);
  score(after, nullptr, nullptr, &raw_after);
  print("after a 5 % zoom, the old template:", stale);
  print("after a 5 % zoom, raw light-on frames:", raw_after);

  const Learned relearned = learnUntilReady(&stream, 1, 8, "after the zoom");
  ASSERT_TRUE(relearned.left.ready && relearned.right.ready);
  const ImageSeparator left2(separator_options, relearned.left.device_template),
      right2(separator_options, relearned.right.device_template);
  Scores fresh;
  for (int w = 0; w < 2; ++w) score(stream.nextWindow(kScoreOffsets), &left2, &right2, &fresh);
  print("after a 5 % zoom, re-learned:", fresh);
  EXPECT_GE(fresh.min_psnr, 35.0);
  EXPECT_LE(fresh.worst_gap, 2.0);
  std::printf("  test time %.1f s\n", secondsSince(t0));
}

// Pairs one after the other (the window tracker's choice, for memory) learn the very same image
// as pairs in parallel, with and without interpolated flows: the result depends on no thread.
TEST(DeviceImageLearner, PairsInSeriesLearnWhatPairsInParallelLearn) {
  cv::RNG rng(7);
  cv::Mat scene(120, 160, CV_8UC1);
  rng.fill(scene, cv::RNG::UNIFORM, 20, 200);
  cv::GaussianBlur(scene, scene, cv::Size(5, 5), 1.5);
  cv::Mat pattern = cv::Mat::zeros(scene.size(), CV_8UC1);
  cv::rectangle(pattern, cv::Rect(40, 30, 80, 60), cv::Scalar(40), cv::FILLED);
  const cv::Mat off = scene.clone();
  std::vector<LightPair> pairs;
  for (int k = 1; k <= 6; ++k) {
    cv::Mat moved;
    const cv::Matx23d shift(1, 0, 0.7 * k, 0, 1, -0.4 * k);
    cv::warpAffine(scene, moved, shift, scene.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
    pairs.push_back({off, moved + pattern, k});
  }
  for (int step : {1, 2}) {
    DeviceLearnerOptions parallel;
    parallel.min_pairs = 2;
    parallel.flow_pair_step = step;
    DeviceLearnerOptions series = parallel;
    series.parallel_pairs = false;
    const cv::Mat a = learnDeviceImage(pairs, parallel, 0).device_template.device;
    const cv::Mat b = learnDeviceImage(pairs, series, 0).device_template.device;
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0.0) << "flow_pair_step " << step;
    // And it learned the pattern: the lit rectangle stands out of the rest.
    EXPECT_GT(cv::mean(a(cv::Rect(50, 40, 60, 40)))[0], cv::mean(a(cv::Rect(0, 0, 30, 120)))[0] + 20.0);
  }
}

TEST(DeviceImageLearner, RejectsWrongInputs) {
  DeviceLearnerOptions bad;
  bad.min_pairs = 1;
  EXPECT_NE(bad.validate(), "");
  DeviceLearnerOptions too_coarse;
  too_coarse.flow_finest_scale = 5;
  EXPECT_NE(too_coarse.validate().find("flow_finest_scale"), std::string::npos);
  DeviceLearnerOptions no_overlap;  // DIS needs its patches (8 wide) to overlap
  no_overlap.flow_patch_stride = 8;
  EXPECT_NE(no_overlap.validate().find("flow_patch_stride"), std::string::npos);
  no_overlap.flow_patch_stride = 7;
  EXPECT_EQ(no_overlap.validate(), "");
  DeviceLearnerOptions sparse;
  sparse.flow_pair_step = 5;
  EXPECT_NE(sparse.validate().find("flow_pair_step"), std::string::npos);
  const cv::Mat a(48, 64, CV_8UC1, cv::Scalar(10)), b(48, 64, CV_8UC1, cv::Scalar(20));
  EXPECT_THROW(learnDeviceImage({{a, b}, {a, b}}, bad, 0), std::invalid_argument);
  EXPECT_THROW(learnDeviceImage({{a, b}}, DeviceLearnerOptions(), 0), std::invalid_argument);
  LightPairSet set(3);
  EXPECT_THROW(set.add(a, cv::Mat(48, 32, CV_8UC1)), std::invalid_argument);
  EXPECT_THROW(set.add(cv::Mat(48, 64, CV_16UC1), cv::Mat(48, 64, CV_16UC1)), std::invalid_argument);
  set.add(a, b);
  EXPECT_THROW(set.add(cv::Mat(24, 32, CV_8UC1), cv::Mat(24, 32, CV_8UC1)), std::invalid_argument);
  for (int i = 0; i < 5; ++i) set.add(a, b);
  EXPECT_EQ(set.size(), 3);  // the oldest are dropped
  set.reset(7);
  EXPECT_EQ(set.size(), 0);
  EXPECT_EQ(set.epoch(), 7u);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
