// The scene renderer's row kernels, written once with OpenCV's width-agnostic universal
// intrinsics (cv::v_float32 and vx_*: 4 lanes with SSE2/NEON, 8 with AVX2) and included by one
// .cpp per instruction set, which defines SCENE_KERNEL_GETTER and SCENE_KERNEL_NAME first.
// Everything but the getter has internal linkage, and nothing here calls a std:: template or
// inline library function (the C library's sqrtf and log2f are real functions): see
// scene_kernel.h for why.
#include <math.h>
#include <opencv2/core/hal/intrin.hpp>

#include "scene_kernel.h"

#if !defined(SCENE_KERNEL_GETTER) || !defined(SCENE_KERNEL_NAME)
#error "define SCENE_KERNEL_GETTER and SCENE_KERNEL_NAME before including scene_kernel.inl"
#endif

namespace embedded_calibration_stereo::core {
namespace sim {
namespace scene_kernel {
namespace {

constexpr float kMinT = 1e-6f;  // hits closer than this along the ray are not hits
// Planes of a scene meet edge to edge (a wall and the floor): a ray on the seam must hit one of
// them whatever the rounding, so each rectangle reaches this far (metres) past its edges; where
// two overlap, the nearer hit wins as anywhere else.
constexpr float kSeam = 1e-5f;
const float kInfinity = __builtin_inff();

float minf(float a, float b) { return a < b ? a : b; }
float maxf(float a, float b) { return a > b ? a : b; }

// --- One pixel -------------------------------------------------------------------------

float bilinear(const Texture& tex, int k, float x, float y) {
  x = minf(maxf(x * tex.scale[k], 0.0f), tex.max_x[k]);
  y = minf(maxf(y * tex.scale[k], 0.0f), tex.max_y[k]);
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const float fx = x - x0, fy = y - y0;
  const unsigned short* r0 = tex.data + tex.offset[k] + y0 * tex.stride[k] + x0;
  const unsigned short* r1 = r0 + tex.stride[k];
  return ((1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1])) * (1.0f / kTexelScale);
}

// Trilinear: the two levels around log2(footprint); level 0 alone when the footprint is not
// above one texel (or not a number).
float trilinear(const Texture& tex, float x, float y, float footprint) {
  if (!(footprint > 1.0f)) return bilinear(tex, 0, x, y);
  const float level = minf(log2f(footprint), static_cast<float>(tex.levels - 1));
  const int l0 = static_cast<int>(level);
  const int l1 = l0 + 1 < tex.levels ? l0 + 1 : tex.levels - 1;
  const float w = level - l0;
  const float v0 = bilinear(tex, l0, x, y);
  return w > 0.0f ? (1 - w) * v0 + w * bilinear(tex, l1, x, y) : v0;
}

// Footprint of one pixel on its plane, in metres: the larger of the plane displacements of the
// hit t m when the ray m = (x, y, 1) moves to the next column (dmx) and to the next row (dmy):
// dP = t (dm - m (n.dm) / (n.m)), measured along the plane's u and v axes.
float footprint(const Plane& pc, float t, float x, float y, float dmx0, float dmx1, float dmy0, float dmy1) {
  const float nm = pc.n[0] * x + pc.n[1] * y + pc.n[2];
  float extent2[2];
  const float d[2][2] = {{dmx0, dmx1}, {dmy0, dmy1}};
  for (int i = 0; i < 2; ++i) {
    const float k = (pc.n[0] * d[i][0] + pc.n[1] * d[i][1]) / nm;
    const float p0 = t * (d[i][0] - x * k), p1 = t * (d[i][1] - y * k), p2 = -t * k;
    const float da = pc.u[0] * p0 + pc.u[1] * p1 + pc.u[2] * p2;
    const float db = pc.v[0] * p0 + pc.v[1] * p1 + pc.v[2] * p2;
    extent2[i] = da * da + db * db;
  }
  return sqrtf(maxf(extent2[0], extent2[1]));
}

void shadePixel(const Plane* planes, const RowRays& rays, const RowHits& hits, const DepthLine& line, int col,
                float* out, float* depth) {
  const int p = hits.plane[col];
  if (p < 0) {
    out[col] = 0.0f;
    if (depth) depth[col] = kInfinity;
    return;
  }
  const Plane& pc = planes[p];
  const float* x = rays.x;
  const float* y = rays.y;
  const int next = col + 1 < rays.width ? col + 1 : col - 1;
  const float sign = col + 1 < rays.width ? 1.0f : -1.0f;
  const float f = footprint(pc, hits.t[col], x[col], y[col], sign * (x[next] - x[col]), sign * (y[next] - y[col]),
                            rays.next_sign * (rays.next_x[col] - x[col]),
                            rays.next_sign * (rays.next_y[col] - y[col]));
  out[col] = trilinear(pc.texture, hits.a[col] * pc.inv_texel_u - pc.texel_offset,
                       hits.b[col] * pc.inv_texel_v - pc.texel_offset, f * pc.footprint_scale);
  if (depth) depth[col] = line.z_centre + hits.t[col] * (line.r[0] * x[col] + line.r[1] * y[col] + line.r[2]);
}

void castScalar(const Plane& pc, int index, const RowRays& rays, int col, const RowHits& hits) {
  const float x = rays.x[col], y = rays.y[col];
  const float t = pc.numerator / (pc.n[0] * x + pc.n[1] * y + pc.n[2]);
  const float a = pc.a0 + t * (pc.u[0] * x + pc.u[1] * y + pc.u[2]);
  const float b = pc.b0 + t * (pc.v[0] * x + pc.v[1] * y + pc.v[2]);
  if (t > kMinT && t < hits.t[col] && a >= -kSeam && a <= pc.width + kSeam && b >= -kSeam && b <= pc.height + kSeam) {
    hits.t[col] = t;
    hits.a[col] = a;
    hits.b[col] = b;
    hits.plane[col] = index;
  }
}

#if CV_SIMD
// --- A vector of pixels ----------------------------------------------------------------
using VFloat = cv::v_float32;
using VInt = cv::v_int32;
constexpr int kLanes = VFloat::nlanes;

VFloat splat(float v) { return cv::vx_setall_f32(v); }

// log2 of positive finite floats to about 3e-5: exponent plus a least-squares quartic of the
// mantissa (the level of detail needs a few digits, not libm's).
VFloat fastLog2(const VFloat& v) {
  const VInt bits = cv::v_reinterpret_as_s32(v);
  const VFloat exponent = cv::v_cvt_f32((bits >> 23) - cv::vx_setall_s32(127));
  const VFloat m =
      cv::v_reinterpret_as_f32((bits & cv::vx_setall_s32(0x007fffff)) | cv::vx_setall_s32(0x3f800000)) - splat(1.0f);
  VFloat p = splat(0.04588553f);
  p = cv::v_fma(p, m, splat(-0.19442267f));
  p = cv::v_fma(p, m, splat(0.41542195f));
  p = cv::v_fma(p, m, splat(-0.7086821f));
  p = cv::v_fma(p, m, splat(1.4418258f));
  return cv::v_fma(p, m, exponent);
}

int pairAt(const Texture& tex, int index) {
  int pair;
  __builtin_memcpy(&pair, tex.data + index, 4);
  return pair;
}

// The texel pairs (i, i + 1) at index[lane], as floats (in texel units).
void loadPairs(const Texture& tex, const int* index, VFloat* left, VFloat* right) {
  // Plain 32-bit loads inserted into a register (cheaper than gathers on the CPUs measured, and
  // than a store and reload, which defeats store forwarding).
#if CV_SIMD_WIDTH == 32
  const VInt both(pairAt(tex, index[0]), pairAt(tex, index[1]), pairAt(tex, index[2]), pairAt(tex, index[3]),
                  pairAt(tex, index[4]), pairAt(tex, index[5]), pairAt(tex, index[6]), pairAt(tex, index[7]));
#elif CV_SIMD_WIDTH == 16
  const VInt both(pairAt(tex, index[0]), pairAt(tex, index[1]), pairAt(tex, index[2]), pairAt(tex, index[3]));
#else
  alignas(64) int pairs[kLanes];
  for (int lane = 0; lane < kLanes; ++lane) pairs[lane] = pairAt(tex, index[lane]);
  const VInt both = cv::vx_load_aligned(pairs);
#endif
  *left = cv::v_cvt_f32(both & cv::vx_setall_s32(0xffff));  // little-endian: texel i is the low half
  *right = cv::v_cvt_f32(cv::v_reinterpret_as_s32(cv::v_reinterpret_as_u32(both) >> 16));
}

// Bilinear samples at level coordinates (xs, ys), already clamped, on levels given by their
// first texel and row stride per lane, in texel units. Each texel row of a neighbourhood is one
// 32-bit pair.
VFloat bilinearAt(const Texture& tex, const VInt& offset, const VInt& stride, const VFloat& xs, const VFloat& ys) {
  const VInt x0 = cv::v_trunc(xs), y0 = cv::v_trunc(ys);
  const VFloat fx = xs - cv::v_cvt_f32(x0), fy = ys - cv::v_cvt_f32(y0);
  alignas(32) int top[kLanes], bottom[kLanes];
  const VInt first = offset + y0 * stride + x0;
  cv::v_store_aligned(top, first);
  cv::v_store_aligned(bottom, first + stride);
  VFloat v00, v01, v10, v11;
  loadPairs(tex, top, &v00, &v01);
  loadPairs(tex, bottom, &v10, &v11);
  const VFloat upper = cv::v_fma(fx, v01 - v00, v00), lower = cv::v_fma(fx, v11 - v10, v10);
  return cv::v_fma(fy, lower - upper, upper);
}

// Level k for every lane.
VFloat bilinearLevel(const Texture& tex, int k, const VFloat& x, const VFloat& y) {
  const VFloat zero = cv::vx_setzero_f32(), s = splat(tex.scale[k]);
  // v_max first: a NaN coordinate (a lane of another plane) becomes 0, inside the texture.
  return bilinearAt(tex, cv::vx_setall_s32(tex.offset[k]), cv::vx_setall_s32(tex.stride[k]),
                    cv::v_min(cv::v_max(x * s, zero), splat(tex.max_x[k])),
                    cv::v_min(cv::v_max(y * s, zero), splat(tex.max_y[k])));
}

// Level l per lane.
VFloat bilinearLevels(const Texture& tex, const VInt& l, const VFloat& x, const VFloat& y) {
  const VFloat zero = cv::vx_setzero_f32(), s = cv::v_lut(tex.scale, l);
  return bilinearAt(tex, cv::v_lut(tex.offset, l), cv::v_lut(tex.stride, l),
                    cv::v_min(cv::v_max(x * s, zero), cv::v_lut(tex.max_x, l)),
                    cv::v_min(cv::v_max(y * s, zero), cv::v_lut(tex.max_y, l)));
}

// trilinear() for every lane, in texel units, given log2 of the footprints (<= 0 or NaN: level 0).
VFloat trilinearV(const Texture& tex, const VFloat& x, const VFloat& y, const VFloat& log2_footprint) {
  const VFloat zero = cv::vx_setzero_f32();
  const VFloat level =
      cv::v_min(cv::v_select(log2_footprint > zero, log2_footprint, zero), splat(static_cast<float>(tex.levels - 1)));
  const VInt l0 = cv::v_trunc(level);
  const VFloat w = level - cv::v_cvt_f32(l0);
  const int k = cv::v_extract_n<0>(l0);
  if (cv::v_check_all(l0 == cv::vx_setall_s32(k))) {  // one level for every lane (most vectors)
    const VFloat v0 = bilinearLevel(tex, k, x, y);
    if (k + 1 >= tex.levels || !cv::v_check_any(w > zero)) return v0;
    return cv::v_fma(w, bilinearLevel(tex, k + 1, x, y) - v0, v0);
  }
  const VInt l1 = cv::v_min(l0 + cv::vx_setall_s32(1), cv::vx_setall_s32(tex.levels - 1));
  const VFloat v0 = bilinearLevels(tex, l0, x, y);
  return cv::v_fma(w, bilinearLevels(tex, l1, x, y) - v0, v0);
}

// The radiance of pixels [col, col + kLanes) as if they all hit plane pc (none in the last
// column): footprint() and trilinear() for every lane.
VFloat shadeAs(const Plane& pc, const RowRays& rays, const RowHits& hits, int col) {
  const VFloat x = cv::vx_load(rays.x + col), y = cv::vx_load(rays.y + col), t = cv::vx_load(hits.t + col);
  const VFloat n0 = splat(pc.n[0]), n1 = splat(pc.n[1]);
  const VFloat inv_nm = splat(1.0f) / cv::v_fma(n0, x, cv::v_fma(n1, y, splat(pc.n[2])));
  const auto extent2 = [&](const VFloat& d0, const VFloat& d1) {
    const VFloat k = cv::v_fma(n0, d0, n1 * d1) * inv_nm;
    const VFloat p0 = t * (d0 - x * k), p1 = t * (d1 - y * k), p2 = cv::vx_setzero_f32() - t * k;
    const VFloat da = cv::v_fma(splat(pc.u[0]), p0, cv::v_fma(splat(pc.u[1]), p1, splat(pc.u[2]) * p2));
    const VFloat db = cv::v_fma(splat(pc.v[0]), p0, cv::v_fma(splat(pc.v[1]), p1, splat(pc.v[2]) * p2));
    return cv::v_fma(da, da, db * db);
  };
  const VFloat sign = splat(rays.next_sign);
  const VFloat across = extent2(cv::vx_load(rays.x + col + 1) - x, cv::vx_load(rays.y + col + 1) - y);
  const VFloat down = extent2(sign * (cv::vx_load(rays.next_x + col) - x), sign * (cv::vx_load(rays.next_y + col) - y));
  const VFloat footprint2 = cv::v_max(across, down) * splat(pc.footprint_scale * pc.footprint_scale);
  const VFloat log2_footprint =
      cv::v_select(footprint2 > splat(1.0f), fastLog2(footprint2) * splat(0.5f), cv::vx_setzero_f32());
  const VFloat offset = splat(pc.texel_offset);
  return trilinearV(pc.texture, cv::vx_load(hits.a + col) * splat(pc.inv_texel_u) - offset,
                    cv::vx_load(hits.b + col) * splat(pc.inv_texel_v) - offset, log2_footprint) *
         splat(1.0f / kTexelScale);
}

// Pixels [col, col + kLanes): shaded once per plane among them (usually one, two at a plane's
// edge), each lane keeping its own plane's value.
void shadeVector(const Plane* planes, const RowRays& rays, const RowHits& hits, const DepthLine& line, int col,
                 float* out, float* depth) {
  const VInt plane = cv::vx_load(hits.plane + col);
  const VInt none = cv::vx_setall_s32(-1);
  alignas(32) int lane_plane[kLanes];
  cv::v_store_aligned(lane_plane, plane);
  VFloat value = cv::vx_setzero_f32();
  VInt done = plane == none;  // misses stay 0
  for (int lane = 0; lane < kLanes; ++lane) {
    const int p = lane_plane[lane];
    if (p < 0 || (lane > 0 && cv::v_check_all(done))) continue;
    const VInt mine = plane == cv::vx_setall_s32(p);
    if (!cv::v_check_any(mine & ~done)) continue;  // shaded with an earlier lane of the same plane
    value = cv::v_select(cv::v_reinterpret_as_f32(mine), shadeAs(planes[p], rays, hits, col), value);
    done = done | mine;
  }
  cv::v_store(out + col, value);
  if (!depth) return;
  const VFloat x = cv::vx_load(rays.x + col), y = cv::vx_load(rays.y + col);
  const VFloat along = cv::v_fma(splat(line.r[0]), x, cv::v_fma(splat(line.r[1]), y, splat(line.r[2])));
  const VFloat z = cv::v_fma(cv::vx_load(hits.t + col), along, splat(line.z_centre));
  cv::v_store(depth + col, cv::v_select(cv::v_reinterpret_as_f32(plane == none), splat(kInfinity), z));
}
#endif

void shadeRow(const Plane* planes, const RowRays& rays, const RowHits& hits, const DepthLine& line, float* out,
              float* depth) {
  int col = 0;
#if CV_SIMD
  for (; col + kLanes < rays.width; col += kLanes) shadeVector(planes, rays, hits, line, col, out, depth);
#endif
  for (; col < rays.width; ++col) shadePixel(planes, rays, hits, line, col, out, depth);
}

void castRow(const Plane& pc, int index, const RowRays& rays, int begin, int end, const RowHits& hits) {
  int col = begin;
#if CV_SIMD
  const VFloat n0 = splat(pc.n[0]), n1 = splat(pc.n[1]), n2 = splat(pc.n[2]);
  const VFloat u0 = splat(pc.u[0]), u1 = splat(pc.u[1]), u2 = splat(pc.u[2]);
  const VFloat v0 = splat(pc.v[0]), v1 = splat(pc.v[1]), v2 = splat(pc.v[2]);
  const VFloat numerator = splat(pc.numerator), a0 = splat(pc.a0), b0 = splat(pc.b0);
  const VFloat width = splat(pc.width + kSeam), height = splat(pc.height + kSeam), min_t = splat(kMinT);
  const VFloat seam = splat(kSeam), zero = cv::vx_setzero_f32();
  const VInt index_v = cv::vx_setall_s32(index);
  for (; col + kLanes <= end; col += kLanes) {
    const VFloat x = cv::vx_load(rays.x + col), y = cv::vx_load(rays.y + col);
    const VFloat t = numerator / cv::v_fma(n0, x, cv::v_fma(n1, y, n2));
    const VFloat a = cv::v_fma(t, cv::v_fma(u0, x, cv::v_fma(u1, y, u2)), a0);
    const VFloat b = cv::v_fma(t, cv::v_fma(v0, x, cv::v_fma(v1, y, v2)), b0);
    const VFloat previous = cv::vx_load(hits.t + col);
    // Comparisons with NaN are false, so a ray parallel to the plane (t = inf or NaN) never
    // hits; with t finite, a and b are finite and the min-of-margins test is exact.
    const VFloat inside = cv::v_min(cv::v_min(a + seam, width - a), cv::v_min(b + seam, height - b)) >= zero;
    const VFloat hit = (t > min_t) & (t < previous) & inside;
    cv::v_store(hits.t + col, cv::v_select(hit, t, previous));
    cv::v_store(hits.a + col, cv::v_select(hit, a, cv::vx_load(hits.a + col)));
    cv::v_store(hits.b + col, cv::v_select(hit, b, cv::vx_load(hits.b + col)));
    cv::v_store(hits.plane + col, cv::v_select(cv::v_reinterpret_as_s32(hit), index_v, cv::vx_load(hits.plane + col)));
  }
#endif
  for (; col < end; ++col) castScalar(pc, index, rays, col, hits);
}

}  // namespace

const Kernel& SCENE_KERNEL_GETTER() {
  static const Kernel kernel{SCENE_KERNEL_NAME, castRow, shadeRow};
  return kernel;
}

}  // namespace scene_kernel
}  // namespace sim
}  // namespace embedded_calibration_stereo::core
