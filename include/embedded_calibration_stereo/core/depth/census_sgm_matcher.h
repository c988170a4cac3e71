#pragma once
// The head's default matcher ("census_sgm"): semi-global matching (Hirschmueller, 2008) of
// census costs, vectorised across the disparities (docs/depth.md: design and measurements).
//
// Cost: the Hamming distance between the census codes of a 5x5 window (24 bits: is each
// neighbour brighter than the centre by more than census_threshold?), insensitive to the
// brightness and contrast differences between the cameras; the threshold keeps sensor noise in
// flat regions from flipping bits. Aggregation along eight paths (the four axes' and diagonals' both ways),
// or five (none from below: one pass over the image, faster, less exact): P1 for a step of one
// disparity, P2 for larger ones, P2 lowered across intensity steps where depth edges are likely.
// Then winner-take-all, a uniqueness test (no disparity other than the winner and its
// neighbours within uniqueness_ratio % of it), an equiangular sub-pixel offset and a left-right
// check against the right image's winners taken from the same sums; pixels whose match falls
// outside the right image (or within 2 columns of its edge, where the census sees repeated
// border columns) or whose right pixel sees something nearer are marked occluded.
//
// Rows are processed in bands of fixed height, in parallel; each band's paths start some rows
// outside it. The bands do not depend on the number of threads, so neither do the results;
// every kernel (instruction set) gives the same results too.
//
// Threading: computeCensusSgmDisparity16 is reentrant; its only state is scratch memory kept
// between calls in pools guarded by a mutex (as many buffers as were in use at once).
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace embedded_calibration_stereo::core {

constexpr int kCensusSgmWindow = 5;  // the census's window, pixels (square)

struct CensusSgmParams {
  int min_disparity = 0;
  int num_disparities = 64;      // multiple of 16, up to 512
  int census_threshold = 1;      // grey levels (0..255)
  int paths = 8;                 // 8, or 5 (no paths from below: one pass, faster)
  int P1 = 6;                    // penalty of a one-disparity step, census bits (0..63)
  int P2 = 48;                   // penalty of a larger step, census bits (P1 < P2 <= 200)
  int edge_scale = 16;           // P2 / (1 + |dI| / edge_scale) across intensity steps; 0 = off
  double uniqueness_ratio = 0;   // percent; 0 disables
  bool left_right_check = true;
  int left_right_tolerance = 1;  // pixels
  bool subpixel = true;
  std::string kernel = "auto";   // "auto" (the widest this CPU runs), or one of censusSgmKernelNames()

  // Empty when usable; otherwise the problems, joined by "; ".
  std::string validate() const;
};

// The kernels this build and CPU can run: "baseline" always, "avx2" on x86-64 CPUs with AVX2,
// "avx512" on those with AVX-512 F, BW, VL, DQ, CD, VBMI and BITALG (Ice Lake, Zen 4 and later).
std::vector<std::string> censusSgmKernelNames();

// left, right: rectified CV_8UC1 of one size. Writes CV_16SC1 disparity scaled by 16
// (cv::StereoMatcher::DISP_SCALE), invalid pixels = (min_disparity - 1) * 16, the encoding of
// OpenCV's matchers. With `occluded`, also a CV_8UC1 mask: 255 where the left-right check
// found the pixel hidden from the right camera (fill it from the background), 0 elsewhere.
// Throws std::invalid_argument on bad input or parameters.
void computeCensusSgmDisparity16(const cv::Mat& left, const cv::Mat& right,
                                 const CensusSgmParams& params, cv::Mat* disparity,
                                 cv::Mat* occluded = nullptr);

}  // namespace embedded_calibration_stereo::core
