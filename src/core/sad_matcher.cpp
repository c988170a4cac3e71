#include "embedded_calibration_stereo/core/sad_matcher.h"

#include <algorithm>
#include <cstdint>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <vector>

namespace ecs {
namespace {

constexpr int kDispScale = 16;  // cv::StereoMatcher::DISP_SCALE

// x-Sobel response clipped to +-cap and shifted to 0..2*cap (StereoBM's XSOBEL prefilter):
// insensitive to the brightness offset between the cameras.
cv::Mat prefilterXSobel(const cv::Mat& img, int cap) {
  cv::Mat dx;
  cv::Sobel(img, dx, CV_16S, 1, 0, 3, 1, 0, cv::BORDER_REPLICATE);
  cv::Mat clipped = cv::min(cv::max(dx, -cap), cap);
  cv::Mat out;
  clipped.convertTo(out, CV_8U, 1.0, cap);
  return out;
}

// Everything a band worker needs, shared read-only between bands.
struct SadProblem {
  int width, height, ndisp, min_disp, radius;
  int padded_width;    // width + 2 * radius (left image columns of the window)
  int right_width;     // columns of the padded, mirrored right image
  int right_pad_left;  // columns of replicated border left of the right image
  cv::Mat left;        // prefiltered, padded by radius on every side
  cv::Mat right_rev;   // prefiltered, padded, then mirrored left-right
  SadMatcherParams params;

