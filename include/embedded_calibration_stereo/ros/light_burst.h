#pragma once
// The frames of one light burst for learning its device image (the PatternTracker's window
// tracking and teaching, the Separator's learning; core/tracker/window_tracker.h): the burst's
// settled light-on frames and the settled light-off frames around it, the last one before it and
// the first one after it (the learned device image needs both), kept as the shared message
// pointers: no image is copied.
//
// Threads: not thread-safe (one owner: the tracker nodelet's callback queue).
#include <sensor_msgs/Image.h>

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/core/tracker/window_tracker.h"

namespace embedded_calibration_stereo {

using StereoImages = std::pair<sensor_msgs::ImageConstPtr, sensor_msgs::ImageConstPtr>;  // left, right

struct LightBurst {
  StereoImages light_off_before, light_off_after;
  std::vector<StereoImages> light_on;  // in arrival order
};

// A burst that ended. `problem` is empty when it can be tracked; otherwise why it is dropped
// (its light-on frames are then not kept; light_off_before may be null).
struct EndedBurst {
  LightBurst burst;
  int light_on_frames = 0;  // settled light-on frames it had
  std::string problem;
};

class LightBurstCollector {
 public:
  // A burst with fewer settled light-on frames (a verification flash) ends without a word.
  // `need_light_off_before` false: a burst that no settled light-off frame preceded (a subscriber
  // that came in during it) is kept, with a null light_off_before.
  explicit LightBurstCollector(int min_light_on_frames, bool need_light_off_before = true)
      : min_light_on_frames_(min_light_on_frames), need_light_off_before_(need_light_off_before) {}

  // One settled frame (calibration_mode settled) with its light state. Returns the burst this
  // frame ends: at the first settled light-off frame after a burst of at least
  // min_light_on_frames light-on frames. Dropped (a problem): its frames (light-off ones
  // included) differ in size or encoding or have an encoding other than mono8, bgr8, rgb8, or no
  // settled light-off frame preceded it (unless need_light_off_before is false). A new calibration coming into force during a burst does
  // not end it: the images do not depend on the calibration, only the corners' use does, and
  // the calibrator solves against what is in force when it solves.
  std::optional<EndedBurst> add(const sensor_msgs::ImageConstPtr& left, const sensor_msgs::ImageConstPtr& right,
                                bool light_on);
  // The burst under way: the light-off frame before it and its settled light-on frames so far
  // (no light-on frame while none is under way, or when it will be dropped).
  LightBurst underWay() const;
  // How many light-on frames underWay() holds.
  int lightOnFramesKept() const { return problem_.empty() ? static_cast<int>(light_on_.size()) : 0; }

 private:
  const int min_light_on_frames_;
  const bool need_light_off_before_;
  StereoImages light_off_;  // the latest settled light-off frame since the last burst
  std::vector<StereoImages> light_on_;
  int frames_ = 0;  // settled light-on frames of the burst under way, kept or not
  std::string problem_;
};

// Why a stereo frame cannot be tracked ("" when it can): left and right of different sizes or
// encodings, or an encoding other than mono8, bgr8, rgb8.
std::string stereoFormatProblem(const sensor_msgs::Image& left, const sensor_msgs::Image& right);

// A stereo frame as the core tracker takes it: the messages' pixels (they own them) and the
// colour order, or why it cannot be read ("" when read): stereoFormatProblem, or cv_bridge's error.
std::string readStereo(const sensor_msgs::ImageConstPtr& left, const sensor_msgs::ImageConstPtr& right,
                       cv::Mat* left_image, cv::Mat* right_image, core::ColorOrder* order);

// A burst's image as the core takes it: the message's pixels (the message owns them), rgb8
// converted to BGR. Throws cv_bridge::Exception when the message cannot be read.
cv::Mat windowImage(const sensor_msgs::ImageConstPtr& m);

// One camera's frames of a burst (0 left, 1 right), through windowImage: keep the burst (its
// messages) alive while they are used. A missing light-off frame (the burst under way has none
// after it) is left out.
core::WindowFrames windowFrames(const LightBurst& burst, int camera);

}  // namespace embedded_calibration_stereo
