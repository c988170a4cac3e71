// The census_sgm matcher's kernel, written once with OpenCV's width-agnostic universal
// intrinsics (cv::v_uint8 and vx_*: 16 lanes with SSE2/NEON, 32 with AVX2, 64 with AVX-512) and
// included by one .cpp per instruction set, which defines SGM_KERNEL_GETTER and SGM_KERNEL_NAME
// first.
// Everything but the getter has internal linkage, and nothing here calls a std:: template
// (sad_kernel.h says why). Every instruction set gives identical results (test_census_sgm).
//
// Per row: the census costs of every disparity (Hamming distances, vectorised across the
// disparities), then semi-global aggregation, each path in 8-bit saturating arithmetic: a path's
// cost minus its previous minimum never exceeds the cost plus P2, so it fits a byte.
//   - Down pass, rows top to bottom: the paths from above, above-left, above-right and the left,
//     their sum kept per pixel in bytes (saturating at 255, which only disparities far from
//     every path's minimum reach).
//   - Up pass, rows bottom to top (eight paths only): the paths from below, below-left and
//     below-right. With five paths, each row's up step follows its down step at once.
//   - Per row, right to left: the path from the right and the sum of all paths (bytes,
//     saturating at 255); and the winner, its uniqueness and the right image's winners (for
//     the left-right check, from the same sums): with eight paths in a second loop over the
//     row's stored sums, with five in the same loop (upRow says why); after the row, the
//     sub-pixel offsets in one vectorised pass.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <opencv2/core/hal/intrin.hpp>

#include "sgm_kernel.h"

#if !defined(SGM_KERNEL_GETTER) || !defined(SGM_KERNEL_NAME)
#error "define SGM_KERNEL_GETTER and SGM_KERNEL_NAME before including sgm_kernel.inl"
#endif

