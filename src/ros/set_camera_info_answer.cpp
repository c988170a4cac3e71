#include "embedded_calibration_stereo/ros/set_camera_info_answer.h"

namespace embedded_calibration_stereo {

std::string stagedAnswer(const std::string& reason) { return std::string(kStagedAnswerPrefix) + " " + reason; }

bool isStagedAnswer(const std::string& status_message) {
  return status_message.compare(0, sizeof(kStagedAnswerPrefix) - 1, kStagedAnswerPrefix) == 0;
}

bool isStagedAnswer(const sensor_msgs::SetCameraInfo::Response& response) {
  return response.success && isStagedAnswer(response.status_message);
}

}  // namespace embedded_calibration_stereo
