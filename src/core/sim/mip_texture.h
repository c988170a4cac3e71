#pragma once
// A texture's mip pyramid in one contiguous buffer, sampled trilinearly by one pixel or by four
// at once. One buffer lets a 4-lane sample address any level by a 32-bit index, so the four
// lanes of a group may sit at different levels (a floor seen at a grazing angle changes level
// every few pixels).
//
// Level 0 has texel (i, j) at texture coordinates (i, j); level k+1 is level k low-passed and
// halved (cv::pyrDown), so texture coordinate x is x / 2^k on level k.
//
// Threading: immutable after construction; sampling is safe from any thread.
#include <opencv2/core.hpp>
#include <opencv2/core/hal/intrin.hpp>
#include <vector>

namespace ecs {
namespace sim {

class MipTexture {
 public:
  static constexpr int kMaxLevels = 8;

  MipTexture() = default;
  // Builds levels from `level0` (CV_32F) until kMaxLevels or a side below 4 texels.
  explicit MipTexture(const cv::Mat& level0);

  int levels() const { return levels_; }
  // A view of one level (no copy).
  cv::Mat level(int k) const;

  // Value at level-0 coordinates (x, y) for a pixel footprint of `footprint` level-0 texels:
  // blends the two levels around log2(footprint); level 0 alone when the footprint is not
  // above one texel (magnification) or not a number.
  float sample(float x, float y, float footprint) const;

#if CV_SIMD128
  // The same for four pixels, given log2 of their footprints (any value; <= 0 or NaN means
  // level 0). Lanes may use different levels.
  inline cv::v_float32x4 sample4(const cv::v_float32x4& x, const cv::v_float32x4& y,
                                 const cv::v_float32x4& log2_footprint) const;
#endif

 private:
  float bilinear(int level, float x, float y) const;
#if CV_SIMD128
  // Bilinear samples of four pixels on the levels l (per lane).
  inline cv::v_float32x4 bilinear4(const cv::v_int32x4& l, const cv::v_float32x4& x, const cv::v_float32x4& y) const;
  // The same when every lane is on level k.
  inline cv::v_float32x4 bilinear4(int k, const cv::v_float32x4& x, const cv::v_float32x4& y) const;
  inline cv::v_float32x4 bilinear4(const cv::v_int32x4& offset, const cv::v_int32x4& stride,
                                   const cv::v_float32x4& xs, const cv::v_float32x4& ys) const;
#endif