namespace embedded_calibration_stereo::core {
namespace sgm_kernel {
namespace {

constexpr int kDispScale = 16;  // cv::StereoMatcher::DISP_SCALE
#if CV_SIMD
constexpr int kLanes8 = cv::v_uint8::nlanes;
#else
#error "the census_sgm kernel needs universal intrinsics (SSE2, NEON or wider)"
#endif

int absInt(int v) { return v < 0 ? -v : v; }

// The per-pixel helpers must be inlined for a pixel's sums to stay in registers.
#if defined(__GNUC__)
#define SGM_INLINE inline __attribute__((always_inline))
#else
#define SGM_INLINE inline
#endif

// Horizontal minima, the kernel's most frequent reductions: with AVX2 and AVX-512 (after
// folding the halves down to 128 bits), SSE4.1's PHMINPOSUW finds the least of eight 16-bit lanes (here: bytes paired, each pair's lesser in
// its low byte and 0 in its high byte) in one instruction. minOf() gives the minimum as a
// number; minInAll() in every lane, without the round trip through a general register, for the
// paths along a row, whose next pixel waits on it.
#if CV_AVX512_SKX
inline __m128i minInLowWord(const cv::v_uint8& v) {
  const __m256i h = _mm256_min_epu8(_mm512_castsi512_si256(v.val), _mm512_extracti64x4_epi64(v.val, 1));
  const __m128i m = _mm_min_epu8(_mm256_castsi256_si128(h), _mm256_extracti128_si256(h, 1));
  return _mm_minpos_epu16(_mm_min_epu8(m, _mm_srli_epi16(m, 8)));
}
inline uint8_t minOf(const cv::v_uint8& v) { return static_cast<uint8_t>(_mm_cvtsi128_si32(minInLowWord(v))); }
inline cv::v_uint8 minInAll(const cv::v_uint8& v) { return cv::v_uint8(_mm512_broadcastb_epi8(minInLowWord(v))); }
#elif CV_AVX2
inline __m128i minInLowWord(const cv::v_uint8& v) {
  const __m128i m = _mm_min_epu8(_mm256_castsi256_si128(v.val), _mm256_extracti128_si256(v.val, 1));
  return _mm_minpos_epu16(_mm_min_epu8(m, _mm_srli_epi16(m, 8)));
}
inline uint8_t minOf(const cv::v_uint8& v) { return static_cast<uint8_t>(_mm_cvtsi128_si32(minInLowWord(v))); }
inline cv::v_uint8 minInAll(const cv::v_uint8& v) { return cv::v_uint8(_mm256_broadcastb_epi8(minInLowWord(v))); }
#else
inline uint8_t minOf(const cv::v_uint8& v) { return cv::v_reduce_min(v); }
inline cv::v_uint8 minInAll(const cv::v_uint8& v) { return cv::vx_setall_u8(cv::v_reduce_min(v)); }
#endif

// ---- census ----------------------------------------------------------------------------

// One row of the census over a 5x5 window: bit i says whether the i-th neighbour (row by row,
// the centre left out) is brighter than the centre by more than `threshold` grey levels.
void censusRow(const uint8_t* padded, size_t step, int width, int y, int threshold, uint8_t* out) {
  const uint8_t* centre = padded + (y + kCensusRadiusY) * step + kCensusRadiusX;
  int x = 0;
  for (; x + kLanes8 <= width; x += kLanes8) {
    const cv::v_uint8 c = cv::vx_load(centre + x) + cv::vx_setall_u8(static_cast<uint8_t>(threshold));
    cv::v_uint8 planes[kPlanes];
    for (int k = 0; k < kPlanes; ++k) planes[k] = cv::vx_setzero_u8();
    int bit = 0;
    for (int dy = -kCensusRadiusY; dy <= kCensusRadiusY; ++dy)
      for (int dx = -kCensusRadiusX; dx <= kCensusRadiusX; ++dx) {
        if (dy == 0 && dx == 0) continue;
        const cv::v_uint8 n = cv::vx_load(centre + dy * static_cast<ptrdiff_t>(step) + dx + x);
        const cv::v_uint8 mask = cv::vx_setall_u8(static_cast<uint8_t>(1u << (bit % 8)));
        planes[bit / 8] = planes[bit / 8] | ((n > c) & mask);
        ++bit;
      }
    for (int k = 0; k < kPlanes; ++k) cv::v_store(out + k * width + x, planes[k]);
  }
  for (; x < width; ++x) {
    uint32_t code = 0;
    int bit = 0;
    for (int dy = -kCensusRadiusY; dy <= kCensusRadiusY; ++dy)
      for (int dx = -kCensusRadiusX; dx <= kCensusRadiusX; ++dx) {
        if (dy == 0 && dx == 0) continue;
        const int c = centre[x] + threshold > 255 ? 255 : centre[x] + threshold;
        code |= static_cast<uint32_t>(centre[dy * static_cast<ptrdiff_t>(step) + dx + x] > c) << bit;
        ++bit;
      }
    for (int k = 0; k < kPlanes; ++k) out[k * width + x] = static_cast<uint8_t>(code >> (8 * k));
  }
}

// ---- scratch -----------------------------------------------------------------------------

// A row of path costs: one block of ndisp_padded bytes per pixel, blocks at a stride of
// ndisp_padded + 2 so that a block's neighbours at -1 and +1 (the disparities either side) can
// be read with unaligned loads; the pad bytes and the blocks of the columns -1 and width hold
// 255, which makes a path start at the image's edge.
struct PathRow {
  uint8_t* cost;  // block of column x at cost + (x + 1) * stride + 1
  uint8_t* min;   // min[x + 1]: the block's minimum
};

struct Penalties;

struct Scratch {
  uint8_t* costs;          // [x][k] census costs of the row under way
  PathRow vertical[3][2];  // the three paths from the previous row: previous and current row
  uint8_t* down;           // [row][x][k] the down pass's sums, rows y0.. of the band
  uint8_t* right_k;        // [q] the right image's winner, low byte, entries as Problem::census_right
  uint8_t* right_k_high;   // [q] its high byte (more than 256 disparities only)
  uint16_t* winner_k;      // [x] the left pixel's winning disparity index
  int32_t* offset_num;     // [x] the sub-pixel offset's numerator, then the offset (1/16 px)
  int32_t* offset_den;     // [x] its denominator (1 where there is no offset)
  uint8_t* p2[4];          // [x] the P2 of each path of the pass at row y (rowPenalties)
  const Penalties* penalties;
};

int blockStride(const Problem& p) { return p.ndisp_padded + 2; }
size_t rowElements(const Problem& p) {
  return static_cast<size_t>(p.width) * static_cast<size_t>(p.ndisp_padded);
}

size_t layOut(const Problem& p, int band_rows, uint8_t* base, Scratch* s) {
  const size_t W = static_cast<size_t>(p.width);
  const size_t path_row = (W + 2) * static_cast<size_t>(blockStride(p)) + kLanes8;
  const size_t right = static_cast<size_t>(p.right_len + p.ndisp_padded);
  size_t used = 0;
  auto take = [&](size_t n) {
    used = (used + 63) / 64 * 64;
    uint8_t* at = base ? base + used : nullptr;
    used += n;
    return at;
  };
  s->costs = take(rowElements(p));
  for (auto& path : s->vertical)
    for (auto& row : path) {
      row.cost = take(path_row);
      row.min = take(W + 2);
    }
  const size_t band = rowElements(p) * static_cast<size_t>(p.paths == 5 ? 1 : band_rows);
  s->down = take(band);
  s->right_k = take(right);
  s->right_k_high = take(right);
  s->winner_k = reinterpret_cast<uint16_t*>(take(W * 2));
  s->offset_num = reinterpret_cast<int32_t*>(take(W * 4));
  s->offset_den = reinterpret_cast<int32_t*>(take(W * 4));
  for (auto& row : s->p2) row = take(W);
  return used + 64;
}

size_t scratchBytes(const Problem& p, int band_rows) {
  Scratch s;
  return layOut(p, band_rows, nullptr, &s);
}

void resetVerticalPaths(const Problem& p, Scratch& s) {
  const size_t W = static_cast<size_t>(p.width);
  for (auto& path : s.vertical)
    for (auto& row : path) {
      std::memset(row.cost, 255, (W + 2) * static_cast<size_t>(blockStride(p)) + kLanes8);
      std::memset(row.min, 255, W + 2);
    }
}

void swapVerticalRows(Scratch& s) {
  for (auto& path : s.vertical) {
    const PathRow t = path[0];
    path[0] = path[1];
    path[1] = t;
  }
}

// ---- costs -------------------------------------------------------------------------------

// Census costs of row y: costs[x * D + k] = Hamming distance between left pixel x and right
// pixel x - min_disp - k; 255 in the padded lanes k >= ndisp.
template <int NV>
void costRow(const Problem& p, int y, uint8_t* costs) {
  constexpr int D = NV * kLanes8;
  // Locals, not p's members, in the loop: its stores might alias them (VerticalPaths says more).
  const int width = p.width, ndisp = p.ndisp;
  const size_t right_len = static_cast<size_t>(p.right_len);
  const uint8_t* left = p.census_left + static_cast<size_t>(y) * p.left_step;
  const uint8_t* right = p.census_right + static_cast<size_t>(y) * p.right_step +
                         (p.width - 1 + p.right_off + p.min_disp);  // q0(x) = -x
  for (int x = 0; x < width; ++x) {
    cv::v_uint8 l[kPlanes];
    for (int k = 0; k < kPlanes; ++k) l[k] = cv::vx_setall_u8(left[k * width + x]);
    uint8_t* out = costs + static_cast<size_t>(x) * D;
    const uint8_t* r = right - x;
    for (int j = 0; j < D; j += kLanes8) {
      cv::v_uint8 sum = cv::v_popcount(cv::vx_load(r + j) ^ l[0]);
      for (int k = 1; k < kPlanes; ++k) sum = sum + cv::v_popcount(cv::vx_load(r + k * right_len + j) ^ l[k]);
      cv::v_store(out + j, sum);
    }
    for (int k = ndisp; k < D; ++k) out[k] = 255;
  }
}

// ---- aggregation -------------------------------------------------------------------------
// Templates on NV, the byte vectors of one pixel's disparities (ndisp_padded / kLanes8), so that
// a pixel's path costs and sums stay in registers.

// One step of a path: L(k) = C(k) + min(P(k), P(k-1) + P1, P(k+1) + P1, minP + P2) - minP,
// written to `out` and added to `sum` (or put there, when not `add`); returns its minimum.
// `prev` is the path's block at the previous pixel, with readable pad bytes of 255 at -1 and
// ndisp_padded (a row written long before, so the unaligned loads do not wait on a store).
template <int NV>
SGM_INLINE uint8_t pathStep(const uint8_t* cost, const uint8_t* prev, uint8_t prev_min,
                            const cv::v_uint8& p1, uint8_t p2, uint8_t* out, bool add,
                            cv::v_uint8* sum) {
  const cv::v_uint8 floor = cv::vx_setall_u8(prev_min);
  const cv::v_uint8 jump = floor + cv::vx_setall_u8(p2);  // saturating: min(prev_min + p2, 255)
  cv::v_uint8 lowest = cv::vx_setall_u8(255);
  for (int j = 0; j < NV; ++j) {
    const uint8_t* at = prev + j * kLanes8;
    const cv::v_uint8 same = cv::vx_load(at);
    const cv::v_uint8 step = cv::v_min(cv::vx_load(at - 1), cv::vx_load(at + 1)) + p1;
    const cv::v_uint8 l =
        cv::vx_load(cost + j * kLanes8) + (cv::v_min(cv::v_min(same, step), jump) - floor);
    cv::v_store(out + j * kLanes8, l);
    sum[j] = add ? sum[j] + l : l;
    lowest = cv::v_min(lowest, l);
  }
  return minOf(lowest);
}

// A path along the row (from the left or the right), its previous pixel held in registers:
// the neighbouring disparities come from lane rotations, not from reloading what was just
// stored.
template <int NV>
struct RowPath {
  cv::v_uint8 l[NV];   // the path's costs at the last pixel stepped to
  cv::v_uint8 l_min;   // their minimum, in every lane

