// The census_sgm matcher (census_sgm_matcher.h) against a brute-force reference written from its
// definition, for every kernel (instruction set), path count and filter; the kernels and thread
// counts bit-identical to each other on a real pair; bands that agree at their seams; a plane at
// a known sub-pixel disparity; parameter checks.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <sys/stat.h>
#include <vector>

#include "embedded_calibration_stereo/core/depth/census_sgm_matcher.h"

namespace embedded_calibration_stereo::core {
namespace {

// Random texture, smoothed a little so that matching is meaningful, at disparity `shift`, with
// a nearer square (disparity shift + 9) so that the paths meet a depth edge and an occlusion.
void randomPair(cv::Size size, int shift, unsigned seed, cv::Mat* left, cv::Mat* right) {
  cv::RNG rng(seed);
  cv::Mat background(size.height, size.width + 64, CV_8U), square(size.height, size.width + 64, CV_8U);
  rng.fill(background, cv::RNG::UNIFORM, 0, 256);
  rng.fill(square, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(background, background, cv::Size(3, 3), 0.8);
  cv::GaussianBlur(square, square, cv::Size(3, 3), 0.8);
  // left(x) = right(x - d): the right image starts d columns further into the scene.
  *left = background(cv::Rect(0, 0, size.width, size.height)).clone();
  *right = background(cv::Rect(shift, 0, size.width, size.height)).clone();
  const cv::Rect box(size.width / 3, size.height / 4, size.width / 3, size.height / 2);
  const int near_shift = shift + 9;
  for (int y = box.y; y < box.y + box.height; ++y)
    for (int x = box.x; x < box.x + box.width; ++x) {
      left->at<uint8_t>(y, x) = square.at<uint8_t>(y, x);
      if (x - near_shift >= 0) right->at<uint8_t>(y, x - near_shift) = square.at<uint8_t>(y, x);
    }
  cv::Mat noise(size, CV_8U);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 4);
  *right += noise;  // so that costs are not all zero at the true shift
}

// The matcher from its definition (census_sgm_matcher.h, sgm_kernel.inl), pixel by pixel:
//  - census: bit i says whether the i-th pixel of the 5x5 window (row by row, the centre left
//    out) is brighter than the centre by more than the threshold; borders repeated;
//  - cost C(x, k): Hamming distance to the right pixel x - min - k (column clamped to the image);
//  - a path's cost, from its previous pixel q (C alone where q is outside the image):
//    L(k) = min(255, C(k) + min(L_q(k), L_q(k -+ 1) + P1, min L_q + P2') - min L_q), sums of
//    bytes saturating at 255, L_q outside 0..ndisp - 1 = 255, P2' = max(P1 + 1,
//    P2 * E / (E + |I - I_q|));
//  - the sum: down = sat(sat(T + TL) + sat(TR + L)), then sat(down + sat(sat(B + BL) +
//    sat(BR + R))) with eight paths, sat(down + R) with five; disparities past ndisp up to the
//    padded count sum to all-255 paths (they take part in the rival and the right winners,
//    never win);
//  - winner: least sum, lowest index on ties; uniqueness: best * round((100 + u) * 1024) <
//    rival * 102400, the rival the least sum outside the winner and its neighbours;
//  - right winners: least sum over the left pixels that meet the right pixel, the largest
//    left x on ties; left-right check: the right pixel's census window inside the image and
//    its winner within the tolerance, occluded when it fails with a right winner above k;
//  - sub-pixel: the equiangular (V) fit through the sums a, b, c at k - 1, k, k + 1:
//    (a - c) * 16 / (2 (max(a, c) - b)) as a float, rounded half away from zero.
struct Reference {
  CensusSgmParams p;
  int ndisp_padded;  // as the kernel pads: its lanes times a power of two

  uint32_t census(const cv::Mat& im, int y, int x) const {
    const auto at = [&](int yy, int xx) {
      return im.at<uint8_t>(std::clamp(yy, 0, im.rows - 1), std::clamp(xx, 0, im.cols - 1));
    };
    uint32_t code = 0;
    int bit = 0;
    for (int dy = -2; dy <= 2; ++dy)
      for (int dx = -2; dx <= 2; ++dx) {
        if (dy == 0 && dx == 0) continue;
        code |= static_cast<uint32_t>(at(y + dy, x + dx) > std::min(255, at(y, x) + p.census_threshold))
                << bit++;
      }
    return code;
  }

