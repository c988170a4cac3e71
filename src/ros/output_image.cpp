#include "embedded_calibration_stereo/ros/output_image.h"

#include <boost/make_shared.hpp>
#include <cv_bridge/cv_bridge.h>

namespace embedded_calibration_stereo {

OutputImage newImageLike(const sensor_msgs::Image& like) {
  const int type = cv_bridge::getCvType(like.encoding);
  OutputImage out;
  out.msg = boost::make_shared<sensor_msgs::Image>();
  out.msg->header = like.header;
  out.msg->encoding = like.encoding;
  out.msg->height = like.height;
  out.msg->width = like.width;
  out.msg->is_bigendian = like.is_bigendian;
  out.msg->step = static_cast<uint32_t>(like.width * CV_ELEM_SIZE(type));
  out.msg->data.resize(static_cast<size_t>(out.msg->step) * out.msg->height);
  out.view = cv::Mat(static_cast<int>(like.height), static_cast<int>(like.width), type,
                     out.msg->data.data(), out.msg->step);
  return out;
}

}  // namespace embedded_calibration_stereo