  RowPath() : l_min(cv::vx_setall_u8(255)) {
    for (int j = 0; j < NV; ++j) l[j] = cv::vx_setall_u8(255);
  }

  void step(const uint8_t* cost, const cv::v_uint8& p1, uint8_t p2) {
    const cv::v_uint8 edge = cv::vx_setall_u8(255);
    const cv::v_uint8 floor = l_min;
    const cv::v_uint8 jump = floor + cv::vx_setall_u8(p2);  // saturating: min(floor + p2, 255)
    cv::v_uint8 lowest = edge, below = edge;  // below: l[j - 1] before this step
    for (int j = 0; j < NV; ++j) {
      const cv::v_uint8 same = l[j];
      const cv::v_uint8 above = j + 1 < NV ? l[j + 1] : edge;
      const cv::v_uint8 step =
          cv::v_min(cv::v_rotate_left<1>(same, below), cv::v_rotate_right<1>(same, above)) + p1;
      below = same;
      l[j] = cv::vx_load(cost + j * kLanes8) + (cv::v_min(cv::v_min(same, step), jump) - floor);
      lowest = cv::v_min(lowest, l[j]);
    }
    l_min = minInAll(lowest);
  }
};

// What a band's pixels look up rather than compute: P1; P2 lowered across intensity edges (where
// depth edges are likely), P2 / (1 + |dI| / T); the uniqueness test's limit for each best sum.
struct Penalties {
  cv::v_uint8 p1;
  uint8_t p2[256];
  // The same in vectors of float: P2 * edge_scale / (edge_scale + d), truncated, is exact in
  // float when the numerator is below 2^24 (a quotient that is not whole lies at least
  // 1 / (edge_scale + d) from the next whole number, far more than float's rounding).
  bool in_vectors;
  float numerator, scale;
  int least;
  // The uniqueness test, best * (100 + ratio) < rival * 100 in integers ((100 + ratio) in
  // 1/1024ths), as the greatest rival that fails it, for each best sum.
  bool uniqueness;
  uint8_t rival_limit[256];
  explicit Penalties(const Problem& p) : p1(cv::vx_setall_u8(static_cast<uint8_t>(p.P1))) {
    for (int d = 0; d < 256; ++d) {
      const int v = p.edge_scale > 0 ? p.P2 * p.edge_scale / (p.edge_scale + d) : p.P2;
      p2[d] = static_cast<uint8_t>(v > p.P1 + 1 ? v : p.P1 + 1);
    }
    in_vectors = p.edge_scale > 0 && static_cast<int64_t>(p.P2) * p.edge_scale < (int64_t{1} << 24);
    numerator = static_cast<float>(p.P2 * (in_vectors ? p.edge_scale : 0));
    scale = static_cast<float>(p.edge_scale);
    least = p.P1 + 1;
    uniqueness = p.uniqueness_ratio > 0;
    const int64_t ratio = uniqueness ? static_cast<int64_t>((100.0 + p.uniqueness_ratio) * 1024 + 0.5) : 0;
    for (int best = 0; best < 256; ++best) {
      const int64_t limit = best * ratio / (1024 * 100);
      rival_limit[best] = static_cast<uint8_t>(limit > 255 ? 255 : limit);
    }
  }
  // p2[d] for every lane of d (in_vectors only).
  cv::v_uint8 of(const cv::v_uint8& d) const {
    cv::v_uint16 d16[2];
    cv::v_expand(d, d16[0], d16[1]);
    cv::v_int16 q16[2];
    for (int h = 0; h < 2; ++h) {
      cv::v_uint32 d32[2];
      cv::v_expand(d16[h], d32[0], d32[1]);
      cv::v_int32 q[2];
      for (int i = 0; i < 2; ++i) {
        const cv::v_float32 f = cv::v_cvt_f32(cv::v_reinterpret_as_s32(d32[i])) + cv::vx_setall_f32(scale);
        q[i] = cv::v_max(cv::v_trunc(cv::vx_setall_f32(numerator) / f), cv::vx_setall_s32(least));
      }
      q16[h] = cv::v_pack(q[0], q[1]);
    }
    return cv::v_pack_u(q16[0], q16[1]);
  }
};

// The P2 of every pixel of `row` on the paths of one pass that step it, to out[0..3]: when
// `vertical`, the three from the row `from` (straight, from the pixel before, from the pixel
// after, as VerticalPaths steps them); when `horizontal`, the one along the row from the
// neighbour at `along` (-1: the left, +1: the right). Columns past the image's ends clamped. The
// intensity steps and their P2 in vectors (Penalties::of), out of the paths' way.
void rowPenalties(const Problem& p, const Penalties& pen, const uint8_t* row, const uint8_t* from,
                  int along, bool vertical, bool horizontal, uint8_t* const* out) {
  const int W = p.width;
  const int offsets[4] = {0, -1, +1, along};
  for (int r = vertical ? 0 : 3; r < (horizontal ? 4 : 3); ++r) {
    const uint8_t* other = r < 3 ? from : row;
    const int o = offsets[r];
    uint8_t* d = out[r];
    int x = 1;
#if CV_AVX512_SKX
    // VBMI's two-table byte permutes look the whole 256-entry table up, 64 pixels at a time.
    const __m512i t0 = _mm512_loadu_si512(pen.p2), t1 = _mm512_loadu_si512(pen.p2 + 64);
    const __m512i t2 = _mm512_loadu_si512(pen.p2 + 128), t3 = _mm512_loadu_si512(pen.p2 + 192);
    for (; x + kLanes8 <= W - 1; x += kLanes8) {
      const __m512i dI = cv::v_absdiff(cv::vx_load(row + x), cv::vx_load(other + x + o)).val;
      const __m512i low = _mm512_permutex2var_epi8(t0, dI, t1), high = _mm512_permutex2var_epi8(t2, dI, t3);
      _mm512_storeu_si512(d + x, _mm512_mask_blend_epi8(_mm512_movepi8_mask(dI), low, high));
    }
#else
    if (pen.in_vectors) {
      for (; x + kLanes8 <= W - 1; x += kLanes8)
        cv::v_store(d + x, pen.of(cv::v_absdiff(cv::vx_load(row + x), cv::vx_load(other + x + o))));
    } else {
      for (; x + kLanes8 <= W - 1; x += kLanes8)
        cv::v_store(d + x, cv::v_absdiff(cv::vx_load(row + x), cv::vx_load(other + x + o)));
      for (int i = 1; i < x; ++i) d[i] = pen.p2[d[i]];
    }
#endif
    for (; x < W - 1; ++x) d[x] = pen.p2[absInt(row[x] - other[x + o])];
    const auto clamped = [W](int v) { return v < 0 ? 0 : (v >= W ? W - 1 : v); };
    d[0] = pen.p2[absInt(row[0] - other[clamped(o)])];
    d[W - 1] = pen.p2[absInt(row[W - 1] - other[clamped(W - 1 + o)])];
  }
}

// The three paths into row y from the previous row (y - 1 going down, y + 1 going up):
// straight, from the pixel before and from the pixel after. What the pixel loop reads is held
// in this object's members, a local of the row's function: were it read through Scratch, every
// byte the loop stores might alias it, and the compiler would reload it after each one.
template <int NV>
struct VerticalPaths {
  static constexpr int kStride = NV * kLanes8 + 2;  // blockStride() of this NV
  const uint8_t* prev_cost[3];  // the block of column 0 of the path's previous row
  const uint8_t* prev_min[3];   // its minima, column x at [x + 1]
  uint8_t* cur_cost[3];
  uint8_t* cur_min[3];
  const uint8_t* p2[3];         // the row's P2 per pixel (rowPenalties)
  cv::v_uint8 p1;

