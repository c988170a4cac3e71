#pragma once
// The stamp guard of a node's inputs that are matched by stamp (the synchronised inputs of
// lazy_synced_input.h, the OnlineCalibrator's calibration_mode, observations and camera_info).
// A message is let through when its stamp lies near the latest stamp let through on at least
// one OTHER input: from `tolerance` before it to `tolerance` + the wall time elapsed since
// after it (stamps may advance as fast as the clock between two messages). Otherwise it is
// dropped with a warning naming its topic (throttled per topic), so that:
//  - a message stamped far in the future can no longer sit in a synchroniser's queue (an
//    ExactTime queue evicts its OLDEST entries: a few future entries pushed every live frame
//    out until the clock caught up with them);
//  - a message stamped far in the past can no longer pass for a time jump of its source.
// A real time jump (a restarted source, a bag replayed again) moves every input at once: an
// input whose messages have all been dropped for `tolerance` of wall time follows its new
// stamps (said in a warning), and the other inputs, now near it, follow at once.
// The first message of each input, before any other input has one, is let through.
//
// Threads: every method may be called from any thread (one internal mutex).
#include <ros/node_handle.h>
#include <ros/time.h>

#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

#include <sensor_msgs/Image.h>

namespace embedded_calibration_stereo {

// The default of the stamp_tolerance_s parameter (s): far beyond a frame period or the delay
// between a driver's outputs and the stages after it, well below a forged or stale stamp.
constexpr double kDefaultStampToleranceS = 2.0;

// Seconds of the steady (monotonic) clock: the default clock of the guards' wall-time rules.
double steadySeconds();

// Reads the private parameter stamp_tolerance_s (double, s, >= 0.01, default
// kDefaultStampToleranceS); throws core::ConfigError naming it.
double readStampTolerance(const ros::NodeHandle& private_nh);

class StampGuard {
 public:
  using Clock = std::function<double()>;                // monotonic seconds
  using Warn = std::function<void(const std::string&)>;  // one warning line

  // `topics`: the resolved names of the inputs, by index; `owner`: who drops, for the
  // warnings (e.g. the nodelet's name). Default warn: ROS_WARN; default clock: steady clock.
  StampGuard(std::vector<std::string> topics, double tolerance_s, std::string owner, Warn warn = nullptr,
             Clock clock = nullptr);

  // True when the message of input `index` stamped `stamp` may go on.
  bool admit(size_t index, const ros::Time& stamp);
  // Forgets every stamp (the inputs were unsubscribed: later stamps are no jump).
  void reset();

  uint64_t dropped() const;
  double tolerance() const { return tolerance_s_; }

  static constexpr double kWarnPeriodS = 5.0;

 private:
  struct Input {
    bool has = false;
    ros::Time latest;           // stamp of the latest message let through
    double admitted_at = 0.0;   // clock when it was let through
    double refused_since = -1;  // clock of the first drop since then (< 0: none)
    double warned_at = -1;      // clock of the last warning (< 0: none)
    uint64_t dropped_since_warning = 0;
  };

  const std::vector<std::string> topics_;
  const double tolerance_s_;
  const std::string owner_;
  const Warn warn_;
  const Clock clock_;
  mutable std::mutex mutex_;  // guards everything below
  std::vector<Input> inputs_;
  uint64_t dropped_ = 0;
};

// Why `image` cannot be read safely (its data shorter than height x step, a step shorter than
// a row of its encoding, sizes whose product overflows), or "" when it can. An encoding
// unknown to sensor_msgs::image_encodings is left to the consumer (only the data size is
// checked).
std::string malformedImage(const sensor_msgs::Image& image);

}  // namespace embedded_calibration_stereo