  // Index in the mirrored right row of disparity index 0 for padded left column xi; the costs
  // of disparity indices 0..ndisp-1 then lie at consecutive addresses.
  int rightBase(int xi) const {
    return right_width - 1 - right_pad_left + min_disp - xi + radius;
  }
};

// col[xi][k] += |L(enter) - R(enter)| - |L(leave) - R(leave)| for every column and disparity.
// leave < 0: add only (band start-up).
void updateColumnSums(const SadProblem& p, int enter_row, int leave_row, int16_t* col) {
  const int D = p.ndisp;
  const uint8_t* le = p.left.ptr<uint8_t>(enter_row);
  const uint8_t* re = p.right_rev.ptr<uint8_t>(enter_row);
  const uint8_t* ll = leave_row >= 0 ? p.left.ptr<uint8_t>(leave_row) : le;
  const uint8_t* rl = leave_row >= 0 ? p.right_rev.ptr<uint8_t>(leave_row) : re;
  const bool add_only = leave_row < 0;
  for (int xi = 0; xi < p.padded_width; ++xi) {
    const int base = p.rightBase(xi);
    int16_t* cs = col + static_cast<size_t>(xi) * D;
#if CV_SIMD128
    const cv::v_uint8x16 a_enter = cv::v_setall_u8(le[xi]);
    if (add_only) {
      for (int k = 0; k < D; k += 16) {
        cv::v_uint16x8 e0, e1;
        cv::v_expand(cv::v_absdiff(a_enter, cv::v_load(re + base + k)), e0, e1);
        cv::v_store(cs + k, cv::v_load(cs + k) + cv::v_reinterpret_as_s16(e0));
        cv::v_store(cs + k + 8, cv::v_load(cs + k + 8) + cv::v_reinterpret_as_s16(e1));
      }
      continue;
    }
    const cv::v_uint8x16 a_leave = cv::v_setall_u8(ll[xi]);
    for (int k = 0; k < D; k += 16) {
      cv::v_uint16x8 e0, e1, l0, l1;
      cv::v_expand(cv::v_absdiff(a_enter, cv::v_load(re + base + k)), e0, e1);
      cv::v_expand(cv::v_absdiff(a_leave, cv::v_load(rl + base + k)), l0, l1);
      cv::v_store(cs + k, cv::v_load(cs + k) + cv::v_sub_wrap(cv::v_reinterpret_as_s16(e0),
                                                              cv::v_reinterpret_as_s16(l0)));
      cv::v_store(cs + k + 8, cv::v_load(cs + k + 8) + cv::v_sub_wrap(cv::v_reinterpret_as_s16(e1),
                                                                      cv::v_reinterpret_as_s16(l1)));
    }
#else
    for (int k = 0; k < D; ++k) {
      int v = cs[k] + std::abs(le[xi] - re[base + k]);
      if (!add_only) v -= std::abs(ll[xi] - rl[base + k]);
      cs[k] = static_cast<int16_t>(v);
    }
#endif
  }
}

// out[k] = prev[k] + enter[k] - leave[k]: the window sums one pixel to the right.
inline void slideWindow(const int16_t* prev, const int16_t* enter, const int16_t* leave, int D,
                        int16_t* out) {
#if CV_SIMD128
  for (int k = 0; k < D; k += 16) {  // D is a multiple of 16; no sum exceeds int16
    cv::v_store(out + k, (cv::v_load(prev + k) + cv::v_load(enter + k)) - cv::v_load(leave + k));
    cv::v_store(out + k + 8,
                (cv::v_load(prev + k + 8) + cv::v_load(enter + k + 8)) - cv::v_load(leave + k + 8));
  }
#else
  for (int k = 0; k < D; ++k) out[k] = static_cast<int16_t>(prev[k] + enter[k] - leave[k]);
#endif
}

// dst[k][x0 + j] = src[j][k] for an 8 x D block of window sums (rows = pixels x0..x0+7).
void transposeBlock(const int16_t* const* rows, int D, int16_t* dst, int dst_stride) {
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

constexpr int16_t kMaxCost = 0x7FFF;

// Where cost[x] < best[x]: best[x] = cost[x], best_k[x] = k. n is a multiple of 8.
inline void keepLowerCost(const int16_t* cost, int16_t k, int n, int16_t* best, int16_t* best_k) {
#if CV_SIMD128
  const cv::v_int16x8 kv = cv::v_setall_s16(k);
  for (int x = 0; x < n; x += 8) {
    const cv::v_int16x8 c = cv::v_load(cost + x), b = cv::v_load(best + x);
    // Callers pass k in increasing order, so max() with (better ? k : 0) selects k: one
    // instruction fewer than a select on SSE2.
    cv::v_store(best_k + x, cv::v_max(cv::v_load(best_k + x), (c < b) & kv));
    cv::v_store(best + x, cv::v_min(c, b));
  }
#else
  for (int x = 0; x < n; ++x)
    if (cost[x] < best[x]) {
      best[x] = cost[x];
      best_k[x] = k;
    }
#endif
}

// Winner of 8 pixels at once from their transposed sums t[k * stride + j] (j = 0..7): best
// cost and index (lowest on ties), the costs at index - 1 and + 1 (for the parabola) and the
// number of indices costing at most thresh(best) (for the uniqueness test).
struct BlockWinners {
  int16_t best[8], best_k[8], prev[8], next[8], within[8];
};

inline void blockWinners(const int16_t* t, int stride, int D, double uniqueness_ratio,
                         BlockWinners* w) {
#if CV_SIMD128
  cv::v_int16x8 best = cv::v_setall_s16(kMaxCost), best_k = cv::v_setzero_s16();
  cv::v_int16x8 kv = cv::v_setzero_s16();
  const cv::v_int16x8 one = cv::v_setall_s16(1);
  const int16_t* row = t;
  for (int k = 0; k < D; k += 2, row += 2 * stride) {  // D is a multiple of 16
    const cv::v_int16x8 c0 = cv::v_load(row), c1 = cv::v_load(row + stride);
    best_k = cv::v_max(best_k, (c0 < best) & kv);  // k increases: max() selects it
    best = cv::v_min(c0, best);
    kv = kv + one;
    best_k = cv::v_max(best_k, (c1 < best) & kv);
    best = cv::v_min(c1, best);
    kv = kv + one;
  }
  cv::v_store(w->best, best);
  cv::v_store(w->best_k, best_k);
#else
  for (int j = 0; j < 8; ++j) {
    w->best[j] = kMaxCost;
    w->best_k[j] = 0;
    for (int k = 0; k < D; ++k)
      if (t[k * stride + j] < w->best[j]) {
        w->best[j] = t[k * stride + j];
        w->best_k[j] = static_cast<int16_t>(k);
      }
  }
#endif
  // The neighbours of the winners, gathered from the block (still in L1).
  for (int j = 0; j < 8; ++j) {
    const int k = w->best_k[j];
    w->prev[j] = k > 0 ? t[static_cast<size_t>(k - 1) * stride + j] : kMaxCost;
    w->next[j] = k < D - 1 ? t[static_cast<size_t>(k + 1) * stride + j] : kMaxCost;
  }
  if (uniqueness_ratio <= 0) return;
  int16_t thresh[8];
  const float ratio = static_cast<float>(uniqueness_ratio / 100.0);
  for (int j = 0; j < 8; ++j)
    thresh[j] = static_cast<int16_t>(
        std::min<int>(kMaxCost - 1, w->best[j] + static_cast<int>(w->best[j] * ratio)));
#if CV_SIMD128
  const cv::v_int16x8 th = cv::v_load(thresh);
  cv::v_int16x8 above = cv::v_setzero_s16();
  // A true comparison is all ones (-1) in the lane: adding it counts down.
  cv::v_int16x8 above1 = above;
  row = t;
  for (int k = 0; k < D; k += 2, row += 2 * stride) {
    above = cv::v_add_wrap(above, cv::v_load(row) > th);
    above1 = cv::v_add_wrap(above1, cv::v_load(row + stride) > th);
  }
  above = cv::v_add_wrap(above, above1);
  cv::v_store(w->within, cv::v_setall_s16(static_cast<int16_t>(D)) + above);
#else
  for (int j = 0; j < 8; ++j) {
    w->within[j] = 0;
    for (int k = 0; k < D; ++k) w->within[j] += t[k * stride + j] <= thresh[j];
  }
#endif
  for (int j = 0; j < 8; ++j) {  // the winner and its neighbours do not count against it
    const int k = w->best_k[j];
    w->within[j] -= 1 + (k > 0 && w->prev[j] <= thresh[j]) + (k < D - 1 && w->next[j] <= thresh[j]);
  }
}

// Per-band scratch memory.
struct BandBuffers {
  std::vector<int16_t> col;         // [padded x][k] vertical window sums
  std::vector<int16_t> sums;        // 9 x D: window sums of the pixel before the block + 8
  std::vector<int16_t> sums_t;      // [k][x] window sums of the row (x padded to Wa)
  std::vector<BlockWinners> winners;  // per block of 8 pixels
  std::vector<int16_t> right_cost, right_k;  // right-image winner, indexed xr + pad
  std::vector<int16_t> filler;      // kMaxCost row for padding pixels past the image
};

void matchBand(const SadProblem& p, int y0, int y1, cv::Mat* out) {
  const int W = p.width, D = p.ndisp, r = p.radius;
  const int Wa = (W + 7) / 8 * 8;
  const int right_pad = D + std::abs(p.min_disp) + 8;
  const short invalid = static_cast<short>((p.min_disp - 1) * kDispScale);
  BandBuffers b;
  b.col.assign(static_cast<size_t>(p.padded_width) * D, 0);
  b.sums.resize(static_cast<size_t>(9) * D);
  b.sums_t.resize(static_cast<size_t>(D) * Wa);
  b.winners.resize(Wa / 8);
  b.right_cost.resize(W + 2 * right_pad);
  b.right_k.resize(W + 2 * right_pad);
  b.filler.assign(D, kMaxCost);
  int16_t* col = b.col.data();
  int16_t* st = b.sums_t.data();

  for (int pr = y0; pr <= y0 + 2 * r; ++pr) updateColumnSums(p, pr, -1, col);
  for (int y = y0; y < y1; ++y) {
    if (y > y0) updateColumnSums(p, y + 2 * r, y - 1, col);
    short* dst = out->ptr<short>(y);

    // 1. Blocks of 8 pixels: window sums by a running box sum along x (vectorised across
    // disparities), transposed to [k][x], then the 8 winners found together while hot in cache.
    int16_t* s = b.sums.data();  // row 0: sums of the pixel before the block
    for (int x0 = 0; x0 < Wa; x0 += 8) {
      const int16_t* rows[8];
      for (int j = 0; j < 8; ++j) {
        const int x = x0 + j;
        int16_t* __restrict sx = s + static_cast<size_t>(j + 1) * D;
        if (x >= W) {
          rows[j] = b.filler.data();
          continue;
        }
        rows[j] = sx;
        if (x == 0) {
          std::fill(sx, sx + D, 0);
          for (int xi = 0; xi <= 2 * r; ++xi)
            for (int k = 0; k < D; ++k) sx[k] = static_cast<int16_t>(sx[k] + col[xi * D + k]);
          continue;
        }
        slideWindow(sx - D, col + static_cast<size_t>(x + 2 * r) * D,
                    col + static_cast<size_t>(x - 1) * D, D, sx);
      }
      std::copy(s + static_cast<size_t>(8) * D, s + static_cast<size_t>(9) * D, s);
      transposeBlock(rows, D, st + x0, Wa);
      blockWinners(st + x0, Wa, D, p.params.uniqueness_ratio, &b.winners[x0 / 8]);
    }

    // 2. Right winner of every right pixel xr = x - min_disp - k from the same sums.
    int16_t* rcost = b.right_cost.data() + right_pad;
    int16_t* rk = b.right_k.data() + right_pad;
    if (p.params.left_right_check) {
      std::fill(b.right_cost.begin(), b.right_cost.end(), kMaxCost);
      std::fill(b.right_k.begin(), b.right_k.end(), 0);
      for (int k = 0; k < D; ++k)
        keepLowerCost(st + static_cast<size_t>(k) * Wa, static_cast<int16_t>(k), Wa,
                      rcost - p.min_disp - k, rk - p.min_disp - k);
    }

    // 3. Per pixel: validity, uniqueness, left-right agreement, parabola sub-pixel.
    const int tol = p.params.left_right_tolerance;
    const bool check_unique = p.params.uniqueness_ratio > 0;
    for (int x = 0; x < W; ++x) {
      const BlockWinners& w = b.winners[x / 8];
      const int j = x % 8;
      const int k = w.best_k[j];
      const int d = p.min_disp + k;
      const int xr = x - d;
      const bool ok = xr >= 0 && xr < W && (!check_unique || w.within[j] <= 0) &&
                      (!p.params.left_right_check || std::abs(rk[xr] - k) <= tol);
      if (!ok) {
        dst[x] = invalid;
        continue;
      }
      int d16 = d * kDispScale;
      if (p.params.subpixel && k > 0 && k < D - 1) {
        const int denom = w.prev[j] + w.next[j] - 2 * w.best[j];
        if (denom > 0)  // vertex of the parabola, (prev - next) / (2 denom) px from k
          d16 += cvRound(kDispScale * 0.5f * (w.prev[j] - w.next[j]) / static_cast<float>(denom));
      }
      dst[x] = static_cast<short>(d16);
    }
  }
}

}  // namespace

cv::Mat computeSadDisparity16(const cv::Mat& left, const cv::Mat& right,
                              const SadMatcherParams& params) {
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

  SadProblem p;
  p.params = params;
  p.width = left.cols;
  p.height = left.rows;
  p.ndisp = params.num_disparities;
  p.min_disp = params.min_disparity;
  p.radius = params.window_size / 2;
  p.padded_width = p.width + 2 * p.radius;
  p.right_pad_left = std::max(0, p.radius + p.min_disp + p.ndisp - 1);
  const int right_pad_right = std::max(0, p.radius - p.min_disp);
  p.right_width = p.width + p.right_pad_left + right_pad_right;
  const int r = p.radius;
  cv::copyMakeBorder(prefilterXSobel(left, params.prefilter_cap), p.left, r, r, r, r,
                     cv::BORDER_REPLICATE);
  cv::Mat right_padded;
  cv::copyMakeBorder(prefilterXSobel(right, params.prefilter_cap), right_padded, r, r,
                     p.right_pad_left, right_pad_right, cv::BORDER_REPLICATE);
  cv::flip(right_padded, p.right_rev, 1);

  cv::Mat out(left.size(), CV_16SC1);
  // A few bands per thread balance the load; each band re-reads 2r rows to start its sums.
  const int bands = std::max(1, std::min(p.height / 16, cv::getNumThreads() * 2));
  cv::parallel_for_(cv::Range(0, bands), [&](const cv::Range& range) {
    for (int b = range.start; b < range.end; ++b) {
      const int y0 = p.height * b / bands, y1 = p.height * (b + 1) / bands;
      matchBand(p, y0, y1, &out);
    }
  }, bands);
  return out;
}

}  // namespace ecs
