#include "mip_texture.h"

#include <algorithm>
#include <opencv2/imgproc.hpp>

namespace ecs {
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
  for (int k = 0; k < levels_; ++k) {
    offset_[k] = static_cast<int>(offset);
    stride_[k] = sizes[k].width;
    max_x_[k] = sizes[k].width - 1.001f;
    max_y_[k] = sizes[k].height - 1.001f;
    scale_[k] = 1.0f / static_cast<float>(1 << k);
    cv::Mat view(sizes[k], CV_32F, data_.data() + offset);
    if (k == 0)
      level0.copyTo(view);
    else
      cv::pyrDown(level(k - 1), view, sizes[k]);  // writes into the buffer: the size matches
    offset += static_cast<size_t>(sizes[k].area());
  }
}

cv::Mat MipTexture::level(int k) const {
  const int rows = (k + 1 < levels_ ? offset_[k + 1] - offset_[k] : static_cast<int>(data_.size()) - offset_[k]) /
                   stride_[k];
  return cv::Mat(rows, stride_[k], CV_32F, const_cast<float*>(data_.data()) + offset_[k]);
}

}  // namespace sim
}  // namespace ecs
