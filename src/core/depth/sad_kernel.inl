// The sad matcher's band kernel, written once with OpenCV's width-agnostic universal intrinsics
// (cv::v_int16 and vx_*: 8 lanes with SSE2/NEON, 16 with AVX2) and included by one .cpp per
// instruction set, which defines SAD_KERNEL_GETTER (the function returning its Kernel) and
// SAD_KERNEL_NAME first. Everything but the getter has internal linkage, and nothing here calls
// a std:: template: see sad_kernel.h for why. Every instruction set gives identical results
// (test_sad_kernels checks it).
//
// Per row band: the per-disparity column sums of the window are updated by one entering and one
// leaving row, and the window sums by one entering and one leaving column (running box sums),
// vectorised across the disparities. The sums of kLanes pixels are then transposed so that the
// winner search, the uniqueness test and the right image's winners run across kLanes pixels.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/core/fast_math.hpp>  // cvRound (static inline)

#include "sad_kernel.h"

#if !defined(SAD_KERNEL_GETTER) || !defined(SAD_KERNEL_NAME)
#error "define SAD_KERNEL_GETTER and SAD_KERNEL_NAME before including sad_kernel.inl"
#endif

namespace embedded_calibration_stereo::core {
namespace sad_kernel {
namespace {

constexpr int kDispScale = 16;  // cv::StereoMatcher::DISP_SCALE
constexpr int16_t kMaxCost = 0x7FFF;
#if CV_SIMD
constexpr int kLanes = cv::v_int16::nlanes;  // pixels per block: one int16 vector
#else
constexpr int kLanes = 8;
#endif

int absInt(int v) { return v < 0 ? -v : v; }
int roundUp(int v, int multiple) { return (v + multiple - 1) / multiple * multiple; }

// Index in the mirrored right row of disparity index 0 for padded left column xi; the costs of
// disparity indices 0..ndisp-1 then lie at consecutive addresses.
int rightBase(const Problem& p, int xi) {
  return p.right_width - 1 - p.right_pad_left + p.min_disp - xi + p.radius;
}
// The transposed sums' rows [k][x] hold x in [-sumsPadLeft, Wa + sumsPadRight): the pads cost
// kMaxCost, so that the right-winner search reads any x = xr + min_disp + k (xr in [0, Wa))
// without a bounds check.
int sumsPadLeft(const Problem& p) { return roundUp(p.min_disp < 0 ? -p.min_disp : 0, kLanes); }
int sumsPadRight(const Problem& p) {
  return roundUp(p.min_disp + p.ndisp > 0 ? p.min_disp + p.ndisp : 0, kLanes);
}
int sumsStride(const Problem& p) {
  return sumsPadLeft(p) + roundUp(p.width, kLanes) + sumsPadRight(p);
}

// Views into the caller's scratch memory for one band.
struct Scratch {
  int16_t* col;     // [padded x][k] vertical window sums
  int16_t* sums;    // (kLanes + 1) x D: window sums of the pixel before the block, then the block
  int16_t* sums_t;  // [k][x] window sums of the row, row stride sumsStride (x from -sumsPadLeft)
  int16_t *best, *best_k, *prev, *next, *within;  // [x] per pixel: see blockWinners
  int16_t* right_k;  // [xr] right-image winner
  int16_t* filler;  // D x kMaxCost, the sums of pixels past the image's end
};

// Lays Scratch out from base (nullptr: only counts); returns the int16 elements used.
size_t layOut(const Problem& p, int16_t* base, Scratch* s) {
  const size_t D = static_cast<size_t>(p.ndisp), Wa = static_cast<size_t>(roundUp(p.width, kLanes));
  size_t used = 0;
  auto take = [&](size_t n) {
    int16_t* at = base ? base + used : nullptr;
    used += n;
    return at;
  };
  s->col = take(static_cast<size_t>(p.padded_width) * D);
  s->sums = take((kLanes + 1) * D);
  s->sums_t = take(D * static_cast<size_t>(sumsStride(p)));
  if (s->sums_t) s->sums_t += sumsPadLeft(p);
  s->best = take(Wa);
  s->best_k = take(Wa);
  s->prev = take(Wa);
  s->next = take(Wa);
  s->within = take(Wa);
  s->right_k = take(Wa);
  s->filler = take(D);
  return used;
}

// The rows entering and leaving the window when it moves down one row (leave < 0: start-up,
// add only).
struct RowStep {
  const uint8_t *le, *re, *ll, *rl;
  bool add_only;
};

RowStep rowStep(const Problem& p, int enter_row, int leave_row) {
  RowStep s;
  s.le = p.left + static_cast<size_t>(enter_row) * p.left_step;
  s.re = p.right_rev + static_cast<size_t>(enter_row) * p.right_step;
  s.add_only = leave_row < 0;
  s.ll = s.add_only ? s.le : p.left + static_cast<size_t>(leave_row) * p.left_step;
  s.rl = s.add_only ? s.re : p.right_rev + static_cast<size_t>(leave_row) * p.right_step;
  return s;
}

// col[xi][k] += |L(enter) - R(enter)| - |L(leave) - R(leave)| for every disparity index k.
CV_ALWAYS_INLINE void updateColumn(const Problem& p, const RowStep& s, int xi, int D, int16_t* col) {
  const int base = rightBase(p, xi);
  int16_t* cs = col + static_cast<size_t>(xi) * D;
#if CV_SIMD256
  // 16 lanes: widen the bytes while loading (one instruction), then |a - b| in 16 bits.
  const cv::v_uint16 a_enter = cv::vx_setall_u16(s.le[xi]), a_leave = cv::vx_setall_u16(s.ll[xi]);
  for (int k = 0; k < D; k += kLanes) {
    const cv::v_int16 e = cv::v_reinterpret_as_s16(cv::v_absdiff(a_enter, cv::vx_load_expand(s.re + base + k)));
    if (s.add_only) {
      cv::v_store(cs + k, cv::vx_load(cs + k) + e);
      continue;
    }
    const cv::v_int16 l = cv::v_reinterpret_as_s16(cv::v_absdiff(a_leave, cv::vx_load_expand(s.rl + base + k)));
    cv::v_store(cs + k, cv::vx_load(cs + k) + cv::v_sub_wrap(e, l));
  }
#elif CV_SIMD128
  // 8 lanes: |a - b| on 16 bytes at once, then widened (SSE2 has no widening load).
  const cv::v_uint8x16 a_enter = cv::v_setall_u8(s.le[xi]);
  if (s.add_only) {
    for (int k = 0; k < D; k += 16) {
      cv::v_uint16x8 e0, e1;
      cv::v_expand(cv::v_absdiff(a_enter, cv::v_load(s.re + base + k)), e0, e1);
      cv::v_store(cs + k, cv::v_load(cs + k) + cv::v_reinterpret_as_s16(e0));
      cv::v_store(cs + k + 8, cv::v_load(cs + k + 8) + cv::v_reinterpret_as_s16(e1));
    }
    return;
  }
  const cv::v_uint8x16 a_leave = cv::v_setall_u8(s.ll[xi]);
  for (int k = 0; k < D; k += 16) {
    cv::v_uint16x8 e0, e1, l0, l1;
    cv::v_expand(cv::v_absdiff(a_enter, cv::v_load(s.re + base + k)), e0, e1);
    cv::v_expand(cv::v_absdiff(a_leave, cv::v_load(s.rl + base + k)), l0, l1);
    cv::v_store(cs + k, cv::v_load(cs + k) + cv::v_sub_wrap(cv::v_reinterpret_as_s16(e0),
                                                            cv::v_reinterpret_as_s16(l0)));
    cv::v_store(cs + k + 8, cv::v_load(cs + k + 8) + cv::v_sub_wrap(cv::v_reinterpret_as_s16(e1),
                                                                    cv::v_reinterpret_as_s16(l1)));
  }
#else
  for (int k = 0; k < D; ++k) {
    int v = cs[k] + absInt(s.le[xi] - s.re[base + k]);
    if (!s.add_only) v -= absInt(s.ll[xi] - s.rl[base + k]);
    cs[k] = static_cast<int16_t>(v);
  }
#endif
}

// out[k] = prev[k] + enter[k] - leave[k]: the window sums one pixel to the right.
CV_ALWAYS_INLINE void slideWindow(const int16_t* prev, const int16_t* enter, const int16_t* leave, int D,
                        int16_t* out) {
#if CV_SIMD
  for (int k = 0; k < D; k += kLanes)  // D is a multiple of 16; no sum exceeds int16
    cv::v_store(out + k, (cv::vx_load(prev + k) + cv::vx_load(enter + k)) - cv::vx_load(leave + k));
#else
  for (int k = 0; k < D; ++k) out[k] = static_cast<int16_t>(prev[k] + enter[k] - leave[k]);
#endif
}

// dst[k][j] = rows[j][k] for 8 rows of D sums (j = 0..7); dst rows dst_stride apart.
CV_ALWAYS_INLINE void transpose8(const int16_t* const* rows, int D, int16_t* dst, int dst_stride) {
#if CV_SIMD128
  for (int k0 = 0; k0 < D; k0 += 8) {
    cv::v_int16x8 r[8], t[8];
    for (int j = 0; j < 8; ++j) r[j] = cv::v_load(rows[j] + k0);
    for (int j = 0; j < 8; j += 2) cv::v_zip(r[j], r[j + 1], t[j], t[j + 1]);
    // t[2i] holds columns 0-3 of rows 2i, 2i+1 interleaved; t[2i+1] columns 4-7.
    cv::v_int32x4 u[8];
    cv::v_zip(cv::v_reinterpret_as_s32(t[0]), cv::v_reinterpret_as_s32(t[2]), u[0], u[1]);
    cv::v_zip(cv::v_reinterpret_as_s32(t[1]), cv::v_reinterpret_as_s32(t[3]), u[2], u[3]);
    cv::v_zip(cv::v_reinterpret_as_s32(t[4]), cv::v_reinterpret_as_s32(t[6]), u[4], u[5]);
    cv::v_zip(cv::v_reinterpret_as_s32(t[5]), cv::v_reinterpret_as_s32(t[7]), u[6], u[7]);
    // u[c] (c < 4) holds columns 2c, 2c+1 of rows 0-3; u[4 + c] the same of rows 4-7.
    for (int c = 0; c < 4; ++c) {
      const cv::v_int16x8 lo = cv::v_reinterpret_as_s16(u[c]), hi = cv::v_reinterpret_as_s16(u[4 + c]);
      cv::v_store(dst + static_cast<size_t>(k0 + 2 * c) * dst_stride, cv::v_combine_low(lo, hi));
      cv::v_store(dst + static_cast<size_t>(k0 + 2 * c + 1) * dst_stride, cv::v_combine_high(lo, hi));
    }
  }
#else
  for (int j = 0; j < 8; ++j)
    for (int k = 0; k < D; ++k) dst[static_cast<size_t>(k) * dst_stride + j] = rows[j][k];
#endif
}

// Right winner of every right pixel xr in [0, Wa): the k (lowest on ties, as for the left
// winners) minimising t[k * stride + xr + min_disp + k], the sums of the left pixel that xr
// matches at k. Each vector of right pixels keeps its minimum in registers over all k (two
// vectors at a time, to overlap their dependency chains); stores only its result.
CV_ALWAYS_INLINE void rightWinners(const int16_t* t, int stride, int Wa, int D, int min_disp,
                                   int16_t* right_k) {
  const size_t diagonal = static_cast<size_t>(stride) + 1;  // from (k, x) to (k + 1, x + 1)
#if CV_SIMD
  const cv::v_int16 one = cv::vx_setall_s16(1);
  int xr = 0;
  for (; xr + 2 * kLanes <= Wa; xr += 2 * kLanes) {
    const int16_t* c = t + xr + min_disp;
    cv::v_int16 best0 = cv::vx_setall_s16(kMaxCost), best1 = best0;
    cv::v_int16 k0 = cv::vx_setzero_s16(), k1 = k0, kv = k0;
    for (int k = 0; k < D; ++k, c += diagonal, kv = kv + one) {
      const cv::v_int16 c0 = cv::vx_load(c), c1 = cv::vx_load(c + kLanes);
      k0 = cv::v_max(k0, (c0 < best0) & kv);  // k increases: max() selects it
      best0 = cv::v_min(c0, best0);
      k1 = cv::v_max(k1, (c1 < best1) & kv);
      best1 = cv::v_min(c1, best1);
    }
    cv::v_store(right_k + xr, k0);
    cv::v_store(right_k + xr + kLanes, k1);
  }
  for (; xr < Wa; xr += kLanes) {
    const int16_t* c = t + xr + min_disp;
    cv::v_int16 best = cv::vx_setall_s16(kMaxCost), bk = cv::vx_setzero_s16(), kv = bk;
    for (int k = 0; k < D; ++k, c += diagonal, kv = kv + one) {
      const cv::v_int16 cost = cv::vx_load(c);
      bk = cv::v_max(bk, (cost < best) & kv);
      best = cv::v_min(cost, best);
    }
    cv::v_store(right_k + xr, bk);
  }
#else
  for (int xr = 0; xr < Wa; ++xr) {
    int16_t best = kMaxCost, bk = 0;
    const int16_t* c = t + xr + min_disp;
    for (int k = 0; k < D; ++k, c += diagonal)
      if (*c < best) {
        best = *c;
        bk = static_cast<int16_t>(k);
      }
    right_k[xr] = bk;
  }
#endif
}

// Winners of the kLanes pixels x0.. from their transposed sums t[k * stride + j]: best cost and
// index (lowest on ties), the costs at index - 1 and + 1 (for the parabola) and the number of
// other indices costing at most thresh(best) (the uniqueness test, as StereoBM's: no disparity
// but the winner and its two neighbours may cost within uniqueness_ratio % of it).
CV_ALWAYS_INLINE void blockWinners(const int16_t* t, int stride, int D, double uniqueness_ratio, const Scratch& s,
                  int x0) {
  int16_t* best_k = s.best_k + x0;
  int16_t* best = s.best + x0;
  int16_t* prev = s.prev + x0;
  int16_t* next = s.next + x0;
  int16_t* within = s.within + x0;
#if CV_SIMD
  cv::v_int16 vbest = cv::vx_setall_s16(kMaxCost), vbest_k = cv::vx_setzero_s16();
  cv::v_int16 kv = cv::vx_setzero_s16();
  const cv::v_int16 one = cv::vx_setall_s16(1);
  const int16_t* row = t;
  for (int k = 0; k < D; k += 2, row += 2 * stride) {  // D is a multiple of 16
    const cv::v_int16 c0 = cv::vx_load(row), c1 = cv::vx_load(row + stride);
    vbest_k = cv::v_max(vbest_k, (c0 < vbest) & kv);  // k increases: max() selects it
    vbest = cv::v_min(c0, vbest);
    kv = kv + one;
    vbest_k = cv::v_max(vbest_k, (c1 < vbest) & kv);
    vbest = cv::v_min(c1, vbest);
    kv = kv + one;
  }
  cv::v_store(best, vbest);
  cv::v_store(best_k, vbest_k);
#else
  for (int j = 0; j < kLanes; ++j) {
    best[j] = kMaxCost;
    best_k[j] = 0;
    for (int k = 0; k < D; ++k)
      if (t[k * stride + j] < best[j]) {
        best[j] = t[k * stride + j];
        best_k[j] = static_cast<int16_t>(k);
      }
  }
#endif
  // The neighbours of the winners, gathered from the block (still in L1).
  for (int j = 0; j < kLanes; ++j) {
    const int k = best_k[j];
    prev[j] = k > 0 ? t[static_cast<size_t>(k - 1) * stride + j] : kMaxCost;
    next[j] = k < D - 1 ? t[static_cast<size_t>(k + 1) * stride + j] : kMaxCost;
  }
  if (uniqueness_ratio <= 0) return;
  int16_t thresh[kLanes];
  const float ratio = static_cast<float>(uniqueness_ratio / 100.0);
  for (int j = 0; j < kLanes; ++j) {
    const int limit = best[j] + static_cast<int>(best[j] * ratio);
    thresh[j] = static_cast<int16_t>(limit < kMaxCost - 1 ? limit : kMaxCost - 1);
  }
#if CV_SIMD
  const cv::v_int16 th = cv::vx_load(thresh);
  cv::v_int16 above = cv::vx_setzero_s16();
  // A true comparison is all ones (-1) in the lane: adding it counts down.
  cv::v_int16 above1 = above;
  row = t;
  for (int k = 0; k < D; k += 2, row += 2 * stride) {
    above = cv::v_add_wrap(above, cv::vx_load(row) > th);
    above1 = cv::v_add_wrap(above1, cv::vx_load(row + stride) > th);
  }
  above = cv::v_add_wrap(above, above1);
  cv::v_store(within, cv::vx_setall_s16(static_cast<int16_t>(D)) + above);
#else
  for (int j = 0; j < kLanes; ++j) {
    within[j] = 0;
    for (int k = 0; k < D; ++k) within[j] += t[k * stride + j] <= thresh[j];
  }
#endif
  for (int j = 0; j < kLanes; ++j) {  // the winner and its neighbours do not count against it
    const int k = best_k[j];
    within[j] -= 1 + (k > 0 && prev[j] <= thresh[j]) + (k < D - 1 && next[j] <= thresh[j]);
  }
}

#if CV_SIMD
// round(8 * (prev - next) / denom), denom = prev + next - 2 best, where denom > 0, else 0: the
// parabola's vertex in 1/16 px from the winner, with the scalar code's float operations and
// rounding (to nearest even), so that every kernel gives the same output.
CV_ALWAYS_INLINE cv::v_int32 vertexOffset(const cv::v_int32& prev, const cv::v_int32& next, const cv::v_int32& best) {
  const cv::v_int32 denom = prev + next - (best + best);
  const cv::v_float32 offset =
      cv::v_cvt_f32(prev - next) * cv::vx_setall_f32(kDispScale * 0.5f) / cv::v_cvt_f32(denom);
  return cv::v_select(denom > cv::vx_setzero_s32(), cv::v_round(offset), cv::vx_setzero_s32());
}
#endif

// One output row from the winners: invalid where the match falls outside the right image, the
// uniqueness test fails or the right image's winner disagrees (left_right_check); otherwise
// the winner's disparity in 1/16 px, moved to the vertex of the parabola through its
// neighbours' costs (subpixel). Vectorised across pixels, except the left-right lookup (a
// gather) and the row's last W % kLanes pixels.
CV_ALWAYS_INLINE void finishRow(const Problem& p, const Scratch& b, const int16_t* rk, int D, int16_t* dst) {
  const int W = p.width, tol = p.left_right_tolerance;
  const int16_t invalid = static_cast<int16_t>((p.min_disp - 1) * kDispScale);
  const bool check_unique = p.uniqueness_ratio > 0;
  int x = 0;
#if CV_SIMD
  int16_t lane_index[kLanes];
  for (int j = 0; j < kLanes; ++j) lane_index[j] = static_cast<int16_t>(j);
  const cv::v_int16 iota = cv::vx_load(lane_index), zero = cv::vx_setzero_s16();
  const cv::v_int16 min_disp = cv::vx_setall_s16(static_cast<int16_t>(p.min_disp));
  const cv::v_int16 width = cv::vx_setall_s16(static_cast<int16_t>(W));
  const cv::v_int16 last_k = cv::vx_setall_s16(static_cast<int16_t>(D - 1));
  for (; x + kLanes <= W; x += kLanes) {
    const cv::v_int16 k = cv::vx_load(b.best_k + x);
    const cv::v_int16 d = k + min_disp;
    const cv::v_int16 xr = (cv::vx_setall_s16(static_cast<int16_t>(x)) + iota) - d;
    cv::v_int16 ok = (xr >= zero) & (xr < width);
    if (check_unique) ok = ok & (cv::vx_load(b.within + x) <= zero);
    cv::v_int16 d16 = d << 4;  // * kDispScale
    if (p.subpixel) {
      cv::v_int32 prev0, prev1, next0, next1, best0, best1;
      cv::v_expand(cv::vx_load(b.prev + x), prev0, prev1);
      cv::v_expand(cv::vx_load(b.next + x), next0, next1);
      cv::v_expand(cv::vx_load(b.best + x), best0, best1);
      const cv::v_int16 offset = cv::v_pack(vertexOffset(prev0, next0, best0), vertexOffset(prev1, next1, best1));
      d16 = d16 + (offset & ((k > zero) & (k < last_k)));
    }
    cv::v_store(dst + x, cv::v_select(ok, d16, cv::vx_setall_s16(invalid)));
  }
  if (p.left_right_check)
    for (int xv = 0; xv < x; ++xv) {
      const int k = b.best_k[xv], xr = xv - p.min_disp - k;
      if (xr >= 0 && xr < W && absInt(rk[xr] - k) > tol) dst[xv] = invalid;
    }
#endif
  for (; x < W; ++x) {
    const int k = b.best_k[x];
    const int d = p.min_disp + k;
    const int xr = x - d;
    const bool ok = xr >= 0 && xr < W && (!check_unique || b.within[x] <= 0) &&
                    (!p.left_right_check || absInt(rk[xr] - k) <= tol);
    if (!ok) {
      dst[x] = invalid;
      continue;
    }
    int d16 = d * kDispScale;
    if (p.subpixel && k > 0 && k < D - 1) {
      const int denom = b.prev[x] + b.next[x] - 2 * b.best[x];
      if (denom > 0)  // vertex of the parabola, (prev - next) / (2 denom) px from k
        d16 += cvRound(kDispScale * 0.5f * (b.prev[x] - b.next[x]) / static_cast<float>(denom));
    }
    dst[x] = static_cast<int16_t>(d16);
  }
}

size_t scratchElements(const Problem& p) {
  Scratch unused;
  return layOut(p, nullptr, &unused);
}

// kFixedD: the number of disparities as a compile-time constant (0: p.ndisp at run time), so
// that the loops over disparities, a few vectors long, are unrolled.
template <int kFixedD>
void matchBandFor(const Problem& p, int y0, int y1, int16_t* out, size_t out_step, int16_t* memory) {
  const int W = p.width, D = kFixedD > 0 ? kFixedD : p.ndisp, r = p.radius;
  const int Wa = roundUp(W, kLanes);
  Scratch b;
  layOut(p, memory, &b);
  std::memset(b.col, 0, sizeof(int16_t) * static_cast<size_t>(p.padded_width) * D);
  for (int k = 0; k < D; ++k) b.filler[k] = kMaxCost;
  int16_t* col = b.col;
  int16_t* st = b.sums_t;
  const int st_stride = sumsStride(p);
  for (int k = 0; k < D; ++k) {  // the pads; the rows' [0, Wa) is written for every row
    int16_t* row = st + static_cast<size_t>(k) * st_stride;
    for (int x = -sumsPadLeft(p); x < 0; ++x) row[x] = kMaxCost;
    for (int x = Wa; x < Wa + sumsPadRight(p); ++x) row[x] = kMaxCost;
  }

  for (int pr = y0; pr <= y0 + 2 * r; ++pr) {
    const RowStep start = rowStep(p, pr, -1);
    for (int xi = 0; xi < p.padded_width; ++xi) updateColumn(p, start, xi, D, col);
  }
  for (int y = y0; y < y1; ++y) {
    // Each column moves down one row just before the window first uses it in this row, so the
    // column sums are touched while in L1 rather than in a pass of their own.
    const bool move_down = y > y0;
    const RowStep step = move_down ? rowStep(p, y + 2 * r, y - 1) : RowStep{};
    int16_t* dst = out + static_cast<size_t>(y) * out_step;
    // Blocks of kLanes pixels: window sums by a running box sum along x (vectorised across
    // disparities), transposed to [k][x], then the block's winners found while it is in L1.
    int16_t* s = b.sums;  // row 0: sums of the pixel before the block
    for (int x0 = 0; x0 < Wa; x0 += kLanes) {
      const int16_t* rows[kLanes];
      for (int j = 0; j < kLanes; ++j) {
        const int x = x0 + j;
        int16_t* __restrict sx = s + static_cast<size_t>(j + 1) * D;
        if (x >= W) {
          rows[j] = b.filler;
          continue;
        }
        rows[j] = sx;
        if (x == 0) {
          if (move_down)
            for (int xi = 0; xi <= 2 * r; ++xi) updateColumn(p, step, xi, D, col);
          for (int k = 0; k < D; ++k) sx[k] = 0;
          for (int xi = 0; xi <= 2 * r; ++xi)
            for (int k = 0; k < D; ++k) sx[k] = static_cast<int16_t>(sx[k] + col[xi * D + k]);
          continue;
        }
        if (move_down) updateColumn(p, step, x + 2 * r, D, col);
        slideWindow(sx - D, col + static_cast<size_t>(x + 2 * r) * D,
                    col + static_cast<size_t>(x - 1) * D, D, sx);
      }
      std::memcpy(s, s + static_cast<size_t>(kLanes) * D, sizeof(int16_t) * D);
      for (int g = 0; g < kLanes; g += 8) transpose8(rows + g, D, st + x0 + g, st_stride);
      blockWinners(st + x0, st_stride, D, p.uniqueness_ratio, b, x0);
    }

    // Right winner of every right pixel from the same sums, for the left-right check: a pass of
    // its own over the row's transposed sums (per block, the diagonal reads would reach into
    // blocks not yet summed).
    if (p.left_right_check) rightWinners(st, st_stride, Wa, D, p.min_disp, b.right_k);

    finishRow(p, b, b.right_k, D, dst);
  }
}

void matchBand(const Problem& p, int y0, int y1, int16_t* out, size_t out_step, int16_t* memory) {
  switch (p.ndisp) {  // the product's range and its double
    case 64: return matchBandFor<64>(p, y0, y1, out, out_step, memory);
    case 128: return matchBandFor<128>(p, y0, y1, out, out_step, memory);
    default: return matchBandFor<0>(p, y0, y1, out, out_step, memory);
  }
}

}  // namespace

const Kernel& SAD_KERNEL_GETTER() {
  static const Kernel kernel{SAD_KERNEL_NAME, &scratchElements, &matchBand};
  return kernel;
}

}  // namespace sad_kernel
}  // namespace embedded_calibration_stereo::core
