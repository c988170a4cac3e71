// The sad matcher's kernels (sad_matcher.h): each one against a brute-force reference written
// from the definition (the winner alone; then with uniqueness, left-right check and sub-pixel
// vertex on), and the wide kernels bit-identical to the baseline one with every filter on, over
// sizes that leave partial pixel blocks and negative minimum disparities.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/core/fast_math.hpp>  // cvRound
#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/depth/sad_matcher.h"

namespace embedded_calibration_stereo::core {
namespace {

// Random texture, smoothed a little so that matching is meaningful, plus a horizontal shift.
void randomPair(cv::Size size, int shift, unsigned seed, cv::Mat* left, cv::Mat* right) {
  cv::Mat wide(size.height, size.width + std::abs(shift), CV_8U);
  cv::RNG rng(seed);
  rng.fill(wide, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(wide, wide, cv::Size(3, 3), 0.8);
  const int off = std::abs(shift);
  *left = wide(cv::Rect(shift >= 0 ? off : 0, 0, size.width, size.height)).clone();
  *right = wide(cv::Rect(shift >= 0 ? 0 : off, 0, size.width, size.height)).clone();
  cv::Mat noise(size, CV_8U);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 6);
  *right += noise;  // so that costs are not all zero at the true shift
}

// x-Sobel clipped to +-cap, shifted to 0..2cap: the matcher's documented prefilter.
cv::Mat prefilter(const cv::Mat& image, int cap) {
  cv::Mat dx;
  cv::Sobel(image, dx, CV_16S, 1, 0, 3, 1, 0, cv::BORDER_REPLICATE);
  cv::Mat out;
  cv::Mat(cv::min(cv::max(dx, -cap), cap)).convertTo(out, CV_8U, 1.0, cap);
  return out;
}

// The whole matcher from its definition (sad_matcher.h): brute-force window costs; winner k
// (lowest on ties); uniqueness (no index but k and its two neighbours costs at most
// best + int(best * ratio / 100)); left-right check (the right pixel's own winner, over the left
// pixels inside the image, within the tolerance of k); parabola vertex through the costs at
// k - 1, k, k + 1, rounded to 1/16 px with cvRound as the documented formula
// 16 * d + round(8 * (prev - next) / (prev + next - 2 best)). With uniqueness 0 and the check and
// sub-pixel off: the plain winner, invalid where the matched right pixel falls outside the image.
cv::Mat bruteForce(const cv::Mat& left, const cv::Mat& right, const SadMatcherParams& p) {
  const cv::Mat l = prefilter(left, p.prefilter_cap), r = prefilter(right, p.prefilter_cap);
  const int W = left.cols, H = left.rows, radius = p.window_size / 2, D = p.num_disparities;
  constexpr int kMaxCost = 0x7FFF;
  const auto at = [](const cv::Mat& m, int y, int x) {
    return static_cast<int>(m.at<uint8_t>(std::clamp(y, 0, m.rows - 1), std::clamp(x, 0, m.cols - 1)));
  };
  cv::Mat out(left.size(), CV_16S);
  std::vector<int> cost(static_cast<size_t>(W) * D);  // [x][k] of one row
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x)
      for (int k = 0; k < D; ++k) {
        int c = 0;
        for (int j = -radius; j <= radius; ++j)
          for (int i = -radius; i <= radius; ++i)
            c += std::abs(at(l, y + j, x + i) - at(r, y + j, x + i - p.min_disparity - k));
        cost[x * D + k] = c;
      }
    // The right image's winner at xr: the lowest cost over the left pixels x = xr + d inside.
    std::vector<int> right_best(W, kMaxCost), right_k(W, 0);
    for (int x = 0; x < W; ++x)
      for (int k = 0; k < D; ++k) {
        const int xr = x - p.min_disparity - k;
        if (xr >= 0 && xr < W && cost[x * D + k] < right_best[xr]) {
          right_best[xr] = cost[x * D + k];
          right_k[xr] = k;
        }
      }
    for (int x = 0; x < W; ++x) {
      const int* c = &cost[x * D];
      const int k = static_cast<int>(std::min_element(c, c + D) - c);
      const int best = c[k], prev = k > 0 ? c[k - 1] : kMaxCost, next = k < D - 1 ? c[k + 1] : kMaxCost;
      const int xr = x - p.min_disparity - k;
      bool ok = xr >= 0 && xr < W;
      if (p.uniqueness_ratio > 0) {
        const int thresh = std::min(best + static_cast<int>(best * static_cast<float>(p.uniqueness_ratio / 100.0)),
                                    kMaxCost - 1);
        for (int i = 0; i < D; ++i) ok = ok && (std::abs(i - k) <= 1 || c[i] > thresh);
      }
      if (p.left_right_check) ok = ok && std::abs(right_k[xr] - k) <= p.left_right_tolerance;
      int d16 = (p.min_disparity + k) * 16;
      if (p.subpixel && k > 0 && k < D - 1 && prev + next - 2 * best > 0)
        d16 += cvRound(8.0f * (prev - next) / static_cast<float>(prev + next - 2 * best));
      out.at<int16_t>(y, x) = static_cast<int16_t>(ok ? d16 : (p.min_disparity - 1) * 16);
    }
  }
  return out;
}

bool identical(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && a.isContinuous() && b.isContinuous() &&
         std::memcmp(a.data, b.data, a.total() * a.elemSize()) == 0;
}