  int p2(int a, int b) const {
    const int d = std::abs(a - b);
    const int v = p.edge_scale > 0 ? p.P2 * p.edge_scale / (p.edge_scale + d) : p.P2;
    return std::max(v, p.P1 + 1);
  }

  // One path over the whole image in the direction (dy, dx) from the previous pixel.
  std::vector<int> path(const cv::Mat& left, const std::vector<int>& cost, int dy, int dx) const {
    const int W = left.cols, H = left.rows, D = ndisp_padded;
    std::vector<int> L(static_cast<size_t>(W) * H * D, 255);
    const int y0 = dy > 0 ? 0 : H - 1, y1 = dy > 0 ? H : -1, ys = dy > 0 ? 1 : -1;
    const int x0 = dx > 0 ? 0 : W - 1, x1 = dx > 0 ? W : -1, xs = dx > 0 ? 1 : -1;
    // Rows in the path's order; within a row, columns in the path's order (vertical paths read
    // only the previous row, so any order serves them).
    const int ry0 = dy != 0 ? y0 : 0, ry1 = dy != 0 ? y1 : H, rys = dy != 0 ? ys : 1;
    for (int y = ry0; y != ry1; y += rys)
      for (int x = (dy == 0 ? x0 : 0); x != (dy == 0 ? x1 : W); x += (dy == 0 ? xs : 1)) {
        const int qy = y - dy, qx = x - dx;
        int* out = &L[(static_cast<size_t>(y) * W + x) * D];
        const int* c = &cost[(static_cast<size_t>(y) * W + x) * D];
        if (qy < 0 || qy >= H || qx < 0 || qx >= W) {
          for (int k = 0; k < D; ++k) out[k] = c[k];
          continue;
        }
        const int* q = &L[(static_cast<size_t>(qy) * W + qx) * D];
        const int m = *std::min_element(q, q + D);
        const int jump = std::min(255, m + p2(left.at<uint8_t>(y, x), left.at<uint8_t>(qy, qx)));
        for (int k = 0; k < D; ++k) {
          const int below = k > 0 ? q[k - 1] : 255, above = k + 1 < D ? q[k + 1] : 255;
          const int step = std::min(255, std::min(below, above) + p.P1);
          out[k] = std::min(255, c[k] + (std::min({q[k], step, jump}) - m));
        }
      }
    return L;
  }

  static int sat(int v) { return std::min(v, 255); }

  // Census costs of every pixel and padded disparity (255 past num_disparities).
  std::vector<int> costs(const cv::Mat& left, const cv::Mat& right) const {
    const int W = left.cols, H = left.rows, D = ndisp_padded;
    std::vector<int> cost(static_cast<size_t>(W) * H * D, 255);
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x)
        for (int k = 0; k < p.num_disparities; ++k) {
          const int xr = std::clamp(x - p.min_disparity - k, 0, W - 1);
          cost[(static_cast<size_t>(y) * W + x) * D + k] =
              __builtin_popcount(census(left, y, x) ^ census(right, y, xr));
        }
    return cost;
  }

  // All paths' sums, saturating as the definition above says.
  std::vector<int> sums(const cv::Mat& left, const std::vector<int>& cost) const {
    const auto T = path(left, cost, 1, 0), TL = path(left, cost, 1, 1), TR = path(left, cost, 1, -1);
    const auto Lp = path(left, cost, 0, 1), R = path(left, cost, 0, -1);
    std::vector<int> B, BL, BR;
    if (p.paths == 8) B = path(left, cost, -1, 0), BL = path(left, cost, -1, 1), BR = path(left, cost, -1, -1);
    std::vector<int> S(cost.size());
    for (size_t i = 0; i < S.size(); ++i) {
      const int down = sat(sat(T[i] + TL[i]) + sat(TR[i] + Lp[i]));
      S[i] = sat(down + (p.paths == 8 ? sat(sat(B[i] + BL[i]) + sat(BR[i] + R[i])) : R[i]));
    }
    return S;
  }