  explicit VerticalPaths(const Scratch& s) : p1(s.penalties->p1) {
    for (int r = 0; r < 3; ++r) {
      prev_cost[r] = s.vertical[r][0].cost + kStride + 1;
      prev_min[r] = s.vertical[r][0].min;
      cur_cost[r] = s.vertical[r][1].cost + kStride + 1;
      cur_min[r] = s.vertical[r][1].min;
      p2[r] = s.p2[r];
    }
  }

  // Steps the three paths to pixel x; the sum of their costs there to `sum` (bytes saturating
  // at 255: a sum of costs in any order, as min(total, 255)).
  SGM_INLINE void step(int x, const uint8_t* cost, cv::v_uint8* sum) const {
    constexpr int kFrom[3] = {0, -1, +1};
    for (int r = 0; r < 3; ++r) {
      const int xf = x + kFrom[r];
      cur_min[r][x + 1] = pathStep<NV>(cost, prev_cost[r] + xf * kStride, prev_min[r][xf + 1], p1, p2[r][x],
                                       cur_cost[r] + x * kStride, r > 0, sum);
    }
  }
};

const uint8_t* imageRow(const Problem& p, int y) {
  const int yc = y < 0 ? 0 : (y >= p.height ? p.height - 1 : y);
  return p.image + static_cast<size_t>(yc) * p.image_step;
}

// Down pass, row y: the paths from above (and, when `output`, from the left), their sum in
// bytes to down[x * D + k].
template <int NV>
void downRow(const Problem& p, Scratch& s, int y, bool output, const uint8_t* costs,
             uint8_t* down) {
  constexpr int D = NV * kLanes8;
  const Penalties& pen = *s.penalties;
  const uint8_t* row = imageRow(p, y);
  const uint8_t* above = y > 0 ? imageRow(p, y - 1) : row;
  rowPenalties(p, pen, row, above, -1, true, output, s.p2);
  const VerticalPaths<NV> paths(s);
  const uint8_t* const p2_along = s.p2[3];
  const int width = p.width;
  RowPath<NV> from_left;
  cv::v_uint8 vertical[NV];
  for (int x = 0; x < width; ++x) {
    const uint8_t* cost = costs + static_cast<size_t>(x) * D;
    paths.step(x, cost, vertical);
    if (!output) continue;
    from_left.step(cost, paths.p1, p2_along[x]);
    for (int j = 0; j < NV; ++j)
      cv::v_store(down + static_cast<size_t>(x) * D + j * kLanes8, vertical[j] + from_left.l[j]);
  }
}

// ---- winners -----------------------------------------------------------------------------
// All paths' sum of one disparity in a byte, saturating at 255: the winner and its rivals lie
// far below that, and byte lanes halve the work of every reduction and give the winner's index
// from a lane mask rather than from a vector of indices.

inline int firstBit(uint64_t m) { return __builtin_ctzll(m); }

constexpr int kGroupLanes = 64;                            // lanes per 64-bit lane mask
constexpr int kVectorsPerGroup = kGroupLanes / kLanes8;  // 1 with AVX-512, 2 with AVX2, 4 with 128 bits
constexpr uint64_t kAllLanes = kLanes8 == 64 ? ~uint64_t{0} : (uint64_t{1} << (kLanes8 % 64)) - 1;

// Bit i: whether lane i of a vector equals that of `b` / is at most that of `t`. AVX-512
// compares into a mask register; elsewhere the compare's lanes become bits through v_signmask
// (an int for up to 32 lanes, sign-extended here, hence kAllLanes; an int64 for 64).
#if CV_AVX512_SKX
SGM_INLINE uint64_t equalLanes(const cv::v_uint8& v, const cv::v_uint8& b) { return _mm512_cmpeq_epu8_mask(v.val, b.val); }
SGM_INLINE uint64_t atMostLanes(const cv::v_uint8& v, const cv::v_uint8& t) { return _mm512_cmple_epu8_mask(v.val, t.val); }
#else
SGM_INLINE uint64_t equalLanes(const cv::v_uint8& v, const cv::v_uint8& b) {
  return static_cast<uint64_t>(cv::v_signmask(v == b)) & kAllLanes;
}
SGM_INLINE uint64_t atMostLanes(const cv::v_uint8& v, const cv::v_uint8& t) {
  return static_cast<uint64_t>(cv::v_signmask(cv::v_min(v, t) == v)) & kAllLanes;
}
#endif

// `if_equal` in the lanes where a equals b, `otherwise` elsewhere.
SGM_INLINE cv::v_uint8 selectWhereEqual(const cv::v_uint8& a, const cv::v_uint8& b, const cv::v_uint8& if_equal,
                                        const cv::v_uint8& otherwise) {
#if CV_AVX512_SKX
  return cv::v_uint8(_mm512_mask_blend_epi8(_mm512_cmpeq_epu8_mask(a.val, b.val), otherwise.val, if_equal.val));
#else
  return cv::v_select(a == b, if_equal, otherwise);
#endif
}

// Bit i: whether lane kGroupLanes * g + i of the pixel's sums `s` (NV vectors) passes `test`,
// which gives a vector's lanes that pass as bits (equalLanes, atMostLanes).
template <int NV, class Test>
SGM_INLINE uint64_t laneMask(const cv::v_uint8* s, int g, const Test& test) {
  uint64_t mask = 0;
  for (int i = 0; i < kVectorsPerGroup && g * kVectorsPerGroup + i < NV; ++i)
    mask |= test(s[g * kVectorsPerGroup + i]) << (i * kLanes8);
  return mask;
}

template <int NV>
constexpr int groups() { return (NV + kVectorsPerGroup - 1) / kVectorsPerGroup; }

// The index of the first lane holding the least sum `b` (in every lane of b; so there is one).
template <int NV>
SGM_INLINE int firstLaneOf(const cv::v_uint8* s, const cv::v_uint8& b) {
  const auto is_best = [&b](const cv::v_uint8& v) { return equalLanes(v, b); };
  for (int g = 0; g + 1 < groups<NV>(); ++g) {
    const uint64_t m = laneMask<NV>(s, g, is_best);
    if (m) return g * kGroupLanes + firstBit(m);
  }
  const int g = groups<NV>() - 1;
  return g * kGroupLanes + firstBit(laneMask<NV>(s, g, is_best));
}

// Whether every sum outside the winner k and its two neighbours is above the limit `t` (in
// every lane).
template <int NV>
SGM_INLINE bool noRivalAtMost(const cv::v_uint8* s, int k, const cv::v_uint8& t) {
  const auto at_most = [&t](const cv::v_uint8& v) { return atMostLanes(v, t); };
  if (groups<NV>() == 1) {  // 64 disparities or fewer: the winner's lanes by one shift
    const uint64_t around = k > 0 ? uint64_t{7} << (k - 1) : uint64_t{3};
    return (laneMask<NV>(s, 0, at_most) & ~around) == 0;
  }
  for (int g = 0; g < groups<NV>(); ++g) {
    uint64_t m = laneMask<NV>(s, g, at_most);
    for (int i = k - 1 - g * kGroupLanes; i <= k + 1 - g * kGroupLanes; ++i)
      if (i >= 0 && i < kGroupLanes) m &= ~(uint64_t{1} << i);
    if (m) return false;
  }
  return true;
}

// The right image's winners, from the left pixels' sums folded right to left (x from width - 1
// down to 0): entry q of right_k / right_k_high is right column width - 1 + right_off - q, which
// disparity index k of left pixel x meets at q0(x) + k, and q0 grows by one from one pixel to
// the next. So the entries a pixel meets are held in registers, a window that moves on by one
// entry per pixel; the entry it leaves behind is final and is stored. (In memory, each pixel's
// loads would overlap the previous pixel's stores one byte off, which stalls the loads until
// the stores are written.) On ties an entry keeps the pixel folded first (the larger x).
template <int NV>
struct RightWinners {
  static constexpr bool kHigh = NV * kLanes8 > 256;
  cv::v_uint8 cost[NV];   // the best sum so far of entries q0 ..
  cv::v_uint8 k[NV];      // its disparity index, low byte
  cv::v_uint8 high[NV];   // and high byte (more than 256 disparities only)
  cv::v_uint8 index[NV];  // lane i of vector j: j * kLanes8 + i, low byte

