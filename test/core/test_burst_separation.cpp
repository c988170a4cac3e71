// The Separator's device image learned from one light burst (core/tracker/window_tracker.h
// windowEnds + learnWindowDevice, as the Separator nodelet learns it), on the moving drive_photo
// scenario: the head drives, people cross, nothing is covered. Scored against the simulator's
// true scene-only images (PSNR) on the burst's own light-on frames and on later ones:
//  - the burst's ends (4 light-on frames of each end, each paired with the light-off frame on its
//    side), what the Separator learns when a burst ends;
//  - the first 8 light-on frames of a burst paired with the light-off frame before it, what it
//    learns while its first burst goes on: one-sided pairs are worse (the scene moved one way);
//  - the raw light-on frames, for scale.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/depth/separator.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/depth/stereo_device_template.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kConfig = std::string(ECS_SOURCE_DIR) + "/config/drive_photo.yaml";
constexpr double kFps = 30.0;
constexpr int kFirst = 60, kLit = 30;

struct Psnr {
  double min = 1e9, sum = 0;
  int n = 0;
  void add(double p) {
    min = std::min(min, p);
    sum += p;
    ++n;
  }
  double mean() const { return sum / n; }
};

class BurstSeparation : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    sim_ = new SimRig(loadSimRigConfig(kConfig));
    for (int k = 0; k <= kLit + 1; ++k) {
      const bool on = k >= 1 && k <= kLit;
      burst_.push_back(sim_->render((kFirst + k) / kFps, on ? 1.0 : 0.0, 100 + kFirst + k));
    }
    for (int k = 0; k < 5; ++k) later_.push_back(sim_->render((kFirst + 60 + 13 * k) / kFps, 1.0, 900 + k));
  }
  static void TearDownTestSuite() {
    delete sim_;
    burst_.clear();
    later_.clear();
  }

  // One camera's frames of the burst: its light-on frames 1..`lit`, with the light-off frame
  // after it when `whole`.
  static WindowFrames frames(int camera, int lit, bool whole) {
    const auto image = [camera](const SimFrame& f) { return camera ? f.right : f.left; };
    WindowFrames w;
    w.light_off_before.push_back(image(burst_[0]));
    for (int k = 1; k <= lit; ++k) w.light_on.push_back(image(burst_[k]));
    if (whole) w.light_off_after.push_back(image(burst_[kLit + 1]));
    return w;
  }

  // Separates the burst's light-on frames from `from` on and the later ones.
  static void score(const LearnedDevice (&learned)[2], int from, Psnr* in_burst, Psnr* later) {
    ImageSeparator left(SeparatorOptions(), learned[0].device_template);
    ImageSeparator right(SeparatorOptions(), learned[1].device_template);
    const auto add = [&](const SimFrame& f, Psnr* p) {
      cv::Mat l, r;
      separateStereo(left, right, f.left, f.right, &l, &r);
      p->add(cv::PSNR(l, f.left_scene));
      p->add(cv::PSNR(r, f.right_scene));
    };
    for (int k = from; k <= kLit; ++k) add(burst_[k], in_burst);
    for (const SimFrame& f : later_) add(f, later);
  }

  static SimRig* sim_;
  static std::vector<SimFrame> burst_, later_;
};

SimRig* BurstSeparation::sim_ = nullptr;
std::vector<SimFrame> BurstSeparation::burst_, BurstSeparation::later_;

TEST_F(BurstSeparation, TheEndsOfOneBurstSeparateTheSceneWithin35Decibels) {
  Psnr raw;
  for (int k = 1; k <= kLit; ++k) {
    raw.add(cv::PSNR(burst_[k].left, burst_[k].left_scene));
    raw.add(cv::PSNR(burst_[k].right, burst_[k].right_scene));
  }
  LearnedDevice ends[2], early[2];
  const auto t0 = std::chrono::steady_clock::now();
  const std::clock_t c0 = std::clock();
  for (int c = 0; c < 2; ++c) ends[c] = learnWindowDevice(windowEnds(frames(c, kLit, true), 4), separatorLearnerOptions());
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double cpu = static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
  for (int c = 0; c < 2; ++c) early[c] = learnWindowDevice(frames(c, 8, false), separatorLearnerOptions());
  Psnr ends_in, ends_later, early_in, early_later;
  score(ends, 1, &ends_in, &ends_later);
  score(early, 9, &early_in, &early_later);
  std::printf("  raw light-on frames: PSNR min %.1f mean %.1f dB\n", raw.min, raw.mean());
  std::printf("  the burst's ends (%s; %.2f s wall, %.2f s of CPU, both cameras): its frames min %.1f mean %.1f dB, "
              "later frames min %.1f dB\n",
              ends[0].summary().c_str(), wall, cpu, ends_in.min, ends_in.mean(), ends_later.min);
  std::printf("  its first 8 light-on frames (%s): its frames 9..30 min %.1f mean %.1f dB, later frames min %.1f dB\n",
              early[0].summary().c_str(), early_in.min, early_in.mean(), early_later.min);
  EXPECT_EQ(ends[0].pairs, 8);
  EXPECT_TRUE(ends[0].ready && ends[1].ready);
  EXPECT_GE(ends_in.min, 35.0);
  EXPECT_GE(ends_later.min, 35.0);
  EXPECT_GE(early_in.min, 30.0);
  EXPECT_GT(early_in.min, raw.min + 15.0);
  EXPECT_LT(early_in.mean(), ends_in.mean()) << "one-sided pairs are expected to be worse";
}

