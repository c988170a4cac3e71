// The simulated sensor's normal deviates (src/core/sim/sensor_noise.h) against the normal
// distribution itself (std::erfc), and their independence between pixels, rows and seeds.
#include <gtest/gtest.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "../../src/core/sim/sensor_noise.h"

namespace {

using ecs::sim::fillNormalRow;

constexpr int kWidth = 1001;  // odd: the vector loop and the scalar tail both draw

std::vector<float> draw(uint64_t seed, int rows) {
  std::vector<float> all(static_cast<size_t>(rows) * kWidth);
  for (int r = 0; r < rows; ++r) fillNormalRow(seed, r, kWidth, all.data() + static_cast<size_t>(r) * kWidth);
  return all;
}

double normalCdf(double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); }

double correlation(const float* a, const float* b, size_t n) {
  double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  for (size_t i = 0; i < n; ++i) {
    sa += a[i];
    sb += b[i];
    saa += a[i] * a[i];
    sbb += b[i] * b[i];
    sab += a[i] * b[i];
  }
  const double ma = sa / n, mb = sb / n;
  return (sab / n - ma * mb) / std::sqrt((saa / n - ma * ma) * (sbb / n - mb * mb));
}

TEST(SensorNoise, DeviatesFollowTheNormalDistribution) {
  const std::vector<float> x = draw(12345, 2000);  // two million deviates
  double mean = 0, m2 = 0, m4 = 0;
  for (float v : x) mean += v;
  mean /= x.size();
  for (float v : x) {
    const double d = v - mean;
    m2 += d * d;
    m4 += d * d * d * d;
  }
  m2 /= x.size();
  m4 /= x.size();
  // The empirical CDF against the normal's at every 0.05 sigma in [-4, 4] (Kolmogorov-Smirnov).
  std::vector<float> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  double ks = 0.0, below_3 = 0.0, largest = 0.0;
  for (double q = -4.0; q <= 4.0; q += 0.05) {
    const double below = static_cast<double>(std::lower_bound(sorted.begin(), sorted.end(), q) - sorted.begin());
    ks = std::max(ks, std::abs(below / sorted.size() - normalCdf(q)));
  }
  below_3 = static_cast<double>(std::lower_bound(sorted.begin(), sorted.end(), -3.0) - sorted.begin()) / sorted.size();
  largest = std::max(-sorted.front(), sorted.back());
  std::printf("[ figures  ] %zu deviates: mean %.5f variance %.5f kurtosis %.4f; max |CDF - normal| %.5f; "
              "P(x < -3) %.6f (normal %.6f); largest |x| %.2f\n", x.size(), mean, m2, m4 / (m2 * m2), ks,
              below_3, normalCdf(-3.0), largest);
  EXPECT_NEAR(mean, 0.0, 0.003);
  EXPECT_NEAR(m2, 1.0, 0.003);
  EXPECT_NEAR(m4 / (m2 * m2), 3.0, 0.02) << "the normal's tails, not a lighter distribution's";
  EXPECT_LT(ks, 0.002);
  EXPECT_NEAR(below_3, normalCdf(-3.0), 0.0002);
  EXPECT_GT(largest, 3.5);
}

TEST(SensorNoise, PixelsRowsAndSeedsAreIndependent) {
  const int rows = 400;
  const std::vector<float> a = draw(1, rows), b = draw(2, rows);
  const size_t n = a.size();
  // Pooled over all rows (400k pairs: one standard error is 0.0016).
  const double along = std::abs(correlation(a.data(), a.data() + 1, n - 1));
  const double every_fourth = std::abs(correlation(a.data(), a.data() + 4, n - 4));  // the same stream
  const double across = std::abs(correlation(a.data(), a.data() + kWidth, n - kWidth));
  const double seeds = std::abs(correlation(a.data(), b.data(), n));
  std::printf("[ figures  ] |correlation| over %d rows of %d: along a row %.4f, 4 columns apart %.4f, between rows "
              "%.4f, between seeds %.4f\n", rows, kWidth, along, every_fourth, across, seeds);
  EXPECT_LT(along, 0.005);
  EXPECT_LT(every_fourth, 0.005);
  EXPECT_LT(across, 0.005);
  EXPECT_LT(seeds, 0.005);
}

TEST(SensorNoise, ARowIsTheSameWhateverItsWidthOrWhoDrawsIt) {
  std::vector<float> wide(kWidth), narrow(37), again(kWidth);
  fillNormalRow(99, 17, kWidth, wide.data());
  fillNormalRow(99, 17, 37, narrow.data());
  fillNormalRow(99, 17, kWidth, again.data());
  for (int c = 0; c < 37; ++c) EXPECT_EQ(narrow[c], wide[c]) << "column " << c;
  EXPECT_EQ(again, wide);
  std::vector<float> other(kWidth);
  fillNormalRow(99, 18, kWidth, other.data());
  EXPECT_NE(other, wide);
}

}  // namespace