  RightWinners() {
    alignas(64) uint8_t ramp[kLanes8];
    for (int i = 0; i < kLanes8; ++i) ramp[i] = static_cast<uint8_t>(i);
    for (int j = 0; j < NV; ++j) {
      cost[j] = cv::vx_setall_u8(255);
      k[j] = high[j] = cv::vx_setzero_u8();
      index[j] = cv::v_add_wrap(cv::vx_load_aligned(ramp), cv::vx_setall_u8(static_cast<uint8_t>(j * kLanes8)));
    }
  }

  // Folds the sums of the next pixel in, stores its entry q0 to k_out[0] (high_out[0]), and
  // moves on to the next pixel's entries.
  SGM_INLINE void fold(const cv::v_uint8* sums, uint8_t* k_out, uint8_t* high_out) {
    for (int j = 0; j < NV; ++j) {
      const cv::v_uint8 least = cv::v_min(sums[j], cost[j]);
      const cv::v_uint8 before = cost[j];
      cost[j] = least;
      k[j] = selectWhereEqual(least, before, k[j], index[j]);
      if (kHigh)
        high[j] = selectWhereEqual(least, before, high[j], cv::vx_setall_u8(static_cast<uint8_t>((j * kLanes8) >> 8)));
    }
    *k_out = cv::v_extract_n<0>(k[0]);
    if (kHigh) *high_out = cv::v_extract_n<0>(high[0]);
    const cv::v_uint8 none = cv::vx_setall_u8(255), zero = cv::vx_setzero_u8();
    for (int j = 0; j < NV; ++j) {
      cost[j] = cv::v_rotate_right<1>(cost[j], j + 1 < NV ? cost[j + 1] : none);
      k[j] = cv::v_rotate_right<1>(k[j], j + 1 < NV ? k[j + 1] : zero);
      if (kHigh) high[j] = cv::v_rotate_right<1>(high[j], j + 1 < NV ? high[j + 1] : zero);
    }
  }

