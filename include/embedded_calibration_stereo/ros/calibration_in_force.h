#pragma once
// The OnlineCalibrator's view of the calibration in force: the latest valid left/right
// camera_info pair the driver publishes, every frame's camera_info for reading a commit back (the
// epoch of the first frame carrying it), and the key of the pair last put on /tf_static.
// docs/nodelets.md, "OnlineCalibrator".
//
// Threading: not thread-safe; the owner guards it with its own mutex.
#include <sensor_msgs/CameraInfo.h>

#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/calibration_windows.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"

namespace embedded_calibration_stereo {

class CalibrationInForce {
 public:
  // What storing one side's camera_info did.
  struct Stored {
    std::string problem;  // why it was dropped (the pair in force stays); "" when kept
    bool changed = false;  // the pair in force changed its rectification: put it on /tf_static
  };

  // One side's camera_info (`topic`; the other side's: `other_topic`). A side that fails the
  // consumers' checks, or that does not form a rectified pair with the other side of its stamp,
  // is dropped; when the other side of its stamp has not arrived yet it waits.
  Stored store(bool left, const sensor_msgs::CameraInfoConstPtr& info, const std::string& topic,
               const std::string& other_topic);

  // The latest valid pair (null until there is one).
  const sensor_msgs::CameraInfoConstPtr& left() const { return left_; }
  const sensor_msgs::CameraInfoConstPtr& right() const { return right_; }

  // The epoch of the driver's first frame (among `frames`) whose left and right camera_info carry
  // `committed`, among frames of another epoch than `before` (the one in force at the solve).
  // Read, not predicted: how the driver counts set_camera_info calls is its business.
  std::optional<uint32_t> epochCarrying(const CommittedCalibration& committed, uint32_t before,
                                        const std::deque<core::FrameSeen>& frames) const;

  // The driver still publishes the calibration `u` was gated against (its epoch may have moved:
  // a failed commit puts the left calibration back).
  bool stillInForce(const UncommittedCalibration& u) const;

 private:
  static constexpr size_t kKeptInfos = 16;  // camera_info per side (the commit's epoch)
  std::deque<sensor_msgs::CameraInfoConstPtr> recent_left_, recent_right_;
  sensor_msgs::CameraInfoConstPtr left_, right_;                // the latest valid pair
  sensor_msgs::CameraInfoConstPtr latest_left_, latest_right_;  // the latest valid side
  // The rectification (left R, right R and P) of the pair last reported changed: a pair set from
  // outside the calibrator (a rollback, rosservice) goes on /tf_static too.
  std::vector<double> tf_key_;
};

}  // namespace embedded_calibration_stereo
