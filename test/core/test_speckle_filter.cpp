// SpeckleFilter against its reference, cv::filterSpeckles: the outputs must be equal pixel for
// pixel on random piecewise-smooth maps, on a real matcher output full of speckles, on
// sub-matrices and over the parameter range; plus a worked example with the size threshold and
// 4-connectivity, and the input checks.
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/depth/sad_matcher.h"
#include "embedded_calibration_stereo/core/depth/speckle_filter.h"

namespace embedded_calibration_stereo::core {
namespace {

// Piecewise-smooth fixed-point disparity: random rectangles of constant or sloped disparity,
// salt noise of random values, and invalid pixels (value `invalid`) with probability p_invalid.
cv::Mat randomDisparity(cv::RNG& rng, cv::Size size, int invalid, double p_invalid) {
  cv::Mat d(size, CV_16SC1, cv::Scalar(rng.uniform(0, 64 * 16)));
  for (int i = 0; i < 40; ++i) {
    const cv::Point a(rng.uniform(0, size.width), rng.uniform(0, size.height));
    const cv::Size s(rng.uniform(1, size.width / 3), rng.uniform(1, size.height / 3));
    const cv::Rect r = cv::Rect(a, s) & cv::Rect(cv::Point(), size);
    const int base = rng.uniform(0, 64 * 16), slope = rng.uniform(-12, 13);
    for (int y = r.y; y < r.br().y; ++y)
      for (int x = r.x; x < r.br().x; ++x) d.at<short>(y, x) = static_cast<short>(base + slope * (x - r.x) / 4);
  }
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      const double u = rng.uniform(0.0, 1.0);
      if (u < p_invalid) d.at<short>(y, x) = static_cast<short>(invalid);
      else if (u < p_invalid + 0.05) d.at<short>(y, x) = static_cast<short>(rng.uniform(0, 64 * 16));
    }
  return d;
}

int differingPixels(const cv::Mat& a, const cv::Mat& b) { return cv::countNonZero(a != b); }

TEST(SpeckleFilter, EqualsOpenCvOnRandomMaps) {
  cv::RNG rng(20261122);
  SpeckleFilter filter;  // one instance throughout: its buffers are reused between calls
  struct Params { int new_value, max_size, max_diff; };
  const Params params[] = {{-16, 100, 32}, {-16, 100, 0}, {0, 1, 16}, {-1, 400, 64}, {-16, 10000, 8}, {7, 50, 1000}};
  int filtered_pixels = 0;
  for (int map = 0; map < 12; ++map) {
    const cv::Size size(rng.uniform(1, 200), rng.uniform(1, 120));
    for (const Params& p : params) {
      const cv::Mat input = randomDisparity(rng, size, p.new_value, map % 3 * 0.15);
      cv::Mat expected = input.clone(), ours = input.clone();
      cv::filterSpeckles(expected, p.new_value, p.max_size, p.max_diff);
      filter.apply(&ours, p.new_value, p.max_size, p.max_diff);
      ASSERT_EQ(differingPixels(expected, ours), 0)
          << "map " << map << " " << size << " new_value " << p.new_value << " max_size " << p.max_size
          << " max_diff " << p.max_diff;
      filtered_pixels += differingPixels(input, expected);
    }
  }
  EXPECT_GT(filtered_pixels, 10000);  // the maps do exercise the filter
}

// Maps tall enough for several stripes of rows (cv::getNumThreads() of them, at least 32 rows
// each), so regions crossing the seams between stripes are joined as in the serial filter.
TEST(SpeckleFilter, EqualsOpenCvAcrossParallelStripes) {
  const int threads = cv::getNumThreads();
  cv::RNG rng(99);
  SpeckleFilter filter;
  for (int n : {1, 2, 3, 4}) {
    cv::setNumThreads(n);
    for (int map = 0; map < 4; ++map) {
      const cv::Size size(rng.uniform(100, 400), rng.uniform(128, 300));
      const cv::Mat input = randomDisparity(rng, size, -16, 0.1 * map);
      cv::Mat expected = input.clone(), ours = input.clone();
      cv::filterSpeckles(expected, -16, 200, 24);
      filter.apply(&ours, -16, 200, 24);
      EXPECT_EQ(differingPixels(expected, ours), 0) << n << " threads, map " << map << " " << size;
    }
  }
  cv::setNumThreads(threads);
}

// The sad matcher's raw output on a pair whose right half does not match: many speckles.
TEST(SpeckleFilter, EqualsOpenCvOnMatcherOutput) {
  cv::RNG rng(7);
  cv::Mat left(240, 376, CV_8U), right;
  rng.fill(left, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(left, left, cv::Size(3, 3), 0.8);
  cv::Mat shifted = cv::Mat::zeros(left.size(), CV_8U);
  left.colRange(9, left.cols).copyTo(shifted.colRange(0, left.cols - 9));  // disparity 9
  right = shifted.clone();
  rng.fill(right.colRange(200, 376), cv::RNG::UNIFORM, 0, 256);
  cv::Mat noise(left.size(), CV_8U);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 12);
  right += noise;
  SadMatcherParams p;
  p.window_size = 5;
  p.num_disparities = 32;
  p.uniqueness_ratio = 0;
  p.left_right_check = false;
  const cv::Mat raw = computeSadDisparity16(left, right, p);
  SpeckleFilter filter;
  for (int max_size : {20, 100, 1000}) {
    cv::Mat expected = raw.clone(), ours = raw.clone();
    cv::filterSpeckles(expected, -16, max_size, 2 * 16);
    filter.apply(&ours, -16, max_size, 2 * 16);
    EXPECT_EQ(differingPixels(expected, ours), 0) << "max_size " << max_size;
    EXPECT_GT(differingPixels(raw, expected), 500) << "max_size " << max_size;
  }
}

TEST(SpeckleFilter, FiltersASubMatrixInPlace) {
  cv::RNG rng(3);
  const cv::Mat full = randomDisparity(rng, cv::Size(160, 100), -16, 0.1);
  cv::Mat expected = full.clone(), ours = full.clone();
  const cv::Rect roi(13, 7, 101, 60);
  cv::Mat expected_roi = expected(roi), ours_roi = ours(roi);
  cv::filterSpeckles(expected_roi, -16, 60, 16);
  SpeckleFilter().apply(&ours_roi, -16, 60, 16);
  EXPECT_EQ(differingPixels(expected, ours), 0);  // inside and (untouched) outside the ROI
}

TEST(SpeckleFilter, RemovesRegionsUpToTheSizeAndUsesFourConnectivity) {
  // A 3x3 island of 100 in a field of 500, and two single pixels of 100 touching only at a
  // corner (diagonal: two regions of one pixel each).
  cv::Mat d(12, 12, CV_16SC1, cv::Scalar(500));
  d(cv::Rect(2, 2, 3, 3)).setTo(100);
  d.at<short>(8, 8) = 100;
  d.at<short>(9, 9) = 100;
  cv::Mat kept = d.clone(), removed = d.clone();
  SpeckleFilter filter;
  filter.apply(&kept, -1, 8, 10);     // the island has 9 pixels: kept
  EXPECT_EQ(kept.at<short>(3, 3), 100);
  EXPECT_EQ(kept.at<short>(8, 8), -1);  // one-pixel regions go
  EXPECT_EQ(kept.at<short>(9, 9), -1);
  EXPECT_EQ(kept.at<short>(0, 0), 500);
  filter.apply(&removed, -1, 9, 10);  // at most 9 pixels: removed
  EXPECT_EQ(cv::countNonZero(removed(cv::Rect(2, 2, 3, 3)) == -1), 9);
  EXPECT_EQ(cv::countNonZero(removed == 500), 144 - 9 - 2);
}

TEST(SpeckleFilter, ChecksItsInput) {
  SpeckleFilter filter;
  cv::Mat floats(4, 4, CV_32FC1, cv::Scalar(1));
  EXPECT_THROW(filter.apply(&floats, -1, 10, 1), std::invalid_argument);
  cv::Mat empty(0, 0, CV_16SC1);
  EXPECT_NO_THROW(filter.apply(&empty, -1, 10, 1));
  cv::Mat d(4, 4, CV_16SC1, cv::Scalar(3));
  d.at<short>(1, 1) = 200;
  const cv::Mat before = d.clone();
  filter.apply(&d, -1, 0, 1);  // max size 0: nothing is a speckle, as in cv::filterSpeckles
  EXPECT_EQ(differingPixels(before, d), 0);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