struct KernelCase {
  int width, height, shift, window, min_disparity, num_disparities;
};

std::vector<KernelCase> cases() {
  return {{101, 37, 9, 5, 0, 32}, {75, 29, -4, 7, -16, 32}, {133, 23, 21, 3, 2, 48},
          {90, 31, 5, 15, 0, 16}};
}

// The case's window and disparities; every other parameter at its default.
SadMatcherParams paramsOf(const KernelCase& c) {
  SadMatcherParams p;
  p.window_size = c.window;
  p.min_disparity = c.min_disparity;
  p.num_disparities = c.num_disparities;
  return p;
}

std::string describe(const KernelCase& c) {
  return std::to_string(c.width) + "x" + std::to_string(c.height) + " window " + std::to_string(c.window) +
         " disparities " + std::to_string(c.min_disparity) + "+" + std::to_string(c.num_disparities);
}

int countDifferent(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat differ;
  cv::compare(a, b, differ, cv::CMP_NE);
  return cv::countNonZero(differ);
}

TEST(SadKernelTest, EveryKernelEqualsTheBruteForceWinner) {
  for (const std::string& kernel : sadKernelNames())
    for (const KernelCase& c : cases()) {
      cv::Mat left, right;
      randomPair(cv::Size(c.width, c.height), c.shift, 7 + c.width, &left, &right);
      SadMatcherParams p = paramsOf(c);
      p.kernel = kernel;
      p.uniqueness_ratio = 0;
      p.left_right_check = false;
      p.subpixel = false;
      EXPECT_EQ(countDifferent(computeSadDisparity16(left, right, p), bruteForce(left, right, p)), 0)
          << kernel << " " << describe(c);
    }
}

TEST(SadKernelTest, EveryKernelEqualsTheBruteForceWithEveryFilterOn) {
  for (const std::string& kernel : sadKernelNames())
    for (const KernelCase& c : cases())
      for (const double uniqueness : {0.0, 10.0}) {
        cv::Mat left, right;
        randomPair(cv::Size(c.width, c.height), c.shift, 11 + c.width, &left, &right);
        SadMatcherParams p = paramsOf(c);
        p.kernel = kernel;
        p.uniqueness_ratio = uniqueness;
        p.left_right_check = true;
        p.left_right_tolerance = 1;
        p.subpixel = true;
        const cv::Mat expected = bruteForce(left, right, p);
        int valid = 0, fractional = 0;
        for (int i = 0; i < static_cast<int>(expected.total()); ++i) {
          const int16_t v = expected.at<int16_t>(i);
          valid += v >= c.min_disparity * 16 - 8;
          fractional += v >= c.min_disparity * 16 - 8 && v % 16 != 0;
        }
        ASSERT_GT(valid, static_cast<int>(expected.total()) / 4) << "too few matches to compare";
        ASSERT_GT(fractional, valid / 4) << "too few sub-pixel values to compare";
        EXPECT_EQ(countDifferent(computeSadDisparity16(left, right, p), expected), 0)
            << kernel << " " << describe(c) << " uniqueness " << uniqueness;
      }
}

TEST(SadKernelTest, WideKernelsEqualTheBaselineWithEveryFilterOn) {
  const std::vector<std::string> kernels = sadKernelNames();
  ASSERT_EQ(kernels.front(), "baseline");
  if (kernels.size() == 1) GTEST_SKIP() << "only the baseline kernel runs on this machine";
  std::vector<KernelCase> all = cases();
  all.push_back({752, 480, 23, 11, 0, 64});  // the product's frame size and defaults
  for (const KernelCase& c : all)
    for (const double uniqueness : {0.0, 5.0, 15.0}) {
      cv::Mat left, right;
      randomPair(cv::Size(c.width, c.height), c.shift, 99 + c.height, &left, &right);
      SadMatcherParams p = paramsOf(c);
      p.uniqueness_ratio = uniqueness;
      p.left_right_check = true;
      p.subpixel = true;
      p.kernel = "baseline";
      const cv::Mat baseline = computeSadDisparity16(left, right, p);
      int valid = 0;
      for (int i = 0; i < static_cast<int>(baseline.total()); ++i)
        valid += baseline.at<int16_t>(i) >= c.min_disparity * 16;
      EXPECT_GT(valid, baseline.total() / 20) << "too few matches to compare";
      for (size_t k = 1; k < kernels.size(); ++k) {
        p.kernel = kernels[k];
        EXPECT_TRUE(identical(computeSadDisparity16(left, right, p), baseline))
            << kernels[k] << " differs from baseline, " << describe(c) << " uniqueness " << uniqueness;
      }
    }
}

TEST(SadKernelTest, AutoTakesTheWidestAndUnknownKernelsAreRefused) {
  cv::Mat left, right;
  randomPair(cv::Size(120, 40), 6, 3, &left, &right);
  SadMatcherParams p;
  p.num_disparities = 32;
  p.kernel = sadKernelNames().back();
  const cv::Mat widest = computeSadDisparity16(left, right, p);
  p.kernel = "auto";
  EXPECT_TRUE(identical(computeSadDisparity16(left, right, p), widest));
  p.kernel = "avx512";
  EXPECT_THROW(computeSadDisparity16(left, right, p), std::invalid_argument);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
