// MeasurementRate: measurements at a set rate from streams of any frame rate, stamps with
// jitter, gaps and stamps that go back.
#include <gtest/gtest.h>

#include <algorithm>
#include <stdexcept>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/measurement_rate.h"

namespace core = embedded_calibration_stereo::core;

namespace {

// Frame stamps at `fps` for `seconds`, with up to `jitter_s` of jitter (a fixed pattern).
std::vector<double> stamps(double fps, double seconds, double jitter_s) {
  std::vector<double> t;
  for (int i = 0; i < static_cast<int>(seconds * fps); ++i) t.push_back(100.0 + i / fps + jitter_s * ((i * 7) % 3 - 1));
  return t;
}

int measured(core::MeasurementRate* rate, const std::vector<double>& times) {
  int n = 0;
  for (double t : times) n += rate->take(t) ? 1 : 0;
  return n;
}

}  // namespace

TEST(MeasurementRate, MeasuresAtTheRateAtAnyFrameRateOrEveryFrameWhenSlower) {
  const double seconds = 10.0;
  for (const double jitter : {0.0, 0.003}) {
    for (const double fps : {5.0, 10.0, 15.0, 20.0, 25.0, 29.97, 30.0, 60.0}) {
      core::MeasurementRate rate(15.0);
      const double expected = std::min(15.0, fps) * seconds;
      // Within one measurement of the rate over 10 s.
      EXPECT_NEAR(measured(&rate, stamps(fps, seconds, jitter)), expected, 1.0) << fps << " fps, jitter " << jitter;
    }
  }
}

TEST(MeasurementRate, AtTwiceTheRateEveryOtherFrame) {
  core::MeasurementRate rate(15.0);
  const std::vector<double> t = stamps(30.0, 2.0, 0.003);
  for (size_t i = 0; i < t.size(); ++i) EXPECT_EQ(rate.take(t[i]), i % 2 == 0) << i;
}

TEST(MeasurementRate, AGapDoesNotBringMeasurementsBackToBack) {
  core::MeasurementRate rate(10.0);
  const std::vector<double> before = stamps(30.0, 1.0, 0.0);
  measured(&rate, before);
  // 3 s without frames, then 30 fps again: the first frame is measured, the next one is not
  // (a tenth of a second's worth of credit, 1.5 kept through the gap).
  const double resume = before.back() + 3.0;
  EXPECT_TRUE(rate.take(resume));
  EXPECT_FALSE(rate.take(resume + 1.0 / 30.0));
  int in_next_second = 0;
  for (int i = 2; i < 32; ++i) in_next_second += rate.take(resume + i / 30.0) ? 1 : 0;
  EXPECT_NEAR(in_next_second, 10, 1);
}

TEST(MeasurementRate, StampsGoingBackStartOverAndABadRateIsRefused) {
  core::MeasurementRate rate(5.0);
  EXPECT_TRUE(rate.take(50.0));
  EXPECT_FALSE(rate.take(50.05));
  EXPECT_TRUE(rate.take(10.0)) << "a bag played again: its first frame is measured";
  EXPECT_FALSE(rate.take(10.05));
  EXPECT_THROW(core::MeasurementRate(0.0), std::invalid_argument);
  EXPECT_THROW(core::MeasurementRate(-1.0), std::invalid_argument);
}