  // After the row's last pixel: the entries still in the window, from k_out[0] (high_out[0]).
  SGM_INLINE void flush(uint8_t* k_out, uint8_t* high_out) const {
    for (int j = 0; j < NV; ++j) {
      cv::v_store(k_out + j * kLanes8, k[j]);
      if (kHigh) cv::v_store(high_out + j * kLanes8, high[j]);
    }
  }
};

// The equiangular (V-shaped) fit's operands at winner k, to *num and *den, where `fit` (the
// pixel is unique and k has neighbours on both sides; no offset elsewhere), kept for one
// vectorised division per row: census sums grow linearly away from the match, and a parabola
// through them is pulled harder towards the whole pixel.
template <int NV>
SGM_INLINE void keepSubpixelFit(const cv::v_uint8* sums, int k, bool fit, int32_t* num, int32_t* den) {
  *num = 0;
  *den = 1;
  if (!fit) return;
  alignas(64) uint8_t all[NV * kLanes8];
  for (int j = 0; j < NV; ++j) cv::v_store_aligned(all + j * kLanes8, sums[j]);
  const int a = all[k - 1], b = all[k], c = all[k + 1];
  const int denom = a > c ? a - b : c - b;
  if (denom <= 0) return;
  *num = (a - c) * kDispScale;
  *den = 2 * denom;
}

// Adds each pixel's sub-pixel offset, num / den as a float rounded half away from zero.
void addSubpixelOffsets(const Problem& p, Scratch& s, int16_t* out) {
  int x = 0;
  const cv::v_float32 half = cv::vx_setall_f32(0.5f), zero = cv::vx_setzero_f32();
  for (; x + cv::v_float32::nlanes <= p.width; x += cv::v_float32::nlanes) {
    const cv::v_float32 q = cv::v_cvt_f32(cv::vx_load(s.offset_num + x)) /
                            cv::v_cvt_f32(cv::vx_load(s.offset_den + x));
    cv::v_store(s.offset_num + x, cv::v_trunc(cv::v_select(q >= zero, q + half, q - half)));
  }
  for (; x < p.width; ++x) {
    const float q = static_cast<float>(s.offset_num[x]) / static_cast<float>(s.offset_den[x]);
    s.offset_num[x] = static_cast<int>(q >= 0 ? q + 0.5f : q - 0.5f);
  }
  for (x = 0; x < p.width; ++x) out[x] = static_cast<int16_t>(out[x] + s.offset_num[x]);
}

// Clears the left winners whose right pixel's winner disagrees by more than the tolerance, and
// marks in `occluded` (when given) those whose right pixel sees something nearer, or whose
// census window does not lie inside the right image (its border columns are repeated copies):
// hidden from the right camera rather than mismatched.
void leftRightCheck(const Problem& p, const Scratch& s, int16_t* out, uint8_t* occluded) {
  const int16_t invalid = static_cast<int16_t>((p.min_disp - 1) * kDispScale);
  // Locals, not p's and s's members, in the loop: its stores might alias them.
  const int width = p.width, min_disp = p.min_disp, tolerance = p.left_right_tolerance;
  const bool high = p.ndisp_padded > 256;
  const uint16_t* const winner_k = s.winner_k;
  const uint8_t* const right_k = s.right_k + (p.width - 1 + p.right_off);  // entry of column xr at -xr
  const uint8_t* const right_k_high = s.right_k_high + (p.width - 1 + p.right_off);
  // Every pixel takes the same path, without early exits: which pixels fail is as good as random
  // from one pixel to the next.
  for (int x = 0; x < width; ++x) {
    const int k = winner_k[x];
    const int xr = x - min_disp - k;
    const bool inside = (xr >= kCensusRadiusX) & (xr < width - kCensusRadiusX);
    const int at = inside ? -xr : -kCensusRadiusX;  // a readable entry either way
    const int rk = right_k[at] | (high ? right_k_high[at] << 8 : 0);
    const bool valid = out[x] != invalid;
    const bool agree = absInt(rk - k) <= tolerance;
    out[x] = (valid & inside & agree) ? out[x] : invalid;
    const bool hidden = !inside || (!agree && rk > k);
    if (occluded) occluded[x] = (valid & hidden) ? 255 : 0;
  }
}

// Output rows' outputs: the disparity row, and the occlusion row when asked for.
struct RowOut {
  int16_t* disparity;
  uint8_t* occluded;
};

// A row's winners from all paths' sums, pixel by pixel right to left (pick): each pixel's
// winner, its uniqueness and the right image's winners (for the left-right check); then
// (finish) the sub-pixel offsets and the left-right check. A local of the row's function, whose
// members the pixel loop reads (VerticalPaths says why).
template <int NV>
struct Winners {
  const bool uniqueness, subpixel, left_right;
  const uint8_t* const rival_limit;
  const int ndisp, min_disp;
  const int16_t invalid;
  int16_t* const disparity;
  uint16_t* const winner_k;
  int32_t* const offset_num;
  int32_t* const offset_den;
  uint8_t* const right_k;       // entry q0(x) = q_start - x at right_k - x
  uint8_t* const right_k_high;
  RightWinners<NV> right;

