// Disparity core against synthetic ground truth: a textured fronto-parallel plane seen with a
// known (sub-pixel) shift, input validation, options checking/clamping, hole filling,
// evaluation and the PFM writer/reader.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <cstdio>
#include <fstream>
#include <random>

#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"
#include "embedded_calibration_stereo/core/depth/disparity_filling.h"
#include "embedded_calibration_stereo/core/io/pfm_io.h"

namespace embedded_calibration_stereo::core {
namespace {

// Band-limited random texture as a sum of sinusoids, so a shifted copy is exact (no resampling).
struct Texture {
  std::vector<double> fx, fy, phase, amp;
  explicit Texture(unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> f(0.02, 0.45), ph(0, 2 * M_PI), a(0.5, 1.0);
    for (int i = 0; i < 60; ++i) {
      fx.push_back(f(rng) * (i % 2 ? 1 : -1));
      fy.push_back(f(rng) * (i % 3 ? 1 : -1));
      phase.push_back(ph(rng));
      amp.push_back(a(rng));
    }
  }
  double operator()(double x, double y) const {
    double v = 0;
    for (size_t i = 0; i < fx.size(); ++i) v += amp[i] * std::sin(fx[i] * x + fy[i] * y + phase[i]);
    return v;
  }
};

// Left image I(x, y) = T(x, y), right image I(x, y) = T(x + d, y): disparity d everywhere.
void renderPlane(double disparity, cv::Size size, cv::Mat* left, cv::Mat* right) {
  const Texture texture(11);
  *left = cv::Mat(size, CV_8U);
  *right = cv::Mat(size, CV_8U);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      left->at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(128 + 12 * texture(x, y));
      right->at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(128 + 12 * texture(x + disparity, y));
    }
}

struct PlaneCase {
  std::string algorithm;
  std::string sgbm_mode;
};

class PlaneTest : public ::testing::TestWithParam<PlaneCase> {};

TEST_P(PlaneTest, RecoversKnownShiftWithinPointTwoPixels) {
  for (const double true_d : {9.25, 20.5, 37.75}) {
    cv::Mat left, right;
    renderPlane(true_d, cv::Size(320, 200), &left, &right);
    DisparityOptions o;
    o.algorithm = GetParam().algorithm;
    if (!GetParam().sgbm_mode.empty()) o.sgbm_mode = GetParam().sgbm_mode;
    if (o.algorithm != "sad") o.correlation_window_size = 9;
    o.fill_holes = false;
    DisparityComputer computer(o);
    const cv::Mat d = computer.compute(left, right);
    ASSERT_EQ(d.type(), CV_32FC1);
    std::vector<double> errors;
    int total = 0;
    // Interior: away from the left border (no match there) and the window margins.
    for (int y = 10; y < d.rows - 10; ++y)
      for (int x = 64 + 10; x < d.cols - 10; ++x) {
        ++total;
        const float v = d.at<float>(y, x);
        if (isValidDisparity(v)) errors.push_back(std::abs(v - true_d));
      }
    ASSERT_FALSE(errors.empty());
    double sum_abs = 0;
    for (double e : errors) sum_abs += e;
    const double mean_abs = sum_abs / errors.size();
    std::sort(errors.begin(), errors.end());
    const double p99 = errors[errors.size() * 99 / 100];
    const double valid = 100.0 * errors.size() / total;
    std::printf("[ plane ] %s%s d=%.2f: mean |err| %.3f px, 99%% within %.3f px, valid %.1f %%\n",
                o.algorithm.c_str(), o.algorithm == "sgbm" ? ("/" + o.sgbm_mode).c_str() : "",
                true_d, mean_abs, p99, valid);
    EXPECT_LE(mean_abs, 0.2) << "d = " << true_d;
    EXPECT_LE(p99, 1.0) << "d = " << true_d;
    // Exact half-pixel shifts tie two disparities, which the uniqueness and left-right tests of
    // the block matchers reject in places.
    EXPECT_GE(valid, 85.0) << "d = " << true_d;
  }
}

INSTANTIATE_TEST_SUITE_P(
    Algorithms, PlaneTest,
    ::testing::Values(PlaneCase{"sad", ""}, PlaneCase{"bm", ""}, PlaneCase{"sgbm", "sgbm"},
                      PlaneCase{"sgbm", "hh"}, PlaneCase{"sgbm", "sgbm_3way"},
                      PlaneCase{"sgbm", "hh4"}),
    [](const ::testing::TestParamInfo<PlaneCase>& info) {
      return info.param.algorithm + (info.param.sgbm_mode.empty() ? "" : "_" + info.param.sgbm_mode);
    });

TEST(DisparityTest, InvalidIsNanWithoutFillingAndFilledByDefault) {
  cv::Mat left, right;
  renderPlane(20.0, cv::Size(320, 120), &left, &right);
  DisparityOptions o;
  o.fill_holes = false;
  const cv::Mat raw = DisparityComputer(o).compute(left, right);
  // Left of x = d the right camera cannot see the left pixel: no valid match there.
  int invalid_border = 0;
  for (int y = 10; y < raw.rows - 10; ++y)
    for (int x = 0; x < 15; ++x) invalid_border += !isValidDisparity(raw.at<float>(y, x));
  EXPECT_GT(invalid_border, 0.9 * 15 * (raw.rows - 20));
  const cv::Mat filled = DisparityComputer(DisparityOptions()).compute(left, right);
  EXPECT_EQ(cv::countNonZero(filled != filled), 0) << "NaN left after filling";
  EXPECT_NEAR(filled.at<float>(60, 5), 20.0, 0.5) << "border filled from its right neighbour";
}

TEST(DisparityTest, SadHandlesNegativeMinDisparity) {
  cv::Mat left, right;
  renderPlane(-3.5, cv::Size(240, 100), &left, &right);  // right image shifted the other way
  DisparityOptions o;
  o.algorithm = "sad";
  o.min_disparity = -16;
  o.disparity_range = 32;
  o.fill_holes = false;
  const cv::Mat d = DisparityComputer(o).compute(left, right);
  int valid = 0, good = 0;
  for (int y = 10; y < d.rows - 10; ++y)
    for (int x = 20; x < d.cols - 30; ++x) {
      const float v = d.at<float>(y, x);
      if (!isValidDisparity(v)) continue;
      ++valid;
      good += std::abs(v + 3.5) <= 0.25;
    }
  const int total = (d.rows - 20) * (d.cols - 50);
  EXPECT_GE(valid, 0.9 * total);
  EXPECT_GE(good, 0.98 * valid);
}

TEST(DisparityTest, SadWithoutSubpixelUniquenessOrLeftRightCheck) {
  cv::Mat left, right;
  renderPlane(14.25, cv::Size(240, 100), &left, &right);
  DisparityOptions o;
  o.algorithm = "sad";
  o.subpixel = false;
  o.uniqueness_ratio = 0;
  o.left_right_check = false;  // without these filters a smaller window mismatches too often here
  o.correlation_window_size = 9;
  const cv::Mat d = DisparityComputer(o).compute(left, right);
  int whole = 0, right_value = 0, neighbours = 0, total = 0;
  for (int y = 10; y < d.rows - 10; ++y)
    for (int x = 30; x < d.cols - 10; ++x) {
      const float v = d.at<float>(y, x);
      ++total;
      whole += v == std::round(v);
      right_value += v == 14.0f;
      neighbours += v == 14.0f || v == 15.0f;
    }
  EXPECT_EQ(whole, total) << "subpixel off must give whole pixels";
  // True disparity 14.25: the nearest whole value mostly, the other neighbour at worst.
  EXPECT_GE(right_value, 0.8 * total);
  EXPECT_GE(neighbours, 0.98 * total);
}

TEST(DisparityTest, SadResultDoesNotDependOnThreadCount) {
  cv::Mat left, right;
  renderPlane(11.6, cv::Size(320, 160), &left, &right);
  DisparityOptions o;
  o.fill_holes = false;
  const int threads = cv::getNumThreads();
  cv::setNumThreads(1);
  const cv::Mat one = DisparityComputer(o).compute(left, right);
  cv::setNumThreads(4);
  const cv::Mat four = DisparityComputer(o).compute(left, right);
  cv::setNumThreads(threads);
  ASSERT_TRUE(one.isContinuous() && four.isContinuous());
  EXPECT_EQ(std::memcmp(one.data, four.data, one.total() * one.elemSize()), 0)
      << "bit patterns differ (NaN != NaN, hence memcmp)";
}

// The nodelet hands compute() a header over the outgoing message's buffer: it must be written
// in place, with the same result as a fresh output, for every algorithm.
TEST(DisparityTest, WritesIntoAPreallocatedBufferInPlace) {
  cv::Mat left, right;
  renderPlane(9.3, cv::Size(240, 100), &left, &right);
  for (const char* algorithm : {"sad", "bm", "sgbm"}) {
    DisparityOptions o;
    o.algorithm = algorithm;
    o.clamp();
    DisparityComputer computer(o);
    const cv::Mat fresh = computer.compute(left, right);
    std::vector<float> buffer(left.total(), -123.0f);
    cv::Mat out(left.size(), CV_32FC1, buffer.data());
    computer.compute(left, right, &out);
    EXPECT_EQ(out.data, reinterpret_cast<uchar*>(buffer.data())) << algorithm << ": buffer replaced";
    EXPECT_EQ(std::memcmp(buffer.data(), fresh.data, fresh.total() * fresh.elemSize()), 0) << algorithm;
  }
}

TEST(DisparityTest, RejectsWrongInput) {
  DisparityComputer computer{DisparityOptions()};
  const cv::Mat gray(120, 320, CV_8UC1, cv::Scalar(0)), color(120, 320, CV_8UC3);
  try {
    computer.compute(color, color);
    FAIL() << "colour input accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("mono8"), std::string::npos) << e.what();
  }
  EXPECT_THROW(computer.compute(gray, cv::Mat(100, 320, CV_8UC1)), std::invalid_argument);
  EXPECT_THROW(computer.compute(gray, cv::Mat()), std::invalid_argument);
  EXPECT_THROW(computer.compute(cv::Mat(120, 320, CV_16UC1), cv::Mat(120, 320, CV_16UC1)),
               std::invalid_argument);
  EXPECT_THROW(computer.compute(cv::Mat(40, 60, CV_8UC1), cv::Mat(40, 60, CV_8UC1)),
               std::invalid_argument);
}

TEST(DisparityOptionsTest, CheckNamesProblemsAndClampFixesThem) {
  DisparityOptions o;
  EXPECT_EQ(o.validate(), "");
  EXPECT_TRUE(o.clamp().empty());

  o.algorithm = "bm";
  o.disparity_range = 60;
  o.correlation_window_size = 4;
  o.P2 = o.P1;
  const std::string problem = o.validate();
  EXPECT_NE(problem.find("disparity_range"), std::string::npos) << problem;
  EXPECT_NE(problem.find("correlation_window_size"), std::string::npos) << problem;
  EXPECT_NE(problem.find("P2"), std::string::npos) << problem;
  EXPECT_THROW(DisparityComputer{o}, std::invalid_argument);

  const std::vector<std::string> changes = o.clamp();
  EXPECT_EQ(changes.size(), 3u);
  EXPECT_EQ(o.disparity_range, 64);
  EXPECT_EQ(o.correlation_window_size, 5);
  EXPECT_GT(o.P2, o.P1);
  EXPECT_EQ(o.validate(), "");

  DisparityOptions sad;
  sad.algorithm = "sad";
  sad.correlation_window_size = 31;  // the 16-bit window sums allow 15 at most
  EXPECT_NE(sad.validate(), "");
  sad.clamp();
  EXPECT_EQ(sad.correlation_window_size, 15);

  DisparityOptions bad_names;
  bad_names.algorithm = "census";
  bad_names.sgbm_mode = "full";
  EXPECT_NE(bad_names.validate().find("census"), std::string::npos);
  EXPECT_EQ(bad_names.clamp().size(), 2u);
  EXPECT_EQ(bad_names.validate(), "");
}

// census_sgm's own options: each bad value named by validate() and moved by clamp() to the nearest
// usable one; the range limit applies to census_sgm only.
TEST(DisparityTest, CensusSgmOptionsCheckedAndClamped) {
  DisparityOptions o;
  EXPECT_EQ(o.algorithm, "census_sgm");
  EXPECT_EQ(o.validate(), "");
  o.sgm_paths = 6;
  o.sgm_census_threshold = -1;
  o.sgm_P1 = 70;
  o.sgm_P2 = 10;
  o.sgm_edge_scale = -3;
  o.median_size = 4;
  o.disparity_range = 1024;
  const std::string problem = o.validate();
  for (const char* name : {"sgm_paths", "sgm_census_threshold", "sgm_P1", "sgm_P2", "sgm_edge_scale",
                           "median_size", "disparity_range"})
    EXPECT_NE(problem.find(name), std::string::npos) << name << " not named in: " << problem;
  EXPECT_THROW(DisparityComputer{o}, std::invalid_argument);
  EXPECT_EQ(o.clamp().size(), 7u);
  EXPECT_EQ(o.validate(), "");
  EXPECT_EQ(o.sgm_paths, 5);  // 6: nearer 5 than 8
  EXPECT_EQ(o.sgm_census_threshold, 0);
  EXPECT_EQ(o.sgm_P1, 63);
  EXPECT_GT(o.sgm_P2, o.sgm_P1);
  EXPECT_EQ(o.median_size, 3);
  EXPECT_EQ(o.disparity_range, 512);
  DisparityOptions sad;
  sad.algorithm = "sad";
  sad.disparity_range = 1024;
  EXPECT_EQ(sad.validate(), "");
}

// The mask: matched pixels 255; left of x = d (the right camera cannot see them) census_sgm
// marks them hidden (128), filled or not; where sad finds no match it says no match (0).
TEST(DisparityTest, MaskSaysMatchedHiddenOrNoMatch) {
  cv::Mat left, right;
  renderPlane(20.0, cv::Size(320, 120), &left, &right);
  for (const bool fill : {false, true}) {
    DisparityOptions o;
    o.fill_holes = fill;
    cv::Mat d, mask;
    DisparityComputer(o).compute(left, right, &d, &mask);
    ASSERT_EQ(mask.type(), CV_8UC1);
    int hidden = 0, unmatched = 0, matched_inside = 0;
    for (int y = 10; y < d.rows - 10; ++y) {
      for (int x = 0; x < 15; ++x) {
        hidden += mask.at<uint8_t>(y, x) == kMaskOccluded;
        unmatched += mask.at<uint8_t>(y, x) != kMaskMatched;
      }
      for (int x = 40; x < d.cols - 10; ++x) matched_inside += mask.at<uint8_t>(y, x) == kMaskMatched;
    }
    EXPECT_GT(unmatched, 0.9 * 15 * (d.rows - 20)) << "fill " << fill;
    EXPECT_GT(hidden, 0.85 * 15 * (d.rows - 20)) << "fill " << fill;
    EXPECT_GT(matched_inside, 0.95 * (d.cols - 50) * (d.rows - 20)) << "fill " << fill;
    for (int y = 0; y < d.rows; ++y)
      for (int x = 0; x < d.cols; ++x) {
        const uint8_t m = mask.at<uint8_t>(y, x);
        if (!fill) ASSERT_EQ(m == kMaskMatched, isValidDisparity(d.at<float>(y, x))) << x << "," << y;
        ASSERT_TRUE(m == kMaskMatched || m == kMaskOccluded || m == kMaskNoMatch);
      }
  }
  DisparityOptions sad;
  sad.algorithm = "sad";
  cv::Mat d, mask;
  DisparityComputer(sad).compute(left, right, &d, &mask);
  EXPECT_EQ(mask.at<uint8_t>(60, 5), kMaskNoMatch) << "sad cannot tell hidden from unmatched";
}

TEST(DisparityFillingTest, TakesTheFartherNeighbourAndExtendsBorders) {
  cv::Mat d(5, 12, CV_32F, cv::Scalar(kInvalidDisparity));
  for (int y = 0; y < 5; ++y) {
    for (int x = 2; x < 5; ++x) d.at<float>(y, x) = 30;  // foreground
    for (int x = 8; x < 10; ++x) d.at<float>(y, x) = 10;  // background
  }
  fillDisparityHoles(&d);
  EXPECT_FLOAT_EQ(d.at<float>(2, 0), 30);   // left border: nearest valid
  EXPECT_FLOAT_EQ(d.at<float>(2, 6), 10);   // between 30 and 10: background
  EXPECT_FLOAT_EQ(d.at<float>(2, 11), 10);  // right border
}

// fillDisparityHoles from its definition, in one thread: every run of invalid pixels of a row
// takes the smaller valid value at its ends (or the one at the image border), then the filled
// pixels take the whole map's 3x3 median (cv::medianBlur) where that is not NaN.
cv::Mat fillHolesReference(const cv::Mat& in) {
  cv::Mat d = in.clone(), filled(in.size(), CV_8U, cv::Scalar(0));
  for (int y = 0; y < d.rows; ++y) {
    float* row = d.ptr<float>(y);
    for (int x = 0; x < d.cols;) {
      if (isValidDisparity(row[x])) {
        ++x;
        continue;
      }
      int end = x;
      while (end < d.cols && !isValidDisparity(row[end])) ++end;
      const bool has_left = x > 0, has_right = end < d.cols;
      if (has_left || has_right) {
        const float v = has_left && has_right ? std::min(row[x - 1], row[end]) : (has_left ? row[x - 1] : row[end]);
        for (int i = x; i < end; ++i) {
          row[i] = v;
          filled.at<uint8_t>(y, i) = 1;
        }
      }
      x = end;
    }
  }
  cv::Mat median;
  cv::medianBlur(d, median, 3);
  for (int y = 0; y < d.rows; ++y)
    for (int x = 0; x < d.cols; ++x)
      if (filled.at<uint8_t>(y, x) && isValidDisparity(median.at<float>(y, x)))
        d.at<float>(y, x) = median.at<float>(y, x);
  return d;
}

TEST(DisparityFillingTest, EqualsTheDefinitionWhateverTheNumberOfThreads) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> value(1, 60);
  std::uniform_int_distribution<int> run(1, 12);
  cv::Mat in(97, 131, CV_32F);
  for (int y = 0; y < in.rows; ++y) {
    float* row = in.ptr<float>(y);
    for (int x = 0; x < in.cols; ++x) row[x] = value(rng);
    for (int holes = 0; holes < 6; ++holes)  // runs of holes, some at the row ends
      for (int x = run(rng) * 10, end = std::min(x + run(rng), in.cols); x < end; ++x) row[x] = kInvalidDisparity;
    if (y % 23 == 5) std::fill(row, row + in.cols, kInvalidDisparity);  // a row without any match
  }
  const cv::Mat expected = fillHolesReference(in);
  const int threads = cv::getNumThreads();
  for (const int n : {1, 2, 3, 4}) {
    cv::setNumThreads(n);
    cv::Mat got = in.clone();
    fillDisparityHoles(&got);
    EXPECT_EQ(std::memcmp(got.data, expected.data, got.total() * got.elemSize()), 0) << n << " threads";
  }
  cv::setNumThreads(threads);
  int filled = 0;
  for (int i = 0; i < static_cast<int>(in.total()); ++i)
    filled += !isValidDisparity(in.at<float>(i)) && isValidDisparity(expected.at<float>(i));
  EXPECT_GT(filled, static_cast<int>(in.total()) / 20) << "too few filled pixels to compare";
}