  // The right image's winners of one row of sums: least sum, the largest left x on ties.
  std::vector<int> rightWinners(const int* row, int W) const {
    const int D = ndisp_padded;
    std::vector<int> right_best(W, 1 << 30), right_k(W, -1);
    for (int x = W - 1; x >= 0; --x)
      for (int k = 0; k < D; ++k) {
        const int xr = x - p.min_disparity - k;
        if (xr >= 0 && xr < W && row[x * D + k] < right_best[xr]) {
          right_best[xr] = row[x * D + k];
          right_k[xr] = k;
        }
      }
    return right_k;
  }

  // One pixel's disparity (1/16 px) from its sums s, or `invalid` when not unique; *k its winner.
  int pixelDisparity(const int* s, int invalid, int* winner) const {
    const int k = static_cast<int>(std::min_element(s, s + p.num_disparities) - s);
    *winner = k;
    int rival = 1 << 30;
    for (int j = 0; j < ndisp_padded; ++j)
      if (j < k - 1 || j > k + 1) rival = std::min(rival, s[j]);
    const int64_t scale = static_cast<int64_t>((100.0 + p.uniqueness_ratio) * 1024 + 0.5);
    if (p.uniqueness_ratio > 0 && !(s[k] * scale < static_cast<int64_t>(rival) * 102400)) return invalid;
    int value = (p.min_disparity + k) * 16;
    if (p.subpixel && k > 0 && k < p.num_disparities - 1) {
      const int a = s[k - 1], b = s[k], c = s[k + 1], denom = a > c ? a - b : c - b;
      if (denom > 0) {
        const float offset = static_cast<float>((a - c) * 16) / static_cast<float>(2 * denom);
        value += static_cast<int>(offset >= 0 ? offset + 0.5f : offset - 0.5f);
      }
    }
    return value;
  }