  Winners(const Problem& p, const Scratch& s, const RowOut& out)
      : uniqueness(s.penalties->uniqueness), subpixel(p.subpixel), left_right(p.left_right_check),
        rival_limit(s.penalties->rival_limit), ndisp(p.ndisp), min_disp(p.min_disp),
        invalid(static_cast<int16_t>((p.min_disp - 1) * kDispScale)), disparity(out.disparity),
        winner_k(s.winner_k), offset_num(s.offset_num), offset_den(s.offset_den),
        right_k(s.right_k + (p.width - 1 + p.right_off + p.min_disp)),
        right_k_high(s.right_k_high + (p.width - 1 + p.right_off + p.min_disp)) {}

  SGM_INLINE void pick(int x, const cv::v_uint8* sums) {
    cv::v_uint8 lowest = sums[0];
    for (int j = 1; j < NV; ++j) lowest = cv::v_min(lowest, sums[j]);
    const uint8_t best = minOf(lowest);
    const int k = firstLaneOf<NV>(sums, minInAll(lowest));
    const bool unique = !uniqueness || noRivalAtMost<NV>(sums, k, cv::vx_setall_u8(rival_limit[best]));
    disparity[x] = unique ? static_cast<int16_t>((min_disp + k) * kDispScale) : invalid;
    keepSubpixelFit<NV>(sums, k, unique && subpixel && k > 0 && k < ndisp - 1, offset_num + x, offset_den + x);
    winner_k[x] = static_cast<uint16_t>(k);
    if (left_right) right.fold(sums, right_k - x, right_k_high - x);
  }

