#include "mip_texture.h"

#include <algorithm>
#include <opencv2/imgproc.hpp>

namespace embedded_calibration_stereo::core {
namespace sim {

MipTexture::MipTexture(const cv::Mat& level0) {
  CV_Assert(level0.type() == CV_32F && !level0.empty());
  std::vector<cv::Size> sizes{level0.size()};
  while (static_cast<int>(sizes.size()) < kMaxLevels && std::min(sizes.back().width, sizes.back().height) >= 4)
    sizes.push_back(cv::Size((sizes.back().width + 1) / 2, (sizes.back().height + 1) / 2));
  size_t total = 0;
  for (const cv::Size& s : sizes) total += static_cast<size_t>(s.area());
  CV_Assert(total < (1u << 31));
  data_.resize(total);
  levels_ = static_cast<int>(sizes.size());
  size_t offset = 0;
  cv::Mat level = level0;
  for (int k = 0; k < levels_; ++k) {
    offset_[k] = static_cast<int>(offset);
    stride_[k] = sizes[k].width;
    max_x_[k] = sizes[k].width - 1.001f;
    max_y_[k] = sizes[k].height - 1.001f;
    scale_[k] = 1.0f / static_cast<float>(1 << k);
    if (k > 0) {
      cv::Mat smaller;
      cv::pyrDown(level, smaller, sizes[k]);
      level = smaller;
    }
    cv::Mat view(sizes[k], CV_16U, data_.data() + offset);
    level.convertTo(view, CV_16U, scene_kernel::kTexelScale);  // rounds and saturates; writes into the buffer
    offset += static_cast<size_t>(sizes[k].area());
  }
}

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