// The whole burst as the window tracker learns it: the flow computed for every other light-on
// frame of each side and interpolated in time for the others separates the burst as well as every
// frame's own flow does, for about half the flows.
TEST_F(BurstSeparation, InterpolatedFlowsSeparateAsWellAsEveryPairsOwn) {
  DeviceLearnerOptions every = windowLearnerOptions();
  every.flow_pair_step = 1;
  ASSERT_GT(windowLearnerOptions().flow_pair_step, 1);
  LearnedDevice interpolated[2], computed[2];
  double cpu[2];
  for (int variant = 0; variant < 2; ++variant) {
    const std::clock_t c0 = std::clock();
    for (int c = 0; c < 2; ++c)
      (variant ? computed : interpolated)[c] =
          learnWindowDevice(frames(c, kLit, true), variant ? every : windowLearnerOptions());
    cpu[variant] = static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
  }
  Psnr interpolated_in, interpolated_later, computed_in, computed_later;
  score(interpolated, 1, &interpolated_in, &interpolated_later);
  score(computed, 1, &computed_in, &computed_later);
  std::printf("  whole burst, interpolated flows (%.2f s of CPU): min %.2f mean %.2f dB, later frames min %.2f dB\n",
              cpu[0], interpolated_in.min, interpolated_in.mean(), interpolated_later.min);
  std::printf("  whole burst, every pair's flow (%.2f s of CPU): min %.2f mean %.2f dB, later frames min %.2f dB\n",
              cpu[1], computed_in.min, computed_in.mean(), computed_later.min);
  EXPECT_EQ(interpolated[0].pairs, kLit);
  EXPECT_GE(interpolated_in.mean(), computed_in.mean() - 0.2);
  EXPECT_GE(interpolated_in.min, computed_in.min - 0.5);
  EXPECT_GE(interpolated_later.min, computed_later.min - 0.5);
}

// After a 5 % zoom, the template of a burst taken after it separates that burst's middle frames
// with less of the device left (separationResidual) than the template taken before it, and the
// other way round on frames before the zoom: the Separator keeps a new burst's template by this
// score. The raw frames score higher than either.
TEST_F(BurstSeparation, TheResidualPrefersTheTemplateOfTheDeviceAsItIs) {
  SimRig zoomed(loadSimRigConfig(kConfig));
  DriftRequest zoom;
  zoom.focal_scale = 1.05;
  ASSERT_TRUE(zoomed.setDrift(zoom, 0.0).empty());
  std::vector<SimFrame> after;
  for (int k = 0; k <= kLit + 1; ++k) {
    const bool on = k >= 1 && k <= kLit;
    after.push_back(zoomed.render((kFirst + k) / kFps, on ? 1.0 : 0.0, 100 + kFirst + k));
  }
  WindowFrames after_frames;
  after_frames.light_off_before.push_back(after[0].left);
  for (int k = 1; k <= kLit; ++k) after_frames.light_on.push_back(after[k].left);
  after_frames.light_off_after.push_back(after[kLit + 1].left);
  const ImageSeparator before_zoom(SeparatorOptions(),
                                   learnWindowDevice(windowEnds(frames(0, kLit, true), 4), separatorLearnerOptions())
                                       .device_template);
  const ImageSeparator after_zoom(SeparatorOptions(),
                                  learnWindowDevice(windowEnds(after_frames, 4), separatorLearnerOptions()).device_template);
  // The middle frames, which the ends were not learned from.
  std::vector<cv::Mat> middle_before, middle_after;
  for (int k = 12; k <= 18; k += 3) {
    middle_before.push_back(burst_[k].left);
    middle_after.push_back(after[k].left);
  }
  const double on_after[2] = {separationResidual(before_zoom, middle_after), separationResidual(after_zoom, middle_after)};
  const double on_before[2] = {separationResidual(before_zoom, middle_before),
                               separationResidual(after_zoom, middle_before)};
  cv::Mat raw_grey;
  middle_after[0].convertTo(raw_grey, CV_32F);
  cv::Mat smooth;
  cv::blur(raw_grey, smooth, cv::Size(5, 5), cv::Point(-1, -1), cv::BORDER_REFLECT);
  const cv::Mat fine = raw_grey - smooth;
  const double raw = fine.dot(fine) / static_cast<double>(fine.total());
  std::printf("  residual after the zoom: template before %.2f, after %.2f; before the zoom: before %.2f, after %.2f; "
              "a raw frame %.2f (grey levels squared)\n",
              on_after[0], on_after[1], on_before[0], on_before[1], raw);
  EXPECT_LT(on_after[1], on_after[0]);
  EXPECT_LT(on_before[0], on_before[1]);
  EXPECT_LT(on_after[0], raw);
}

TEST(WindowEnds, KeepsTheLightOnFramesNearestEachEnd) {
  WindowFrames w;
  for (int k = 0; k < 7; ++k) w.light_on.push_back(cv::Mat(1, 1, CV_8UC1, cv::Scalar(k)));
  w.light_off_before.push_back(cv::Mat(1, 1, CV_8UC1, cv::Scalar(100)));
  const WindowFrames ends = windowEnds(w, 2);
  ASSERT_EQ(ends.light_on.size(), 4u);
  const int expected[4] = {0, 1, 5, 6};
  for (int i = 0; i < 4; ++i) EXPECT_EQ(ends.light_on[i].at<uchar>(0), expected[i]) << i;
  EXPECT_EQ(ends.light_off_before.size(), 1u);
  EXPECT_EQ(windowEnds(w, 4).light_on.size(), 7u) << "no more than 2 * per_end: all of them";
  EXPECT_THROW(windowEnds(w, 0), std::invalid_argument);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
