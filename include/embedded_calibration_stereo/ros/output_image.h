#pragma once
// A new image message with the header and layout of another image, and a cv::Mat viewing its
// buffer: an OpenCV function writes its result straight into the message, which is then
// published as is (no copy before publishing, never modified after).
#include <opencv2/core.hpp>
#include <sensor_msgs/Image.h>

namespace embedded_calibration_stereo {

struct OutputImage {
  sensor_msgs::ImagePtr msg;
  cv::Mat view;  // msg's buffer, same rows, cols and OpenCV type as the encoding says
};

// Same header, encoding and size as `like`; a dense buffer. Throws cv_bridge::Exception for an
// encoding cv_bridge does not know.
OutputImage newImageLike(const sensor_msgs::Image& like);

}  // namespace embedded_calibration_stereo
