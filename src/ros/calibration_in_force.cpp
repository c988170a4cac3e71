#include "embedded_calibration_stereo/ros/calibration_in_force.h"

#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

CalibrationInForce::Stored CalibrationInForce::store(bool left, const sensor_msgs::CameraInfoConstPtr& info,
                                                     const std::string& topic, const std::string& other_topic) {
  Stored stored;
  stored.problem = checkCameraInfo(*info, topic, info->width, info->height);
  auto& recent = left ? recent_left_ : recent_right_;  // every frame's, for the commit read-back
  recent.push_back(info);
  if (recent.size() > kKeptInfos) recent.pop_front();
  (left ? latest_left_ : latest_right_) = stored.problem.empty() ? info : nullptr;
  const sensor_msgs::CameraInfoConstPtr other = left ? latest_right_ : latest_left_;
  if (!stored.problem.empty() || !other) return stored;
  const std::string mismatch = left ? checkRectifiedPair(*info, topic, *other, other_topic)
                                    : checkRectifiedPair(*other, other_topic, *info, topic);
  if (!mismatch.empty()) {
    if (other->header.stamp == info->header.stamp) stored.problem = mismatch;  // the two sides of one frame disagree
    return stored;
  }
  left_ = left ? info : other;
  right_ = left ? other : info;
  std::vector<double> key(left_->R.begin(), left_->R.end());
  key.insert(key.end(), right_->R.begin(), right_->R.end());
  key.insert(key.end(), right_->P.begin(), right_->P.end());
  if (key != tf_key_) {
    tf_key_ = std::move(key);
    stored.changed = true;
  }
  return stored;
}

std::optional<uint32_t> CalibrationInForce::epochCarrying(const CommittedCalibration& committed, uint32_t before,
                                                          const std::deque<core::FrameSeen>& frames) const {
  const auto at = [](const std::deque<sensor_msgs::CameraInfoConstPtr>& infos, core::StampNs stamp) {
    for (const auto& info : infos)
      if (static_cast<core::StampNs>(info->header.stamp.toNSec()) == stamp) return info;
    return sensor_msgs::CameraInfoConstPtr();
  };
  for (const core::FrameSeen& frame : frames) {
    if (frame.epoch == before) continue;
    const auto left = at(recent_left_, frame.stamp), right = at(recent_right_, frame.stamp);
    if (left && right && carriesCalibration(*left, committed.left) && carriesCalibration(*right, committed.right))
      return frame.epoch;
  }
  return std::nullopt;
}

bool CalibrationInForce::stillInForce(const UncommittedCalibration& u) const {
  return left_ && right_ && carriesCalibration(*left_, u.left_in_force) && carriesCalibration(*right_, u.right_in_force);
}

}  // namespace embedded_calibration_stereo
