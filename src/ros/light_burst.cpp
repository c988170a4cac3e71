#include "embedded_calibration_stereo/ros/light_burst.h"

#include <cv_bridge/cv_bridge.h>
#include <opencv2/imgproc.hpp>

namespace embedded_calibration_stereo {

namespace {

std::string describe(const sensor_msgs::Image& m) {
  return m.encoding + " " + std::to_string(m.width) + "x" + std::to_string(m.height);
}

bool sameFormat(const sensor_msgs::Image& a, const sensor_msgs::Image& b) {
  return a.encoding == b.encoding && a.width == b.width && a.height == b.height;
}

}  // namespace

std::string stereoFormatProblem(const sensor_msgs::Image& left, const sensor_msgs::Image& right) {
  if (!sameFormat(left, right)) return "left and right differ (" + describe(left) + " vs " + describe(right) + ")";
  if (left.encoding != "mono8" && left.encoding != "bgr8" && left.encoding != "rgb8")
    return "encoding '" + left.encoding + "' (expected mono8, bgr8 or rgb8)";
  return "";
}

std::optional<EndedBurst> LightBurstCollector::add(const sensor_msgs::ImageConstPtr& left,
                                                   const sensor_msgs::ImageConstPtr& right, bool light_on) {
  const StereoImages frame(left, right);
  if (!light_on) {
    std::optional<EndedBurst> ended;
    if (frames_ >= min_light_on_frames_) {
      ended.emplace();
      ended->light_on_frames = frames_;
      ended->problem = problem_;
      if (ended->problem.empty()) {
        if (const std::string p = stereoFormatProblem(*left, *right); !p.empty())
          ended->problem = "the light-off frame after it: " + p;
        else if (light_on_.empty())
          ended->problem = "none of its light-on frames was kept";
        else if (!sameFormat(*left, *light_on_.front().first))
          ended->problem = "its frames differ in size or encoding (" + describe(*light_on_.front().first) +
                           ", the light-off frame after it " + describe(*left) + ")";
      }
      ended->burst.light_off_before = light_off_;
      ended->burst.light_off_after = frame;
      if (ended->problem.empty()) ended->burst.light_on = std::move(light_on_);
    }
    light_on_.clear();
    frames_ = 0;
    problem_.clear();
    light_off_ = frame;  // the next burst's, until a later one
    return ended;
  }
  if (frames_++ == 0) {
    if (!light_off_.first) {
      if (need_light_off_before_) problem_ = "no settled light-off frame before it";
    } else if (const std::string p = stereoFormatProblem(*light_off_.first, *light_off_.second); !p.empty()) {
      problem_ = "the light-off frame before it: " + p;
    }
  }
  if (!problem_.empty()) return std::nullopt;
  if (const std::string p = stereoFormatProblem(*left, *right); !p.empty()) {
    problem_ = "a light-on frame: " + p;
  } else if (light_off_.first && !sameFormat(*left, *light_off_.first)) {
    problem_ = "its frames differ in size or encoding (" + describe(*left) + ", the light-off frame before it " +
               describe(*light_off_.first) + ")";
  } else {
    light_on_.push_back(frame);
    return std::nullopt;
  }
  light_on_.clear();  // dropped: the messages need not be kept
  return std::nullopt;
}

std::string readStereo(const sensor_msgs::ImageConstPtr& left, const sensor_msgs::ImageConstPtr& right,
                       cv::Mat* left_image, cv::Mat* right_image, core::ColorOrder* order) {
  if (std::string problem = stereoFormatProblem(*left, *right); !problem.empty()) return problem;
  try {
    *left_image = cv_bridge::toCvShare(left)->image;  // shares the message's data, which `left` keeps
    *right_image = cv_bridge::toCvShare(right)->image;
  } catch (const cv_bridge::Exception& e) {
    return std::string("cannot read it: ") + e.what();
  }
  *order = left->encoding == "rgb8" ? core::ColorOrder::kRgb : core::ColorOrder::kBgr;
  return "";
}

cv::Mat windowImage(const sensor_msgs::ImageConstPtr& m) {
  cv::Mat mat = cv_bridge::toCvShare(m)->image;
  if (m->encoding == "rgb8") cv::cvtColor(mat, mat, cv::COLOR_RGB2BGR);
  return mat;
}

core::WindowFrames windowFrames(const LightBurst& burst, int camera) {
  const auto side = [camera](const StereoImages& pair) { return camera == 0 ? pair.first : pair.second; };
  core::WindowFrames frames;
  if (side(burst.light_off_before)) frames.light_off_before.push_back(windowImage(side(burst.light_off_before)));
  if (side(burst.light_off_after)) frames.light_off_after.push_back(windowImage(side(burst.light_off_after)));
  for (const StereoImages& on : burst.light_on) frames.light_on.push_back(windowImage(side(on)));
  return frames;
}

LightBurst LightBurstCollector::underWay() const {
  LightBurst burst;
  if (!problem_.empty()) return burst;
  burst.light_off_before = light_off_;
  burst.light_on = light_on_;
  return burst;
}

}  // namespace embedded_calibration_stereo
