#pragma once
// Portable float map (PFM) files as Middlebury uses them for disparities: header "Pf" (gray) or
// "PF" (RGB), "width height", then a scale whose sign gives the byte order (negative = little
// endian), then the rows from bottom to top as 32-bit floats.
#include <opencv2/core.hpp>
#include <string>

namespace embedded_calibration_stereo::core {

// Writes a CV_32FC1 or CV_32FC3 image, little endian. Non-finite values (NaN = invalid
// disparity) are written as +inf, Middlebury's "unknown". Throws std::runtime_error on I/O
// failure and std::invalid_argument on a wrong type.
void writePfm(const std::string& path, const cv::Mat& image);

// Reads a PFM file of either byte order into CV_32FC1 / CV_32FC3 (top row first). Throws
// std::runtime_error with the reason when the file is missing or malformed.
cv::Mat readPfm(const std::string& path);

}  // namespace embedded_calibration_stereo::core
