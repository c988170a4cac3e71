#pragma once
// diagnostic_updater status of one image stage (Separator, Rectifier, Disparity), published on
// /diagnostics once a second: input and output rates, latency (image stamp to publication,
// p50/p95/max over the last second), processing time per frame, the count of input frames whose
// pixels had to be COPIED (an encoding conversion by cv_bridge instead of a shared view: must stay
// 0 in our pipeline) and the stage's own key/values (mode, method, epoch...) set by the nodelet.
//
// Threads: the frame methods and set() may be called from any thread (the nodelet's frame
// callback); the report runs on a wall timer of the node handle given to the constructor. Both
// sides take mutex_, held only to update counters or copy them.
#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>

#include <opencv2/core.hpp>

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace embedded_calibration_stereo {

class StageDiagnostics {
 public:
  // The status is named "<pnh's namespace without the leading slash>: <task>" (diagnostic_updater's
  // convention, e.g. "stereo/disparity: disparity"; pnh's namespace rather than the nodelet's
  // getName(), which is not always absolute), published by an Updater of `nh`/`pnh`
  // (diagnostic_period parameter of pnh) and refreshed every second on a wall timer of `nh`.
  StageDiagnostics(ros::NodeHandle& nh, ros::NodeHandle& pnh, const std::string& task);

  // One synchronised input frame (a stereo pair) arrived.
  void frameIn();
  // One output frame with the stamp of its input was published, after `processing_ms` of work
  // (0 for a pass-through).
  void framePublished(const ros::Time& stamp, double processing_ms);
  // Counts the input as copied when cv_bridge's view does not point into the message's own
  // buffer (toCvShare had to convert); returns true when it was copied.
  bool checkShared(const cv::Mat& view, const sensor_msgs::Image& msg);
  // A stage-specific key/value shown in the status (e.g. "mode", "calibration epoch").
  void set(const std::string& key, const std::string& value);

  uint64_t inputCopies() const;

 private:
  void report(diagnostic_updater::DiagnosticStatusWrapper& status);

  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros::WallTimer timer_;

  mutable std::mutex mutex_;
  ros::WallTime window_start_;
  uint64_t window_in_ = 0, window_out_ = 0;
  uint64_t total_in_ = 0, total_out_ = 0, input_copies_ = 0;
  std::vector<double> latencies_ms_, processing_ms_;  // of the current window
  std::map<std::string, std::string> values_;
};

}  // namespace embedded_calibration_stereo
