#pragma once
// The sad matcher's inner loop over a band of rows (sad_kernel.inl), built once per instruction
// set: sad_kernel_baseline.cpp with the build's universal intrinsics (SSE2 on x86-64, NEON on ARM,
// scalar elsewhere) and, on x86-64, sad_kernel_avx2.cpp with 256-bit ones. The interface is plain
// data: the AVX2 object must share no inline function or template instance with the rest of the
// program, or the linker could hand AVX2 code to a caller on a CPU without it.
#include <cstddef>
#include <cstdint>

namespace embedded_calibration_stereo::core {
namespace sad_kernel {

struct Problem {
  int width, height, ndisp, min_disp, radius;
  int padded_width;    // width + 2 * radius (left image columns of the window)
  int right_width;     // columns of the padded, mirrored right image
  int right_pad_left;  // columns of replicated border left of the right image
  const uint8_t* left;       // prefiltered, padded by radius on every side
  size_t left_step;          // bytes per row
  const uint8_t* right_rev;  // prefiltered, padded, then mirrored left-right
  size_t right_step;
  double uniqueness_ratio;   // percent; <= 0 disables the test
  bool left_right_check;
  int left_right_tolerance;  // pixels
  bool subpixel;
};

struct Kernel {
  const char* name;  // "baseline", "avx2"
  // int16 elements of scratch memory one band needs.
  size_t (*scratch_elements)(const Problem& p);
  // Rows y0..y1-1 of the CV_16S disparity (1/16 px; invalid = (min_disp - 1) * 16) into
  // out + y * out_step (elements); scratch: scratch_elements(p) int16 of the caller's memory.
  void (*match_band)(const Problem& p, int y0, int y1, int16_t* out, size_t out_step,
                     int16_t* scratch);
};

const Kernel& baselineKernel();
const Kernel& avx2Kernel();  // defined only when built with ECS_SAD_AVX2

}  // namespace sad_kernel
}  // namespace embedded_calibration_stereo::core