  cv::Mat compute(const cv::Mat& left, const cv::Mat& right, cv::Mat* occluded) const {
    const int W = left.cols, H = left.rows, D = ndisp_padded;
    const std::vector<int> S = sums(left, costs(left, right));
    cv::Mat out(left.size(), CV_16S);
    occluded->create(left.size(), CV_8U);
    *occluded = 0;
    const int invalid = (p.min_disparity - 1) * 16;
    for (int y = 0; y < H; ++y) {
      const int* row = &S[static_cast<size_t>(y) * W * D];
      const std::vector<int> right_k = rightWinners(row, W);
      std::vector<int> winner(W);
      for (int x = 0; x < W; ++x)
        out.at<int16_t>(y, x) = static_cast<int16_t>(pixelDisparity(row + x * D, invalid, &winner[x]));
      if (!p.left_right_check) continue;
      for (int x = 0; x < W; ++x) {
        if (out.at<int16_t>(y, x) == invalid) continue;
        const int k = winner[x], xr = x - p.min_disparity - k;
        const bool inside = xr >= 2 && xr < W - 2;
        if (inside && std::abs(right_k[xr] - k) <= p.left_right_tolerance) continue;
        out.at<int16_t>(y, x) = static_cast<int16_t>(invalid);
        if (!inside || right_k[xr] > k) occluded->at<uint8_t>(y, x) = 255;
      }
    }
    return out;
  }
};

int paddedCount(int ndisp, const std::string& kernel) {
  int n = kernel == "avx512" ? 64 : (kernel == "avx2" ? 32 : 16);
  while (n < ndisp) n *= 2;
  return n;
}

struct Case {
  int min_disparity, num_disparities, paths, census_threshold;
  double uniqueness;
  bool left_right_check, subpixel;
  int edge_scale = 16;  // 0: P2 constant; past 2^24 / P2 the kernel takes P2 from its table
};

// Every kernel's result and occlusions equal the reference's on a random pair (randomPair) for
// the case `c`; returns how many kernels it compared.
int compareKernelsWithReference(const Case& c, cv::Size size, int shift, unsigned seed) {
  int compared = 0;
  for (const std::string& kernel : censusSgmKernelNames()) {
    cv::Mat left, right;
    randomPair(size, shift, seed, &left, &right);
    CensusSgmParams p;
    p.kernel = kernel;
    p.min_disparity = c.min_disparity;
    p.num_disparities = c.num_disparities;
    p.paths = c.paths;
    p.census_threshold = c.census_threshold;
    p.uniqueness_ratio = c.uniqueness;
    p.left_right_check = c.left_right_check;
    p.subpixel = c.subpixel;
    p.edge_scale = c.edge_scale;
    const Reference ref{p, paddedCount(c.num_disparities, kernel)};
    cv::Mat expected_occluded, got, got_occluded;
    const cv::Mat expected = ref.compute(left, right, &expected_occluded);
    computeCensusSgmDisparity16(left, right, p, &got, &got_occluded);
    const std::string label = kernel + " min " + std::to_string(c.min_disparity) + " n " +
                              std::to_string(c.num_disparities) + " paths " + std::to_string(c.paths);
    EXPECT_EQ(cv::countNonZero(expected != got), 0) << label;
    EXPECT_EQ(cv::countNonZero(expected_occluded != got_occluded), 0) << label << " (occlusions)";
    const int invalid = (c.min_disparity - 1) * 16;
    EXPECT_GT(cv::countNonZero(got != invalid), 0.5 * got.total()) << label << ": mostly invalid";
    ++compared;
  }
  return compared;
}

// Every kernel equals the reference on images of one band (at most 120 rows), with sizes that
// leave partial vectors, negative minimum disparities and padded disparity counts; P2 constant,
// lowered steeply across intensity steps (edge scale 3), and past the float division's range.
TEST(CensusSgm, EveryKernelMatchesTheReference) {
  const Case cases[] = {
      {0, 64, 8, 1, 0, true, true},    {0, 64, 5, 0, 10, true, true},  {-8, 48, 8, 3, 5, true, true},
      {0, 96, 8, 1, 0, false, false},  {4, 48, 5, 1, 0, true, false},  {0, 64, 8, 0, 15, false, true},
      {0, 64, 8, 1, 0, true, true, 0}, {0, 64, 8, 1, 0, true, true, 3}, {0, 64, 8, 1, 0, true, true, 400000},
  };
  int compared = 0;
  for (const Case& c : cases) compared += compareKernelsWithReference(c, cv::Size(157, 61), 20, 7 + compared);
  EXPECT_GE(compared, 9);
}

// More than 256 disparities: the winners' indices past 255 (a byte's range) on both sides of
// the left-right check. The pair's disparity 20 is index 270 from a minimum of -250.
TEST(CensusSgm, WinnersPastIndex255MatchTheReference) {
  int compared = 0;
  for (const int paths : {8, 5})
    compared += compareKernelsWithReference({-250, 288, paths, 1, 10, true, true}, cv::Size(157, 24),
                                            20, 31 + paths);
  EXPECT_GE(compared, 2);
}

bool exists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0;
}

// On a real pair: every kernel and thread count gives the same bits; the bands (fixed height,
// their paths started some rows outside them) agree with one band over the whole image almost
// everywhere, which the reference computes.
TEST(CensusSgm, KernelsThreadsAndBandsAgree) {
  const std::string dir = std::string(ECS_SHARED_DATA_DIR) + "/middlebury/teddy/";
  if (!exists(dir + "im2.png")) GTEST_SKIP() << "Teddy not found under " << dir;
  cv::Mat left = cv::imread(dir + "im2.png", cv::IMREAD_GRAYSCALE);
  cv::Mat right = cv::imread(dir + "im6.png", cv::IMREAD_GRAYSCALE);
  cv::resize(left, left, cv::Size(), 0.5, 0.5, cv::INTER_AREA);  // 225x188: two bands
  cv::resize(right, right, cv::Size(), 0.5, 0.5, cv::INTER_AREA);
  CensusSgmParams p;
  p.num_disparities = 32;
  p.kernel = "baseline";
  const int threads = cv::getNumThreads();
  cv::Mat first;
  computeCensusSgmDisparity16(left, right, p, &first);
  for (const std::string& kernel : censusSgmKernelNames())
    for (const int n : {1, 2, 3}) {
      cv::setNumThreads(n);
      p.kernel = kernel;
      cv::Mat d;
      computeCensusSgmDisparity16(left, right, p, &d);
      EXPECT_EQ(cv::countNonZero(d != first), 0) << kernel << ", " << n << " threads";
    }
  cv::setNumThreads(threads);
  cv::Mat occluded;
  const cv::Mat whole = Reference{p, paddedCount(32, p.kernel)}.compute(left, right, &occluded);
  const double same = 1.0 - static_cast<double>(cv::countNonZero(whole != first)) / first.total();
  EXPECT_GE(same, 0.97) << "banded and single-band results differ too often";
  std::printf("[ census_sgm ] bands agree with one band at %.2f %% of the pixels\n", 100 * same);
}