TEST(DisparityEvaluationTest, InvalidCountsAsBadAndUnknownIsSkipped) {
  cv::Mat gt = (cv::Mat_<float>(1, 4) << 10, 10, 0, 10);
  cv::Mat d = (cv::Mat_<float>(1, 4) << 11.5, 13, 50, kInvalidDisparity);
  const BadPixelStats s = evaluateBadPixels(d, gt, 2.0);
  EXPECT_EQ(s.evaluated, 3);
  EXPECT_EQ(s.bad, 2);
  EXPECT_EQ(s.invalid, 1);
}

TEST(PfmTest, RoundTripInfForInvalidBottomUpLittleEndian) {
  cv::Mat d(3, 4, CV_32F);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 4; ++x) d.at<float>(y, x) = 0.125f * (10 * y + x) + 1.0f / 3.0f;
  d.at<float>(1, 2) = kInvalidDisparity;
  const std::string path = ::testing::TempDir() + "ecs_test_roundtrip.pfm";
  writePfm(path, d);

  const cv::Mat back = readPfm(path);
  ASSERT_EQ(back.size(), d.size());
  ASSERT_EQ(back.type(), CV_32FC1);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 4; ++x) {
      if (y == 1 && x == 2) {
        EXPECT_TRUE(std::isinf(back.at<float>(y, x)) && back.at<float>(y, x) > 0);
      } else {
        EXPECT_EQ(back.at<float>(y, x), d.at<float>(y, x));  // bit-exact
      }
    }

  // Layout: text header with a negative scale, then the bottom row first.
  std::ifstream in(path, std::ios::binary);
  std::string magic, scale;
  int w, h;
  in >> magic >> w >> h >> scale;
  in.get();
  EXPECT_EQ(magic, "Pf");
  EXPECT_EQ(w, 4);
  EXPECT_EQ(h, 3);
  EXPECT_EQ(scale[0], '-');
  unsigned char bytes[4];
  in.read(reinterpret_cast<char*>(bytes), 4);
  uint32_t bits = bytes[0] | (bytes[1] << 8) | (bytes[2] << 16) | (static_cast<uint32_t>(bytes[3]) << 24);
  float first;
  std::memcpy(&first, &bits, 4);
  EXPECT_EQ(first, d.at<float>(2, 0));
  std::remove(path.c_str());

  EXPECT_THROW(readPfm(path), std::runtime_error);
  EXPECT_THROW(writePfm(path, cv::Mat(2, 2, CV_8U)), std::invalid_argument);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