  // Inlined, as flush(): were `this` passed to a call, the object would have to live in memory,
  // and every byte the pixel loop stores might alias its members.
  SGM_INLINE void finish(const Problem& p, Scratch& s, const RowOut& out) const {
    if (left_right) right.flush(right_k + 1, right_k_high + 1);
    if (p.subpixel) addSubpixelOffsets(p, s, out.disparity);
    if (out.occluded) std::memset(out.occluded, 0, static_cast<size_t>(p.width));
    if (p.left_right_check) leftRightCheck(p, s, out.disparity, out.occluded);
  }
};

// Row y, right to left: the paths from below (eight paths; kUp), the path from the right, all
// paths' sums and each pixel's winner (Winners). Rows of the up pass's warm-up (`output` false)
// only advance the paths from below. With eight paths, the winners are picked in a loop of
// their own, from the sums stored over the down pass's in `down`: each pixel's winner hangs off
// the path from the right, whose steps wait on one another, and in the paths' loop it holds up
// the steps of the three paths from below (the out-of-order window fills). With five, the path
// from the right is all the loop has, and the winners fill its waits.
template <int NV, bool kUp>
void upRow(const Problem& p, Scratch& s, int y, bool output, const uint8_t* costs, uint8_t* down,
           RowOut out) {
  constexpr int D = NV * kLanes8;
  const Penalties& pen = *s.penalties;
  const uint8_t* row = imageRow(p, y);
  const uint8_t* below = y + 1 < p.height ? imageRow(p, y + 1) : row;
  rowPenalties(p, pen, row, below, +1, kUp, output, s.p2);
  // The pixel loop reads locals only (VerticalPaths says why).
  const VerticalPaths<NV> paths(s);
  const uint8_t* const p2_along = s.p2[3];
  RowPath<NV> from_right;
  cv::v_uint8 sums[NV];
  if (!kUp) {  // five paths: every row is an output row
    Winners<NV> winners(p, s, out);
    for (int x = p.width - 1; x >= 0; --x) {
      const uint8_t* cost = costs + static_cast<size_t>(x) * D;
      from_right.step(cost, paths.p1, p2_along[x]);
      for (int j = 0; j < NV; ++j)
        sums[j] = cv::vx_load(down + static_cast<size_t>(x) * D + j * kLanes8) + from_right.l[j];
      winners.pick(x, sums);
    }
    winners.finish(p, s, out);
    return;
  }
  for (int x = p.width - 1; x >= 0; --x) {
    const uint8_t* cost = costs + static_cast<size_t>(x) * D;
    paths.step(x, cost, sums);
    if (!output) continue;
    from_right.step(cost, paths.p1, p2_along[x]);
    uint8_t* sum = down + static_cast<size_t>(x) * D;
    for (int j = 0; j < NV; ++j)
      cv::v_store(sum + j * kLanes8, cv::vx_load(sum + j * kLanes8) + (sums[j] + from_right.l[j]));
  }
  if (!output) return;
  Winners<NV> winners(p, s, out);  // here, not before the paths' loop, whose registers it would take
  for (int x = p.width - 1; x >= 0; --x) {
    for (int j = 0; j < NV; ++j) sums[j] = cv::vx_load(down + static_cast<size_t>(x) * D + j * kLanes8);
    winners.pick(x, sums);
  }
  winners.finish(p, s, out);
}

RowOut rowOut(const Problem& p, const Band& band, int y) {
  return {band.out + static_cast<size_t>(y) * band.out_step,
          p.occluded ? p.occluded + static_cast<size_t>(y) * p.occluded_step : nullptr};
}

// Five paths: each row's up step (the path from the right and the winners) right after its down
// step, from one row of down sums.
template <int NV>
void matchFivePaths(const Problem& p, const Band& band, Scratch& s) {
  for (int y = band.y_start; y < band.y1; ++y) {
    const bool output = y >= band.y0;
    costRow<NV>(p, y, s.costs);
    downRow<NV>(p, s, y, output, s.costs, s.down);
    if (output) upRow<NV, false>(p, s, y, true, s.costs, s.down, rowOut(p, band, y));
    swapVerticalRows(s);
  }
}

// Eight paths: the down pass over the band (from y_start; the sums of rows y0.. kept), then the
// up pass (from y_end) back to y0. Each pass computes its rows' costs: keeping the down pass's
// would take as much memory again as its sums, and reading them back costs about what
// computing them does.
template <int NV>
void matchEightPaths(const Problem& p, const Band& band, Scratch& s) {
  const size_t row_elements = rowElements(p);
  for (int y = band.y_start; y < band.y1; ++y) {
    const bool output = y >= band.y0;
    const size_t at = output ? static_cast<size_t>(y - band.y0) * row_elements : 0;
    costRow<NV>(p, y, s.costs);
    downRow<NV>(p, s, y, output, s.costs, s.down + at);
    swapVerticalRows(s);
  }
  resetVerticalPaths(p, s);
  for (int y = band.y_end - 1; y >= band.y0; --y) {
    const bool output = y < band.y1;
    const size_t at = output ? static_cast<size_t>(y - band.y0) * row_elements : 0;
    costRow<NV>(p, y, s.costs);
    upRow<NV, true>(p, s, y, output, s.costs, s.down + at, rowOut(p, band, y));
    swapVerticalRows(s);
  }
}

template <int NV>
void matchRows(const Problem& p, const Band& band, Scratch& s) {
  if (p.paths == 8)
    matchEightPaths<NV>(p, band, s);
  else
    matchFivePaths<NV>(p, band, s);
}

void matchBand(const Problem& p, const Band& band, uint8_t* scratch) {
  Scratch s;
  layOut(p, band.y1 - band.y0, scratch, &s);
  const Penalties penalties(p);
  s.penalties = &penalties;
  resetVerticalPaths(p, s);
  switch (p.ndisp_padded / kLanes8) {
    case 1: return matchRows<1>(p, band, s);
    case 2: return matchRows<2>(p, band, s);
    case 4: return matchRows<4>(p, band, s);
    case 8: return matchRows<8>(p, band, s);
    case 16: return matchRows<16>(p, band, s);
    case 32: return matchRows<32>(p, band, s);
    default: return;  // the caller pads ndisp to lanes times a power of two
  }
}

}  // namespace

const Kernel& SGM_KERNEL_GETTER() {
  static const Kernel kernel = {SGM_KERNEL_NAME, kLanes8, censusRow, scratchBytes, matchBand};
  return kernel;
}

}  // namespace sgm_kernel
}  // namespace embedded_calibration_stereo::core
