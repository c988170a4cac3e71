#include "embedded_calibration_stereo/ros/stereo_input_check.h"

#include <ros/time.h>

#include <algorithm>

namespace embedded_calibration_stereo {

namespace {

std::string sizeText(uint32_t width, uint32_t height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

bool allZero(const double* values, size_t n) {
  return std::all_of(values, values + n, [](double v) { return v == 0.0; });
}

}  // namespace

std::string checkImagePair(const sensor_msgs::Image& left, const std::string& left_topic,
                           const sensor_msgs::Image& right, const std::string& right_topic,
                           const std::vector<std::string>& accepted) {
  std::string list;
  for (const auto& e : accepted) list += (list.empty() ? "" : ", ") + e;
  for (const auto* side : {&left, &right}) {
    if (std::find(accepted.begin(), accepted.end(), side->encoding) == accepted.end())
      return (side == &left ? left_topic : right_topic) + ": unsupported encoding '" + side->encoding +
             "' (accepted: " + list + ")";
  }
  if (left.encoding != right.encoding)
    return right_topic + ": encoding '" + right.encoding + "' differs from " + left_topic + "'s '" +
           left.encoding + "'";
  if (left.width != right.width || left.height != right.height)
    return right_topic + ": size " + sizeText(right.width, right.height) + " differs from " + left_topic +
           "'s " + sizeText(left.width, left.height);
  if (left.width == 0 || left.height == 0) return left_topic + ": empty image";
  return "";
}

std::string checkCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& info_topic,
                            const sensor_msgs::Image& image) {
  if (allZero(info.K.data(), info.K.size())) return info_topic + ": uncalibrated camera (K is all zero)";
  if (allZero(info.P.data(), info.P.size())) return info_topic + ": uncalibrated camera (P is all zero)";
  if (!(info.K[0] > 0 && info.K[4] > 0 && info.P[0] > 0 && info.P[5] > 0))
    return info_topic + ": non-positive focal length in K or P";
  if (info.width != image.width || info.height != image.height)
    return info_topic + ": size " + sizeText(info.width, info.height) + " differs from the image's " +
           sizeText(image.width, image.height);
  return "";
}

std::string checkSameFrame(const sensor_msgs::CameraInfo& left, const std::string& left_topic,
                           const sensor_msgs::CameraInfo& right, const std::string& right_topic) {
  if (left.header.frame_id == right.header.frame_id) return "";
  return right_topic + ": frame id '" + right.header.frame_id + "' differs from " + left_topic + "'s '" +
         left.header.frame_id + "' (stereo_image_proc convention: one frame id, see right_in_left_frame)";
}

bool ErrorThrottle::shouldReport(const std::string& message) {
  const double now = ros::WallTime::now().toSec();
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = last_report_s_.find(message);
  if (it != last_report_s_.end() && now - it->second < period_s_) return false;
  last_report_s_[message] = now;
  if (last_report_s_.size() > 256) last_report_s_.clear();  // bounded: messages may carry sizes
  return true;
}

}  // namespace embedded_calibration_stereo
