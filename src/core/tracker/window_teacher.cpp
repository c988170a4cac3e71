#include "embedded_calibration_stereo/core/tracker/window_teacher.h"

#include <opencv2/imgproc.hpp>

#include <stdexcept>

namespace embedded_calibration_stereo::core {

TeachFrame teachFrameFromDevice(const cv::Mat& device) {
  if (device.empty() || device.depth() != CV_32F || (device.channels() != 1 && device.channels() != 3))
    throw std::invalid_argument("a device image must be CV_32FC1 or CV_32FC3");
  cv::Mat grey = device;
  if (device.channels() == 3) cv::cvtColor(device, grey, cv::COLOR_BGR2GRAY);
  TeachFrame frame;
  grey.convertTo(frame.light_on, CV_8U);  // saturating: negative values become 0
  return frame;
}

TeachResult teachCameraFromWindow(const WindowFrames& frames, const BoardLayout& layout,
                                  const std::string& camera_name, const DeviceLearnerOptions& learner,
                                  cv::Mat* taught_on) {
  const LearnedDevice learned = learnWindowDevice(frames, learner);
  const TeachFrame frame = teachFrameFromDevice(learned.device_template.device);
  if (taught_on) *taught_on = frame.light_on;
  TeachResult result = teachCamera({frame}, layout, camera_name);
  result.notes.push_back(camera_name + ": taught on the device image learned from " + std::to_string(learned.pairs) +
                         " light pairs of one burst");
  return result;
}

}  // namespace embedded_calibration_stereo::core
