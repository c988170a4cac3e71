#include "embedded_calibration_stereo/core/sad_matcher.h"

#include <algorithm>
#include <cstdint>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "sad_kernel.h"

namespace ecs {
namespace {

// x-Sobel response clipped to +-cap and shifted to 0..2*cap (StereoBM's XSOBEL prefilter):
// insensitive to the brightness offset between the cameras. dx: work buffer.
void prefilterXSobel(const cv::Mat& img, int cap, cv::Mat* dx, cv::Mat* out) {
  cv::Sobel(img, *dx, CV_16S, 1, 0, 3, 1, 0, cv::BORDER_REPLICATE);
  cv::max(*dx, -cap, *dx);
  cv::min(*dx, cap, *dx);
  dx->convertTo(*out, CV_8U, 1.0, cap);
}

// The images of one call, kept per thread between calls: fresh pages for a few megabytes of
// temporaries cost page faults on every frame (they measured ~10 % of the whole pipeline's time).
struct Workspace {
  cv::Mat dx, left_filtered, right_filtered, left_padded, right_padded, right_rev;
};
Workspace& threadWorkspace() {
  thread_local Workspace workspace;
  return workspace;
}

bool cpuHasAvx2() {
#ifdef ECS_SAD_AVX2
  return cv::checkHardwareSupport(CV_CPU_AVX2);
#else
  return false;
#endif
}

const sad_kernel::Kernel& kernelNamed(const std::string& name) {
  if (name == "baseline") return sad_kernel::baselineKernel();
#ifdef ECS_SAD_AVX2
  if (name == "avx2" && cpuHasAvx2()) return sad_kernel::avx2Kernel();
#endif
  if (name == "auto") return cpuHasAvx2() ? kernelNamed("avx2") : sad_kernel::baselineKernel();
  throw std::invalid_argument("sad matcher: kernel '" + name + "' is not available here (" +
                              [] {
                                std::string names;
                                for (const auto& n : sadKernelNames()) names += (names.empty() ? "" : ", ") + n;
                                return names;
                              }() + ", auto)");
}

// Scratch memory of the calling thread, kept between frames: fresh pages would cost page faults
// on every frame.
std::vector<int16_t>& threadScratch(size_t elements) {
  thread_local std::vector<int16_t> scratch;
  if (scratch.size() < elements) scratch.resize(elements);
  return scratch;
}

}  // namespace

std::vector<std::string> sadKernelNames() {
  std::vector<std::string> names{"baseline"};
  if (cpuHasAvx2()) names.push_back("avx2");
  return names;
}

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
  const sad_kernel::Kernel& kernel = kernelNamed(params.kernel);

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
  const int r = p.radius;
  Workspace& w = threadWorkspace();
  prefilterXSobel(left, params.prefilter_cap, &w.dx, &w.left_filtered);
  prefilterXSobel(right, params.prefilter_cap, &w.dx, &w.right_filtered);
  cv::copyMakeBorder(w.left_filtered, w.left_padded, r, r, r, r, cv::BORDER_REPLICATE);
  cv::copyMakeBorder(w.right_filtered, w.right_padded, r, r, p.right_pad_left, right_pad_right,
                     cv::BORDER_REPLICATE);
  cv::flip(w.right_padded, w.right_rev, 1);
  p.left = w.left_padded.ptr<uint8_t>();
  p.left_step = w.left_padded.step;
  p.right_rev = w.right_rev.ptr<uint8_t>();
  p.right_step = w.right_rev.step;

  disparity->create(left.size(), CV_16SC1);
  cv::Mat& out = *disparity;
  const size_t scratch_elements = kernel.scratch_elements(p);
  // A few bands per thread balance the load; each band re-reads 2r rows to start its sums.
  const int bands = std::max(1, std::min(p.height / 16, cv::getNumThreads() * 2));
  cv::parallel_for_(cv::Range(0, bands), [&](const cv::Range& range) {
    int16_t* scratch = threadScratch(scratch_elements).data();
    for (int b = range.start; b < range.end; ++b) {
      const int y0 = p.height * b / bands, y1 = p.height * (b + 1) / bands;
      kernel.match_band(p, y0, y1, out.ptr<int16_t>(), out.step1(), scratch);
    }
  }, bands);
}

}  // namespace ecs
