#include "mip_texture.h"

#include <algorithm>
#include <cmath>
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

float MipTexture::bilinear(int k, float x, float y) const {
  x = std::min(std::max(x * scale_[k], 0.0f), max_x_[k]);
  y = std::min(std::max(y * scale_[k], 0.0f), max_y_[k]);
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const float fx = x - x0, fy = y - y0;
  const float* r0 = data_.data() + offset_[k] + y0 * stride_[k] + x0;
  const float* r1 = r0 + stride_[k];
  return (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
}

float MipTexture::sample(float x, float y, float footprint) const {
  if (!(footprint > 1.0f)) return bilinear(0, x, y);
  const float level = std::min(std::log2(footprint), static_cast<float>(levels_ - 1));
  const int l0 = static_cast<int>(level);
  const int l1 = std::min(l0 + 1, levels_ - 1);
  const float w = level - l0;
  const float v0 = bilinear(l0, x, y);
  return w > 0.0f ? (1 - w) * v0 + w * bilinear(l1, x, y) : v0;
}


}  // namespace sim
}  // namespace ecs
