#include "embedded_calibration_stereo/ros/frame_source.h"

#include <opencv2/imgproc.hpp>

namespace embedded_calibration_stereo {

cv::Mat convertToEncoding(const cv::Mat& image, const std::string& encoding) {
  cv::Mat converted;
  if (encoding == "mono8" && image.channels() == 3) {
    cv::cvtColor(image, converted, cv::COLOR_BGR2GRAY);
  } else if (encoding == "bgr8" && image.channels() == 1) {
    cv::cvtColor(image, converted, cv::COLOR_GRAY2BGR);
  } else {
    converted = image;
  }
  return converted;
}

}  // namespace embedded_calibration_stereo