// A plane at a known sub-pixel disparity: valid almost everywhere; the sub-pixel estimate,
// biased towards the whole pixel as semi-global sums are, within the bounds measured for it
// (mean -0.14 px, rms 0.19 px, 80 % within a quarter pixel) with a margin.
TEST(CensusSgm, PlaneAtSubpixelDisparity) {
  cv::RNG rng(3);
  cv::Mat texture(100, 300, CV_8U);
  rng.fill(texture, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(texture, texture, cv::Size(5, 5), 1.2);
  const double shift = 17.4;
  cv::Mat map_x(texture.size(), CV_32F), map_y(texture.size(), CV_32F);
  for (int y = 0; y < texture.rows; ++y)
    for (int x = 0; x < texture.cols; ++x) {
      map_x.at<float>(y, x) = static_cast<float>(x - shift);
      map_y.at<float>(y, x) = static_cast<float>(y);
    }
  // The right image is the texture; left(x) = texture(x - d).
  cv::Mat left;
  cv::remap(texture, left, map_x, map_y, cv::INTER_CUBIC, cv::BORDER_REFLECT);
  CensusSgmParams p;
  cv::Mat d;
  computeCensusSgmDisparity16(left, texture, p, &d);
  int valid = 0, good = 0;
  double sum = 0, sum2 = 0;
  for (int y = 5; y < d.rows - 5; ++y)
    for (int x = 30; x < d.cols - 5; ++x) {
      const int v = d.at<int16_t>(y, x);
      if (v < 0) continue;
      ++valid;
      good += std::abs(v / 16.0 - shift) <= 0.25;
      sum += v / 16.0 - shift;
      sum2 += (v / 16.0 - shift) * (v / 16.0 - shift);
    }
  std::printf("[ census_sgm ] plane at %.2f: mean error %.3f px, rms %.3f px, %.1f %% within 0.25 px\n", shift, sum / valid, std::sqrt(sum2 / valid), 100.0 * good / valid);
  const int total = (d.rows - 10) * (d.cols - 35);
  EXPECT_GE(valid, 0.95 * total);
  EXPECT_LE(std::abs(sum / valid), 0.2);
  EXPECT_LE(std::sqrt(sum2 / valid), 0.25);
  EXPECT_GE(good, 0.7 * valid);
}

TEST(CensusSgm, RefusesBadParametersAndInputs) {
  cv::Mat left(40, 120, CV_8U, cv::Scalar(0)), right = left.clone(), d;
  CensusSgmParams p;
  EXPECT_EQ(p.validate(), "");
  for (const auto& bad : std::vector<void (*)(CensusSgmParams*)>{
           [](CensusSgmParams* q) { q->paths = 4; },
           [](CensusSgmParams* q) { q->num_disparities = 40; },
           [](CensusSgmParams* q) { q->num_disparities = 1024; },
           [](CensusSgmParams* q) { q->P2 = q->P1; },
           [](CensusSgmParams* q) { q->uniqueness_ratio = -1; },
           [](CensusSgmParams* q) { q->census_threshold = 256; },
           [](CensusSgmParams* q) { q->kernel = "neon9"; }}) {
    CensusSgmParams q;
    bad(&q);
    EXPECT_THROW(computeCensusSgmDisparity16(left, right, q, &d), std::invalid_argument);
  }
  EXPECT_THROW(computeCensusSgmDisparity16(left, cv::Mat(40, 121, CV_8U), p, &d), std::invalid_argument);
  EXPECT_THROW(computeCensusSgmDisparity16(left, cv::Mat(40, 120, CV_16U), p, &d), std::invalid_argument);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
