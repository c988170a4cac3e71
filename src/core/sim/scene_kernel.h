#pragma once
// The scene renderer's per-row kernels (scene_kernel.inl), built once per instruction set:
// scene_kernel_baseline.cpp with the build's universal intrinsics (SSE2 on x86-64, NEON on ARM,
// scalar elsewhere) and, on x86-64, scene_kernel_avx2.cpp with 256-bit ones and FMA. As for the
// sad kernel (sad_kernel.h), the interface is plain data: the AVX2 object shares no inline
// function or template instance with the rest of the program.
//
// Both kernels give the same images to float rounding (test_sim_textures compares them).
namespace embedded_calibration_stereo::core {
namespace sim {
namespace scene_kernel {

// A mip pyramid in one buffer (MipTexture::view()): level k's texel (i, j) at
// data[offset[k] + j * stride[k] + i], in grey levels times kTexelScale; level-0 coordinates
// scale by scale[k] = 2^-k; a 2x2 neighbourhood stays inside level k for coordinates in
// [0, max_x[k]] x [0, max_y[k]].
constexpr float kTexelScale = 256.0f;  // 16-bit texels: grey levels in [0, 256) to 1/512
struct Texture {
  const unsigned short* data;
  int levels;
  const int *offset, *stride;
  const float *max_x, *max_y, *scale;
};

// A plane as linear forms of the camera ray m = (x, y, 1): t = numerator / (n.m) is the ray
// parameter of the hit, (a, b) = (a0 + t u.m, b0 + t v.m) its plane coordinates in metres,
// inside when 0 <= a <= width and 0 <= b <= height. The texture maps (a, b) to texel
// coordinates (a inv_texel_u - texel_offset, b inv_texel_v - texel_offset).
struct Plane {
  float n[3], u[3], v[3];
  float numerator, a0, b0, width, height;
  Texture texture;
  float inv_texel_u, inv_texel_v, texel_offset;
  float footprint_scale;  // texels per metre along the finer texture axis
};

// One image row's rays and those of its neighbour row (below; above for the last row).
struct RowRays {
  const float *x, *y, *next_x, *next_y;
  float next_sign;  // +1 when next is the row below
  int width;
};

// The nearest hits along a row (plane -1: none), updated plane by plane.
struct RowHits {
  float *t, *a, *b;
  int* plane;
};

// z of a hit C + t R m in the depth frame: z_centre + t (r.m).
struct DepthLine {
  float z_centre, r[3];
};

struct Kernel {
  const char* name;  // "baseline", "avx2"
  // Nearest-hit update of columns [begin, end) of a row against plane `index`.
  void (*cast)(const Plane& plane, int index, const RowRays& rays, int begin, int end, const RowHits& hits);
  // Radiance of every pixel of the row from its nearest hit (0 where none) and, when depth is
  // not null, the hit's z (+inf where none). Texture lookups are trilinear between the mip
  // levels around log2 of the pixel's footprint on its plane.
  void (*shade)(const Plane* planes, const RowRays& rays, const RowHits& hits, const DepthLine& line, float* out,
                float* depth);
};

const Kernel& baselineKernel();
const Kernel& avx2Kernel();  // defined only when built with ECS_SIM_AVX2
// The widest kernel this CPU runs.
const Kernel& bestKernel();

}  // namespace scene_kernel
}  // namespace sim
}  // namespace embedded_calibration_stereo::core
