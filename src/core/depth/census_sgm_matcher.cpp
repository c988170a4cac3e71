#include "embedded_calibration_stereo/core/depth/census_sgm_matcher.h"

#include <algorithm>
#include <cstdint>
#include <opencv2/core/hal/intrin.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "kernel_choice.h"
#include "reusable_buffers.h"
#include "sgm_kernel.h"

namespace core = embedded_calibration_stereo::core;

static_assert(2 * core::sgm_kernel::kCensusRadiusX + 1 == core::kCensusSgmWindow &&
                  2 * core::sgm_kernel::kCensusRadiusY + 1 == core::kCensusSgmWindow,
              "the kernel's census window is the one the header states");

namespace embedded_calibration_stereo::core {
namespace {

// Rows of a band, and rows above it over which its paths from above are started: they are
// fixed, not cut by the number of threads, so that every thread count gives the same result.
constexpr int kBandRows = 120;
constexpr int kWarmUpRows = 16;

#ifdef ECS_SGM_AVX2
const sgm_kernel::Kernel& (*const kAvx2Kernel)() = sgm_kernel::avx2Kernel;
#else
const sgm_kernel::Kernel& (*const kAvx2Kernel)() = nullptr;
#endif
#ifdef ECS_SGM_AVX512
const sgm_kernel::Kernel& (*const kAvx512Kernel)() = sgm_kernel::avx512Kernel;
#else
const sgm_kernel::Kernel& (*const kAvx512Kernel)() = nullptr;
#endif

KernelSet<sgm_kernel::Kernel> sgmKernels() {
  return {sgm_kernel::baselineKernel(), kAvx2Kernel, kAvx512Kernel};
}

// Census planes of both images and the images' padded copies (one per call under way), and the
// bands' scratch memory (one per band under way), reused between calls.
struct Workspace {
  cv::Mat padded_left, padded_right;
  cv::Mat census_left, census_right;  // right: mirrored, see sgm_kernel::Problem
};
ReusableBuffers<Workspace>& workspaces() {
  static ReusableBuffers<Workspace> pool;
  return pool;
}
ReusableBuffers<std::vector<uint8_t>>& bandScratch() {
  static ReusableBuffers<std::vector<uint8_t>> pool;
  return pool;
}

// out[q] = in[W - 1 + off - q] for q in [0, len), the ends repeated past the row's ends.
void mirrorRow(const uint8_t* in, int W, int off, int len, uint8_t* out) {
  uint8_t* row = out + off;  // row[i] = in[W - 1 - i]
  int i = 0;
  for (; i + cv::v_uint8x16::nlanes <= W; i += cv::v_uint8x16::nlanes)
    cv::v_store(row + i, cv::v_reverse(cv::v_load(in + W - i - cv::v_uint8x16::nlanes)));
  for (; i < W; ++i) row[i] = in[W - 1 - i];
  std::fill(out, row, in[W - 1]);
  std::fill(row + W, out + len, in[0]);
}

// Census planes of both images, the right one mirrored with its edge columns repeated so that
// every disparity of every left pixel has an entry (right_off and right_len of the Problem).
void censusBoth(const cv::Mat& left, const cv::Mat& right, const sgm_kernel::Kernel& kernel,
                int threshold, sgm_kernel::Problem* p, Workspace* w) {
  using namespace sgm_kernel;
  const int W = left.cols, H = left.rows;
  cv::copyMakeBorder(left, w->padded_left, kCensusRadiusY, kCensusRadiusY, kCensusRadiusX,
                     kCensusRadiusX, cv::BORDER_REPLICATE);
  cv::copyMakeBorder(right, w->padded_right, kCensusRadiusY, kCensusRadiusY, kCensusRadiusX,
                     kCensusRadiusX, cv::BORDER_REPLICATE);
  // Entry q is column W - 1 + right_off - q: q spans the disparities of every left column.
  p->right_off = std::max(0, -p->min_disp);
  p->right_len = W + p->right_off + std::max(0, p->min_disp + p->ndisp_padded) + 1;
  w->census_left.create(H, kPlanes * W, CV_8U);
  w->census_right.create(H, kPlanes * p->right_len, CV_8U);
  cv::parallel_for_(cv::Range(0, H), [&](const cv::Range& rows) {
    thread_local std::vector<uint8_t> planes;
    planes.resize(static_cast<size_t>(kPlanes) * W);
    for (int y = rows.start; y < rows.end; ++y) {
      kernel.census_row(w->padded_left.ptr<uint8_t>(), w->padded_left.step, W, y, threshold,
                        w->census_left.ptr<uint8_t>(y));
      kernel.census_row(w->padded_right.ptr<uint8_t>(), w->padded_right.step, W, y, threshold,
                        planes.data());
      uint8_t* out = w->census_right.ptr<uint8_t>(y);
      for (int k = 0; k < kPlanes; ++k)
        mirrorRow(planes.data() + static_cast<size_t>(k) * W, W, p->right_off, p->right_len,
                  out + static_cast<size_t>(k) * p->right_len);
    }
  });
  p->census_left = w->census_left.ptr<uint8_t>();
  p->left_step = w->census_left.step;
  p->census_right = w->census_right.ptr<uint8_t>();
  p->right_step = w->census_right.step;
}

}  // namespace

std::string CensusSgmParams::validate() const {
  std::string problems;
  const auto add = [&problems](const std::string& s) { problems += (problems.empty() ? "" : "; ") + s; };
  if (num_disparities < 16 || num_disparities > 512 || num_disparities % 16 != 0)
    add("num_disparities must be a multiple of 16 in 16..512, got " + std::to_string(num_disparities));
  if (paths != 5 && paths != 8) add("paths must be 5 or 8, got " + std::to_string(paths));
  if (P1 < 0 || P1 > 63) add("P1 must be in 0..63 census bits, got " + std::to_string(P1));
  if (P2 <= P1 || P2 > 200)
    add("P2 must be above P1 and at most 200 census bits, got " + std::to_string(P2));
  if (!(uniqueness_ratio >= 0 && uniqueness_ratio <= 100)) add("uniqueness_ratio must be in 0..100");
  if (left_right_tolerance < 0) add("left_right_tolerance must be >= 0");
  if (census_threshold < 0 || census_threshold > 255)
    add("census_threshold must be in 0..255, got " + std::to_string(census_threshold));
  return problems;
}

std::vector<std::string> censusSgmKernelNames() { return kernelNames(sgmKernels()); }

void computeCensusSgmDisparity16(const cv::Mat& left, const cv::Mat& right,
                                 const CensusSgmParams& params, cv::Mat* disparity,
                                 cv::Mat* occluded) {
  if (left.empty() || left.type() != CV_8UC1 || right.type() != CV_8UC1)
    throw std::invalid_argument("census_sgm matcher: images must be non-empty mono8 (CV_8UC1)");
  if (left.size() != right.size())
    throw std::invalid_argument("census_sgm matcher: left and right sizes differ");
  const std::string problem = params.validate();
  if (!problem.empty()) throw std::invalid_argument("census_sgm matcher: " + problem);
  const sgm_kernel::Kernel& kernel =
      kernelNamed("census_sgm", params.kernel, sgmKernels());

  sgm_kernel::Problem p;
  p.width = left.cols;
  p.height = left.rows;
  p.ndisp = params.num_disparities;
  p.ndisp_padded = kernel.lanes;
  while (p.ndisp_padded < p.ndisp) p.ndisp_padded *= 2;
  p.min_disp = params.min_disparity;
  p.paths = params.paths;
  p.P1 = params.P1;
  p.P2 = params.P2;
  p.edge_scale = params.edge_scale;
  p.image = left.ptr<uint8_t>();
  p.image_step = left.step;
  p.uniqueness_ratio = params.uniqueness_ratio;
  p.left_right_check = params.left_right_check;
  p.left_right_tolerance = params.left_right_tolerance;
  p.subpixel = params.subpixel;
  const ReusableBuffers<Workspace>::Lease workspace = workspaces().take();
  Workspace& w = *workspace;
  censusBoth(left, right, kernel, params.census_threshold, &p, &w);

  disparity->create(left.size(), CV_16SC1);
  p.occluded = nullptr;
  p.occluded_step = 0;
  if (occluded) {
    occluded->create(left.size(), CV_8UC1);
    if (!params.left_right_check) occluded->setTo(0);
    p.occluded = params.left_right_check ? occluded->ptr<uint8_t>() : nullptr;
    p.occluded_step = occluded->step;
  }
  cv::Mat& out = *disparity;
  const size_t scratch_bytes = kernel.scratch_bytes(p, kBandRows);
  const int bands = (p.height + kBandRows - 1) / kBandRows;
  cv::parallel_for_(cv::Range(0, bands), [&](const cv::Range& range) {
    const ReusableBuffers<std::vector<uint8_t>>::Lease lease = bandScratch().take();
    if (lease->size() < scratch_bytes) lease->resize(scratch_bytes);
    uint8_t* scratch = lease->data();
    for (int b = range.start; b < range.end; ++b) {
      sgm_kernel::Band band;
      band.y0 = b * kBandRows;
      band.y1 = std::min(p.height, band.y0 + kBandRows);
      band.y_start = std::max(0, band.y0 - kWarmUpRows);
      band.y_end = std::min(p.height, band.y1 + kWarmUpRows);
      band.out = out.ptr<int16_t>();
      band.out_step = out.step1();
      kernel.match_band(p, band, scratch);
    }
  }, bands);
}

}  // namespace embedded_calibration_stereo::core
