#pragma once
// Checks of the stereo inputs shared by the Rectifier and Disparity nodelets: every function
// returns an empty string when the input is usable, otherwise "<topic>: <problem>", so that the
// nodelet can log it (see ErrorThrottle) and skip the frame instead of crashing.
// All functions are pure and thread-safe; ErrorThrottle is thread-safe.
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace embedded_calibration_stereo {

// Both images have an encoding of `accepted`, the same encoding and the same size.
std::string checkImagePair(const sensor_msgs::Image& left, const std::string& left_topic,
                           const sensor_msgs::Image& right, const std::string& right_topic,
                           const std::vector<std::string>& accepted);

// The CameraInfo is calibrated (K and P not all zero, positive focal lengths) and has the
// image's size.
std::string checkCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& info_topic,
                            const sensor_msgs::Image& image);

// The two CameraInfos share one frame id (image_geometry::StereoCameraModel asserts it).
std::string checkSameFrame(const sensor_msgs::CameraInfo& left, const std::string& left_topic,
                           const sensor_msgs::CameraInfo& right, const std::string& right_topic);

// Throttles error reports per message text: a new problem is reported at once even while
// another one repeats (one NODELET_ERROR_THROTTLE call site would hide it).
class ErrorThrottle {
 public:
  explicit ErrorThrottle(double period_s) : period_s_(period_s) {}
  // True when `message` was not reported within the last period (wall time).
  bool shouldReport(const std::string& message);

 private:
  const double period_s_;
  std::mutex mutex_;
  std::map<std::string, double> last_report_s_;
};

}  // namespace embedded_calibration_stereo
