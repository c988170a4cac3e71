#include "embedded_calibration_stereo/core/depth/sad_matcher.h"

#include <algorithm>
#include <cstdint>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "kernel_choice.h"
#include "sad_kernel.h"
#include "parallel_pieces.h"

namespace embedded_calibration_stereo::core {
namespace {

// One row of the prefilter: the 3x3 x-Sobel response of `row` (neighbours `above` and `below`,
// borders replicated) clipped to +-cap and shifted to 0..2*cap, as cv::Sobel(CV_16S, dx = 1,
// BORDER_REPLICATE) + clipping + convertTo give (StereoBM's XSOBEL prefilter: insensitive to the
// brightness offset between the cameras). Written to out[x], or to out[width - 1 - x] when
// `mirrored`. colsum: width + 2 work elements.
void prefilterRow(const uint8_t* above, const uint8_t* row, const uint8_t* below, int width, int cap,
                  bool mirrored, int16_t* colsum, uint8_t* out) {
  int16_t* s = colsum + 1;  // vertical [1 2 1] sums; s[-1] and s[width] replicate the ends
  int x = 0;
#if CV_SIMD128
  for (; x + 16 <= width; x += 16) {
    cv::v_uint16x8 a0, a1, b0, b1, c0, c1;
    cv::v_expand(cv::v_load(above + x), a0, a1);
    cv::v_expand(cv::v_load(row + x), b0, b1);
    cv::v_expand(cv::v_load(below + x), c0, c1);
    cv::v_store(s + x, cv::v_reinterpret_as_s16(a0 + (b0 << 1) + c0));
    cv::v_store(s + x + 8, cv::v_reinterpret_as_s16(a1 + (b1 << 1) + c1));
  }
#endif
  for (; x < width; ++x) s[x] = static_cast<int16_t>(above[x] + 2 * row[x] + below[x]);
  s[-1] = s[0];
  s[width] = s[width - 1];
  x = 0;
#if CV_SIMD128
  const cv::v_int16x8 lo = cv::v_setall_s16(static_cast<int16_t>(-cap));
  const cv::v_int16x8 hi = cv::v_setall_s16(static_cast<int16_t>(cap));
  for (; x + 16 <= width; x += 16) {
    const cv::v_int16x8 d0 = cv::v_load(s + x + 1) - cv::v_load(s + x - 1);
    const cv::v_int16x8 d1 = cv::v_load(s + x + 9) - cv::v_load(s + x + 7);
    const cv::v_uint8x16 v = cv::v_pack_u(cv::v_min(cv::v_max(d0, lo), hi) + hi, cv::v_min(cv::v_max(d1, lo), hi) + hi);
    if (mirrored)
      cv::v_store(out + width - 16 - x, cv::v_reverse(v));
    else
      cv::v_store(out + x, v);
  }
#endif
  for (; x < width; ++x) {
    const int d = s[x + 1] - s[x - 1];
    out[mirrored ? width - 1 - x : x] = static_cast<uint8_t>((d < -cap ? -cap : (d > cap ? cap : d)) + cap);
  }
}

// The matcher's two inputs in one parallel pass over the rows: the prefiltered left image
// padded by `radius` on every side, and the prefiltered right image padded by `radius` rows and
// by right_pad_left / right_pad_right columns, then mirrored left-right (borders replicated, as
// cv::copyMakeBorder(BORDER_REPLICATE) of the prefiltered image would give).
void prefilterAndPad(const cv::Mat& left, const cv::Mat& right, int cap, int radius, int right_pad_left,
                     int right_pad_right, cv::Mat* left_padded, cv::Mat* right_rev) {
  const int W = left.cols, H = left.rows, padded_rows = H + 2 * radius;
  left_padded->create(padded_rows, W + 2 * radius, CV_8U);
  right_rev->create(padded_rows, W + right_pad_left + right_pad_right, CV_8U);
  cv::parallel_for_(cv::Range(0, 2 * padded_rows), [&](const cv::Range& range) {
    thread_local std::vector<int16_t> colsum;
    colsum.resize(W + 2);
    for (int i = range.start; i < range.end; ++i) {
      const bool is_left = i < padded_rows;
      const cv::Mat& image = is_left ? left : right;
      const int py = is_left ? i : i - padded_rows;
      const int y = std::clamp(py - radius, 0, H - 1);  // padding rows repeat the edge rows
      const uint8_t* row = image.ptr<uint8_t>(y);
      const uint8_t* above = image.ptr<uint8_t>(std::max(y - 1, 0));
      const uint8_t* below = image.ptr<uint8_t>(std::min(y + 1, H - 1));
      if (is_left) {
        uint8_t* dst = left_padded->ptr<uint8_t>(py);
        prefilterRow(above, row, below, W, cap, false, colsum.data(), dst + radius);
        std::fill(dst, dst + radius, dst[radius]);
        std::fill(dst + radius + W, dst + 2 * radius + W, dst[radius + W - 1]);
      } else {
        uint8_t* dst = right_rev->ptr<uint8_t>(py);
        uint8_t* mirrored = dst + right_pad_right;  // the row's last pixel first
        prefilterRow(above, row, below, W, cap, true, colsum.data(), mirrored);
        std::fill(dst, mirrored, mirrored[0]);
        std::fill(mirrored + W, mirrored + W + right_pad_left, mirrored[W - 1]);
      }
    }
  });
}

// The padded images, kept per thread between calls: fresh pages for them would cost page faults
// on every frame, a visible share of the pipeline's time.
struct Workspace {
  cv::Mat left_padded, right_rev;
};
Workspace& threadWorkspace() {
  thread_local Workspace workspace;
  return workspace;
}

#ifdef ECS_SAD_AVX2
const sad_kernel::Kernel& (*const kAvx2Kernel)() = sad_kernel::avx2Kernel;
#else
const sad_kernel::Kernel& (*const kAvx2Kernel)() = nullptr;
#endif

// Scratch memory of the calling thread, kept between frames: fresh pages would cost page faults
// on every frame.
std::vector<int16_t>& threadScratch(size_t elements) {
  thread_local std::vector<int16_t> scratch;
  if (scratch.size() < elements) scratch.resize(elements);
  return scratch;
}

}  // namespace

namespace {
KernelSet<sad_kernel::Kernel> sadKernels() { return {sad_kernel::baselineKernel(), kAvx2Kernel, nullptr}; }
}  // namespace

std::vector<std::string> sadKernelNames() { return kernelNames(sadKernels()); }

cv::Mat computeSadDisparity16(const cv::Mat& left, const cv::Mat& right,
                              const SadMatcherParams& params) {
  cv::Mat out;
  computeSadDisparity16(left, right, params, &out);
  return out;
}

void computeSadDisparity16(const cv::Mat& left, const cv::Mat& right, const SadMatcherParams& params,
                           cv::Mat* disparity) {
  if (left.empty() || left.type() != CV_8UC1 || right.type() != CV_8UC1)
    throw std::invalid_argument("sad matcher: images must be non-empty mono8 (CV_8UC1)");
  if (left.size() != right.size())
    throw std::invalid_argument("sad matcher: left and right sizes differ");
  if (params.window_size < 3 || params.window_size > 15 || params.window_size % 2 == 0)
    throw std::invalid_argument("sad matcher: window_size must be odd in 3..15, got " +
                                std::to_string(params.window_size));
  if (params.num_disparities < 16 || params.num_disparities % 16 != 0)
    throw std::invalid_argument("sad matcher: num_disparities must be a positive multiple of 16");
  if (params.prefilter_cap < 1 || params.prefilter_cap > 63)
    throw std::invalid_argument("sad matcher: prefilter_cap must be in 1..63");
  const sad_kernel::Kernel& kernel =
      kernelNamed("sad", params.kernel, sadKernels());

  sad_kernel::Problem p;
  p.width = left.cols;
  p.height = left.rows;
  p.ndisp = params.num_disparities;
  p.min_disp = params.min_disparity;
  p.radius = params.window_size / 2;
  p.padded_width = p.width + 2 * p.radius;
  p.right_pad_left = std::max(0, p.radius + p.min_disp + p.ndisp - 1);
  const int right_pad_right = std::max(0, p.radius - p.min_disp);
  p.right_width = p.width + p.right_pad_left + right_pad_right;
  p.uniqueness_ratio = params.uniqueness_ratio;
  p.left_right_check = params.left_right_check;
  p.left_right_tolerance = params.left_right_tolerance;
  p.subpixel = params.subpixel;
  Workspace& w = threadWorkspace();
  prefilterAndPad(left, right, params.prefilter_cap, p.radius, p.right_pad_left, right_pad_right, &w.left_padded,
                  &w.right_rev);
  p.left = w.left_padded.ptr<uint8_t>();
  p.left_step = w.left_padded.step;
  p.right_rev = w.right_rev.ptr<uint8_t>();
  p.right_step = w.right_rev.step;

  disparity->create(left.size(), CV_16SC1);
  cv::Mat& out = *disparity;
  const size_t scratch_elements = kernel.scratch_elements(p);
  // Each band re-reads 2r rows to start its sums.
  const int bands = parallelPieces(p.height, 16);
  cv::parallel_for_(cv::Range(0, bands), [&](const cv::Range& range) {
    int16_t* scratch = threadScratch(scratch_elements).data();
    for (int b = range.start; b < range.end; ++b) {
      const int y0 = p.height * b / bands, y1 = p.height * (b + 1) / bands;
      kernel.match_band(p, y0, y1, out.ptr<int16_t>(), out.step1(), scratch);
    }
  }, bands);
}

}  // namespace embedded_calibration_stereo::core
