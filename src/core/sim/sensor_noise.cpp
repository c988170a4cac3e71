#include "sensor_noise.h"

#include <cmath>
#include <opencv2/core/hal/intrin.hpp>
#include <vector>

namespace ecs {
namespace sim {
namespace {

constexpr int kBinBits = 12;
constexpr int kBins = 1 << kBinBits;
constexpr int kStreams = 4;

double normalCdf(double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); }
double normalPdf(double x) { return std::exp(-0.5 * x * x) / std::sqrt(2.0 * M_PI); }

// x with normalCdf(x) = p, by bisection (p in (0, 1); built once, so speed does not matter).
double inverseNormalCdf(double p) {
  double lo = -12.0, hi = 12.0;
  for (int i = 0; i < 80; ++i) {
    const double mid = 0.5 * (lo + hi);
    (normalCdf(mid) < p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

// Bin k holds the deviates from knot k to knot k + 1, uniformly: pairs (knot k, width of bin k).
std::vector<float> buildTable() {
  std::vector<double> knot(kBins + 1);
  for (int j = 1; j < kBins; ++j) knot[j] = inverseNormalCdf(static_cast<double>(j) / kBins);
  // The outer bins' means are the tails' conditional means, -+ kBins pdf(knot 1).
  knot[0] = -2.0 * kBins * normalPdf(knot[1]) - knot[1];
  knot[kBins] = -knot[0];
  double second_moment = 0.0;
  for (int k = 0; k < kBins; ++k)
    second_moment += (knot[k] * knot[k] + knot[k] * knot[k + 1] + knot[k + 1] * knot[k + 1]) / 3.0;
  const double scale = 1.0 / std::sqrt(second_moment / kBins);
  std::vector<float> table(2 * kBins);
  for (int k = 0; k < kBins; ++k) {
    table[2 * k] = static_cast<float>(scale * knot[k]);
    table[2 * k + 1] = static_cast<float>(scale * (knot[k + 1] - knot[k]));
  }
  return table;
}

const float* table() {
  static const std::vector<float> t = buildTable();
  return t.data();
}

// xoshiro128+ (Blackman and Vigna): four 32-bit words of state per stream.
struct Xoshiro128Plus {
  uint32_t s[4];
  uint32_t next() {
    const uint32_t result = s[0] + s[3], t = s[1] << 9;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = (s[3] << 11) | (s[3] >> 21);
    return result;
  }
};

float deviate(const float* t, uint32_t u) {
  const uint32_t bin = u >> (32 - kBinBits);
  const float within = static_cast<float>(u & ((1u << (32 - kBinBits)) - 1)) * (1.0f / (1u << (32 - kBinBits)));
  return t[2 * bin] + within * t[2 * bin + 1];
}

}  // namespace

uint64_t mixSeed(uint64_t x) {
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

void fillNormalRow(uint64_t seed, int row, int width, float* out) {
  const float* t = table();
  Xoshiro128Plus streams[kStreams];
  uint64_t key = mixSeed(seed ^ mixSeed(static_cast<uint64_t>(row) + 1));
  for (Xoshiro128Plus& g : streams) {
    for (int w = 0; w < 4; w += 2) {
      key = mixSeed(key);
      g.s[w] = static_cast<uint32_t>(key);
      g.s[w + 1] = static_cast<uint32_t>(key >> 32);
    }
  }
  int col = 0;
#if CV_SIMD128
  // The four streams as the lanes of one vector: state word w of stream i in lane i of s[w].
  cv::v_uint32x4 s[4];
  for (int w = 0; w < 4; ++w)
    s[w] = cv::v_uint32x4(streams[0].s[w], streams[1].s[w], streams[2].s[w], streams[3].s[w]);
  const cv::v_uint32x4 fraction_mask = cv::v_setall_u32((1u << (32 - kBinBits)) - 1);
  const cv::v_float32x4 fraction_scale = cv::v_setall_f32(1.0f / (1u << (32 - kBinBits)));
  for (; col + 4 <= width; col += 4) {
    const cv::v_uint32x4 u = s[0] + s[3], shifted = s[1] << 9;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= shifted;
    s[3] = (s[3] << 11) | (s[3] >> 21);
    alignas(16) uint32_t bins[4];
    cv::v_store_aligned(bins, u >> (32 - kBinBits));
    alignas(16) float pairs[8];
    for (int lane = 0; lane < 4; ++lane) __builtin_memcpy(pairs + 2 * lane, t + 2 * bins[lane], 8);
    cv::v_float32x4 knot, width_of_bin;
    cv::v_load_deinterleave(pairs, knot, width_of_bin);
    // The low bits are below 2^20: exact as signed integers.
    const cv::v_float32x4 within = cv::v_cvt_f32(cv::v_reinterpret_as_s32(u & fraction_mask)) * fraction_scale;
    cv::v_store(out + col, cv::v_fma(within, width_of_bin, knot));
  }
  alignas(16) uint32_t words[4][4];
  for (int w = 0; w < 4; ++w) cv::v_store_aligned(words[w], s[w]);
  for (int i = 0; i < kStreams; ++i)
    for (int w = 0; w < 4; ++w) streams[i].s[w] = words[w][i];
#endif
  for (; col < width; ++col) out[col] = deviate(t, streams[col % kStreams].next());
}

}  // namespace sim
}  // namespace ecs
