#pragma once
// Helpers of the depth rostests: stereo frames matched by stamp, and crafted inputs.
#include <image_geometry/stereo_camera_model.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <stereo_msgs/DisparityImage.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace embedded_calibration_stereo::test_support {

// Median of a non-empty vector (copied).
inline double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// The message of `msgs` with stamp `stamp`, or null.
template <class Ptr>
Ptr findByStamp(const std::vector<Ptr>& msgs, const ros::Time& stamp) {
  for (const auto& m : msgs)
    if (m->header.stamp == stamp) return m;
  return Ptr();
}

// Valid disparities of a DisparityImage (stereo_image_proc convention: invalid < min_disparity).
inline std::vector<double> validDisparities(const stereo_msgs::DisparityImage& msg) {
  std::vector<double> out;
  const float* d = reinterpret_cast<const float*>(msg.image.data.data());
  for (size_t i = 0; i < size_t(msg.image.width) * msg.image.height; ++i)
    if (std::isfinite(d[i]) && d[i] >= msg.min_disparity) out.push_back(d[i]);
  return out;
}

}  // namespace embedded_calibration_stereo::test_support
