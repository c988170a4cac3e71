#pragma once
// The census_sgm matcher's inner loops (sgm_kernel.inl), built once per instruction set as the
// sad matcher's are (sad_kernel.h says why the interface is plain data): sgm_kernel_baseline.cpp
// with the build's universal intrinsics and, on x86-64, sgm_kernel_avx2.cpp with 256-bit ones
// and sgm_kernel_avx512.cpp with 512-bit ones.
#include <cstddef>
#include <cstdint>

namespace embedded_calibration_stereo::core {
namespace sgm_kernel {

// The census of one image: kPlanes byte planes per row, bit i of a pixel's census in plane
// i / 8, bit i % 8.
constexpr int kCensusRadiusX = 2;  // 5x5 window: 24 comparisons with the centre
constexpr int kCensusRadiusY = 2;
constexpr int kPlanes = 3;

struct Problem {
  int width, height;
  int ndisp;         // disparities searched: min_disp .. min_disp + ndisp - 1
  int ndisp_padded;  // ndisp rounded up to Kernel::lanes times a power of two; the
                     // disparities past ndisp never win
  int min_disp;
  // Left census: plane k of row y at census_left + y * left_step + k * width.
  const uint8_t* census_left;
  size_t left_step;
  // Right census, mirrored: plane k of row y at census_right + y * right_step + k * right_len;
  // entry q holds right column xr = width - 1 + right_off - q (the edge columns repeated past
  // the image), so that the disparities of one left pixel lie at consecutive entries.
  const uint8_t* census_right;
  size_t right_step;
  int right_len, right_off;
  int paths;                  // 5 (one pass down the image) or 8 (down, then up)
  int P1, P2;                 // smoothness penalties, in census bits
  int edge_scale;             // P2 / (1 + |dI| / edge_scale) across an intensity step dI; 0 = off
  const uint8_t* image;       // the left image (P2's intensity steps)
  size_t image_step;
  double uniqueness_ratio;    // percent; <= 0 disables the test
  bool left_right_check;
  int left_right_tolerance;   // pixels
  bool subpixel;
  // Optional output (nullptr: none): 255 where the left-right check found the pixel hidden from
  // the right camera, 0 elsewhere.
  uint8_t* occluded;
  size_t occluded_step;
};

// The rows one call works on: disparity rows y0..y1-1 to out + y * out_step (elements; CV_16S,
// 1/16 px, invalid = (min_disp - 1) * 16). The paths from above start at row y_start <= y0 and,
// with eight paths, those from below at row y_end - 1 >= y1 - 1, so that bands agree at their
// seams whatever the number of threads.
struct Band {
  int y_start, y0, y1, y_end;
  int16_t* out;
  size_t out_step;
};

struct Kernel {
  const char* name;  // "baseline", "avx2", "avx512"
  int lanes;         // bytes per vector: ndisp_padded must be lanes times 1, 2, 4, ..., 32
  // One row of census planes (kPlanes x width bytes, plane k at out + k * width) from an image
  // padded by kCensusRadiusY rows and kCensusRadiusX columns on every side (row y of the image
  // is padded row y + kCensusRadiusY); a bit is set where the neighbour is brighter than the
  // centre by more than `threshold` (0..255) grey levels.
  void (*census_row)(const uint8_t* padded, size_t step, int width, int y, int threshold,
                     uint8_t* out);
  // Bytes of scratch memory match_band needs for a band of band_rows output rows.
  size_t (*scratch_bytes)(const Problem& p, int band_rows);
  void (*match_band)(const Problem& p, const Band& band, uint8_t* scratch);
};

const Kernel& baselineKernel();
const Kernel& avx2Kernel();    // defined only when built with ECS_SGM_AVX2
const Kernel& avx512Kernel();  // defined only when built with ECS_SGM_AVX512

}  // namespace sgm_kernel
}  // namespace embedded_calibration_stereo::core
