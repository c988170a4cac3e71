#pragma once
// A texture's mip pyramid in one contiguous buffer, so that a vector of pixels can address any
// level by a 32-bit index: the lanes of a vector may sit at different levels (a floor seen at a
// grazing angle changes level every few pixels). The scene kernels sample it through view().
//
// Level 0 has texel (i, j) at texture coordinates (i, j); level k+1 is level k low-passed and
// halved (cv::pyrDown, in float), so texture coordinate x is x / 2^k on level k. Texels are
// stored as 16-bit fixed point (scene_kernel::kTexelScale): half the memory traffic of floats.
//
// Threading: immutable after construction; views are safe to read from any thread.
#include <opencv2/core.hpp>
#include <vector>

#include "scene_kernel.h"

namespace embedded_calibration_stereo::core {
namespace sim {

class MipTexture {
 public:
  static constexpr int kMaxLevels = 8;

  MipTexture() = default;
  // Builds levels from `level0` (CV_32F, grey levels in [0, 256)) until kMaxLevels or a side
  // below 4 texels.
  explicit MipTexture(const cv::Mat& level0);

  int levels() const { return levels_; }
  // The pyramid as the scene kernels read it; valid while this object lives unchanged.
  scene_kernel::Texture view() const {
    return {data_.data(), levels_, offset_, stride_, max_x_, max_y_, scale_};
  }

 private:
  std::vector<unsigned short> data_;
  int levels_ = 0;
  // Per level: first element in data_, row stride, the largest coordinates that keep a 2x2
  // neighbourhood inside the level, and the scale from level-0 coordinates.
  int offset_[kMaxLevels] = {}, stride_[kMaxLevels] = {};
  float max_x_[kMaxLevels] = {}, max_y_[kMaxLevels] = {}, scale_[kMaxLevels] = {};
};

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
