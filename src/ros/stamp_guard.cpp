#include "embedded_calibration_stereo/ros/stamp_guard.h"

#include <ros/console.h>
#include <sensor_msgs/image_encodings.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>

#include "embedded_calibration_stereo/ros/parameter_reader.h"

namespace embedded_calibration_stereo {

double steadySeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double readStampTolerance(const ros::NodeHandle& private_nh) {
  return ParameterReader(private_nh).atLeast("stamp_tolerance_s", kDefaultStampToleranceS, 0.01);
}

StampGuard::StampGuard(std::vector<std::string> topics, double tolerance_s, std::string owner, Warn warn,
                       Clock clock)
    : topics_(std::move(topics)),
      tolerance_s_(tolerance_s),
      owner_(std::move(owner)),
      warn_(warn ? std::move(warn) : Warn([](const std::string& text) { ROS_WARN("%s", text.c_str()); })),
      clock_(clock ? std::move(clock) : Clock(steadySeconds)),
      inputs_(topics_.size()) {}

bool StampGuard::admit(size_t index, const ros::Time& stamp) {
  std::string warning;
  bool admitted = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Input& input = inputs_.at(index);
    const double now = clock_();
    const double t = stamp.toSec();
    bool any_other = false;
    double nearest_offset = std::numeric_limits<double>::infinity();  // signed: t - latest of `nearest`
    size_t nearest = index;  // the other input admitted most recently
    for (size_t j = 0; j < inputs_.size(); ++j) {
      const Input& other = inputs_[j];
      if (j == index || !other.has) continue;
      any_other = true;
      const double offset = t - other.latest.toSec();
      const double ahead_allowed = tolerance_s_ + std::max(0.0, now - other.admitted_at);
      if (offset >= -tolerance_s_ && offset <= ahead_allowed) {
        admitted = true;
        break;
      }
      // Messages name the input let through most recently (the freshest reference).
      if (nearest == index || other.admitted_at > inputs_[nearest].admitted_at) {
        nearest_offset = offset;
        nearest = j;
      }
    }
    if (!any_other) admitted = true;
    if (!admitted && input.refused_since >= 0 && now - input.refused_since >= tolerance_s_) {
      // Nothing on this input fitted for a whole tolerance: its source moved to other stamps.
      char text[512];
      std::snprintf(text, sizeof(text),
                    "%s: the stamps on %s moved %.3f s %s those of %s and stayed there for %.1f s: following "
                    "them (a restarted source or a replayed bag?)",
                    owner_.c_str(), topics_[index].c_str(), std::abs(nearest_offset),
                    nearest_offset > 0 ? "ahead of" : "behind", topics_[nearest].c_str(), tolerance_s_);
      warning = text;
      admitted = true;
    }
    if (admitted) {
      input.has = true;
      input.latest = stamp;
      input.admitted_at = now;
      input.refused_since = -1;
    } else {
      ++dropped_;
      ++input.dropped_since_warning;
      if (input.refused_since < 0) input.refused_since = now;
      if (input.warned_at < 0 || now - input.warned_at >= kWarnPeriodS) {
        char text[640];
        std::snprintf(text, sizeof(text),
                      "%s: dropped %llu message%s on %s: stamp %.3f s is %.3f s %s the latest on %s (%.3f s); "
                      "allowed: %.1f s (parameter stamp_tolerance_s)",
                      owner_.c_str(), static_cast<unsigned long long>(input.dropped_since_warning),
                      input.dropped_since_warning == 1 ? "" : "s", topics_[index].c_str(), t,
                      std::abs(nearest_offset), nearest_offset > 0 ? "ahead of" : "behind",
                      topics_[nearest].c_str(), inputs_[nearest].latest.toSec(), tolerance_s_);
        warning = text;
        input.warned_at = now;
        input.dropped_since_warning = 0;
      }
    }
  }
  if (!warning.empty()) warn_(warning);
  return admitted;
}

void StampGuard::reset() {
  std::lock_guard<std::mutex> lock(mutex_);
  for (Input& input : inputs_) {
    const double warned_at = input.warned_at;  // the throttle survives a resubscription
    input = Input();
    input.warned_at = warned_at;
  }
}

uint64_t StampGuard::dropped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return dropped_;
}

std::string malformedImage(const sensor_msgs::Image& image) {
  namespace enc = sensor_msgs::image_encodings;
  const uint64_t rows_bytes = static_cast<uint64_t>(image.height) * image.step;  // no overflow in 64 bits
  if (image.data.size() < rows_bytes)
    return "data has " + std::to_string(image.data.size()) + " bytes, fewer than height x step = " +
           std::to_string(image.height) + " x " + std::to_string(image.step);
  int bits = 0, channels = 0;
  try {
    bits = enc::bitDepth(image.encoding);
    channels = enc::numChannels(image.encoding);
  } catch (const std::exception&) {
    return "";  // an encoding we cannot size: the consumer refuses or reads it
  }
  const uint64_t row_bytes = static_cast<uint64_t>(image.width) * static_cast<uint64_t>(channels) *
                             static_cast<uint64_t>(bits) / 8;
  if (image.step < row_bytes)
    return "step " + std::to_string(image.step) + " is shorter than a row of " + std::to_string(image.width) +
           " " + image.encoding + " pixels (" + std::to_string(row_bytes) + " bytes)";
  return "";
}

}  // namespace embedded_calibration_stereo