  std::vector<float> data_;
  int levels_ = 0;
  // Per level: first element in data_, row stride, the largest coordinates that keep a 2x2
  // neighbourhood inside the level, and the scale from level-0 coordinates.
  int offset_[kMaxLevels] = {}, stride_[kMaxLevels] = {};
  float max_x_[kMaxLevels] = {}, max_y_[kMaxLevels] = {}, scale_[kMaxLevels] = {};
};


#if CV_SIMD128

// log2 of positive finite floats to about 3e-5, 4 at a time (exponent plus a polynomial of the
// mantissa): the level of detail needs a few digits, not libm's.
inline cv::v_float32x4 fastLog2(const cv::v_float32x4& v) {
  const cv::v_int32x4 bits = cv::v_reinterpret_as_s32(v);
  const cv::v_float32x4 exponent = cv::v_cvt_f32((bits >> 23) - cv::v_setall_s32(127));
  // Mantissa m in [1, 2); log2(m) = (m - 1) * p(m - 1), p a least-squares quartic.
  const cv::v_float32x4 m =
      cv::v_reinterpret_as_f32((bits & cv::v_setall_s32(0x007fffff)) | cv::v_setall_s32(0x3f800000)) -
      cv::v_setall_f32(1.0f);
  cv::v_float32x4 p = cv::v_setall_f32(0.04588553f);
  p = cv::v_fma(p, m, cv::v_setall_f32(-0.19442267f));
  p = cv::v_fma(p, m, cv::v_setall_f32(0.41542195f));
  p = cv::v_fma(p, m, cv::v_setall_f32(-0.7086821f));
  p = cv::v_fma(p, m, cv::v_setall_f32(1.4418258f));
  return cv::v_fma(p, m, exponent);
}

inline cv::v_float32x4 MipTexture::bilinear4(const cv::v_int32x4& offset, const cv::v_int32x4& stride,
                                             const cv::v_float32x4& xs, const cv::v_float32x4& ys) const {
  const cv::v_int32x4 x0 = cv::v_trunc(xs), y0 = cv::v_trunc(ys);
  const cv::v_float32x4 fx = xs - cv::v_cvt_f32(x0), fy = ys - cv::v_cvt_f32(y0);
  // Each texel row of a bilinear neighbourhood is one 64-bit pair: lanes 0-1 and 2-3 are
  // fetched as pairs, then two zips deinterleave them into the left and right texels.
  alignas(16) int top_index[4], bottom_index[4];
  cv::v_store_aligned(top_index, offset + y0 * stride + x0);
  cv::v_store_aligned(bottom_index, cv::v_load_aligned(top_index) + stride);
  const auto row_pair = [this](const int* index, cv::v_float32x4* left, cv::v_float32x4* right) {
    cv::v_float32x4 z0, z1;
    cv::v_zip(cv::v_lut_pairs(data_.data(), index), cv::v_lut_pairs(data_.data(), index + 2), z0, z1);
    cv::v_zip(z0, z1, *left, *right);
  };
  cv::v_float32x4 v00, v01, v10, v11;
  row_pair(top_index, &v00, &v01);
  row_pair(bottom_index, &v10, &v11);
  const cv::v_float32x4 top = cv::v_fma(fx, v01 - v00, v00), bottom = cv::v_fma(fx, v11 - v10, v10);
  return cv::v_fma(fy, bottom - top, top);
}

inline cv::v_float32x4 MipTexture::bilinear4(int k, const cv::v_float32x4& x, const cv::v_float32x4& y) const {
  const cv::v_float32x4 zero = cv::v_setzero_f32(), s = cv::v_setall_f32(scale_[k]);
  return bilinear4(cv::v_setall_s32(offset_[k]), cv::v_setall_s32(stride_[k]),
                   cv::v_min(cv::v_max(x * s, zero), cv::v_setall_f32(max_x_[k])),
                   cv::v_min(cv::v_max(y * s, zero), cv::v_setall_f32(max_y_[k])));
}

inline cv::v_float32x4 MipTexture::bilinear4(const cv::v_int32x4& l, const cv::v_float32x4& x,
                                             const cv::v_float32x4& y) const {
  const cv::v_float32x4 zero = cv::v_setzero_f32(), s = cv::v_lut(scale_, l);
  return bilinear4(cv::v_lut(offset_, l), cv::v_lut(stride_, l),
                   cv::v_min(cv::v_max(x * s, zero), cv::v_lut(max_x_, l)),
                   cv::v_min(cv::v_max(y * s, zero), cv::v_lut(max_y_, l)));
}

inline cv::v_float32x4 MipTexture::sample4(const cv::v_float32x4& x, const cv::v_float32x4& y,
                                           const cv::v_float32x4& log2_footprint) const {
  const cv::v_float32x4 zero = cv::v_setzero_f32();
  // Not above one texel, or NaN (comparisons with NaN are false): level 0.
  cv::v_float32x4 level = cv::v_select(log2_footprint > zero, log2_footprint, zero);
  level = cv::v_min(level, cv::v_setall_f32(static_cast<float>(levels_ - 1)));
  const cv::v_int32x4 l0 = cv::v_trunc(level);
  const cv::v_float32x4 w = level - cv::v_cvt_f32(l0);
  const int k = cv::v_extract_n<0>(l0);
  if (cv::v_check_all(l0 == cv::v_setall_s32(k))) {  // one level for all four (most groups)
    const cv::v_float32x4 v0 = bilinear4(k, x, y);
    if (k + 1 >= levels_ || !cv::v_check_any(w > zero)) return v0;
    return cv::v_fma(w, bilinear4(k + 1, x, y) - v0, v0);
  }
  const cv::v_int32x4 l1 = cv::v_min(l0 + cv::v_setall_s32(1), cv::v_setall_s32(levels_ - 1));
  const cv::v_float32x4 v0 = bilinear4(l0, x, y);
  return cv::v_fma(w, bilinear4(l1, x, y) - v0, v0);
}

#endif

}  // namespace sim
}  // namespace ecs
