// Disparity accuracy on real Middlebury pairs (ECS_SHARED_DATA_DIR/middlebury/{tsukuba,teddy}).
// Metric: percentage of pixels with ground truth whose disparity is off by more than 2 px;
// pixels left invalid count as bad, so hole filling is part of what is measured.
// All runs use disparity_range 64 (the rig's default; Tsukuba needs ~16 and Teddy ~60).
// Skipped, with a message, when the data folder is absent.
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <sys/stat.h>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"

namespace embedded_calibration_stereo::core {
namespace {

struct MiddleburyPair {
  std::string name;
  cv::Mat left, right, ground_truth;
};

std::string dataDir() { return std::string(ECS_SHARED_DATA_DIR) + "/middlebury"; }

bool exists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0;
}

// File names and ground-truth scales as given in each pair's SOURCE.txt.
MiddleburyPair loadPair(const std::string& name) {
  const std::string dir = dataDir() + "/" + name + "/";
  MiddleburyPair p;
  p.name = name;
  if (name == "tsukuba") {
    p.left = cv::imread(dir + "left.png", cv::IMREAD_GRAYSCALE);
    p.right = cv::imread(dir + "right.png", cv::IMREAD_GRAYSCALE);
    p.ground_truth = loadScaledGroundTruth(dir + "groundtruth.png", 16.0);
  } else {
    p.left = cv::imread(dir + "im2.png", cv::IMREAD_GRAYSCALE);
    p.right = cv::imread(dir + "im6.png", cv::IMREAD_GRAYSCALE);
    p.ground_truth = loadScaledGroundTruth(dir + "disp2.pgm", 4.0);
  }
  return p;
}

class MiddleburyTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!exists(dataDir() + "/tsukuba/left.png") || !exists(dataDir() + "/teddy/im2.png"))
      GTEST_SKIP() << "Middlebury data not found under " << dataDir()
                   << " (ECS_SHARED_DATA_DIR); accuracy tests skipped";
    tsukuba_ = loadPair("tsukuba");
    teddy_ = loadPair("teddy");
    ASSERT_FALSE(tsukuba_.left.empty() || tsukuba_.right.empty());
    ASSERT_FALSE(teddy_.left.empty() || teddy_.right.empty());
  }

  double badRate(const DisparityOptions& options, const MiddleburyPair& pair) {
    DisparityComputer computer(options);
    const cv::Mat disparity = computer.compute(pair.left, pair.right);
    return evaluateBadPixels(disparity, pair.ground_truth, 2.0).badPercent();
  }

  void report(const std::string& label, const DisparityOptions& options, double* tsukuba,
              double* teddy) {
    *tsukuba = badRate(options, tsukuba_);
    *teddy = badRate(options, teddy_);
    std::printf("[ middlebury ] %-28s bad>2px: tsukuba %6.2f %%  teddy %6.2f %%\n", label.c_str(),
                *tsukuba, *teddy);
  }

  MiddleburyPair tsukuba_, teddy_;
};

TEST_F(MiddleburyTest, DefaultBeatsStockAndMeetsTargets) {
  double ts, td, bm_ts, bm_td, sgbm_ts, sgbm_td;
  report("default (" + DisparityOptions().algorithm + ")", DisparityOptions(), &ts, &td);
  const DisparityOptions stock_bm = DisparityOptions::stereoImageProcDefaults("bm");
  const DisparityOptions stock_sgbm = DisparityOptions::stereoImageProcDefaults("sgbm");
  report("stock stereo_image_proc BM", stock_bm, &bm_ts, &bm_td);
  report("stock stereo_image_proc SGBM", stock_sgbm, &sgbm_ts, &sgbm_td);
  // With 64 levels the stock matchers leave the 64 leftmost columns invalid, which dominates
  // their Tsukuba figure; with Tsukuba's own range (16) they score as usually quoted.
  DisparityOptions bm16 = stock_bm, sgbm16 = stock_sgbm;
  bm16.disparity_range = sgbm16.disparity_range = 16;
  std::printf("[ middlebury ] stock BM / SGBM with disparity_range 16 on tsukuba: %.2f %% / %.2f %%\n",
              badRate(bm16, tsukuba_), badRate(sgbm16, tsukuba_));
  // The targets of the head's default matcher (docs/depth.md).
  EXPECT_LE(ts, 4.0);
  EXPECT_LE(td, 10.0);
  EXPECT_LT(ts, sgbm_ts);
  EXPECT_LT(td, sgbm_td);
  EXPECT_LT(ts, bm_ts);
  EXPECT_LT(td, bm_td);
}

// census_sgm's five-path mode (one pass, faster) and the sad fast mode, each within the bounds
// measured for it with a margin; the default (eight paths) beats both.
TEST_F(MiddleburyTest, FastModes) {
  double ts8, td8, ts5, td5, ts, td;
  report("census_sgm, 8 paths", DisparityOptions(), &ts8, &td8);
  DisparityOptions five;
  five.sgm_paths = 5;
  report("census_sgm, 5 paths", five, &ts5, &td5);
  EXPECT_LE(ts5, 5.0);
  EXPECT_LE(td5, 9.0);
  DisparityOptions sad;
  sad.algorithm = "sad";
  report("sad 11x11", sad, &ts, &td);
  EXPECT_LE(ts, 6.0);
  EXPECT_LE(td, 15.0);
  EXPECT_LT(ts8, ts5);
  EXPECT_LT(ts8, ts);
  EXPECT_LT(td8, td);
}

// SGBM with the penalties tuned for a 3x3 window, in every OpenCV mode.
TEST_F(MiddleburyTest, TunedSgbmInEveryMode) {
  for (const std::string mode : {"sgbm", "hh", "sgbm_3way", "hh4"}) {
    DisparityOptions o;
    o.algorithm = "sgbm";
    o.correlation_window_size = 3;
    o.P1 = 8 * 9;
    o.P2 = 32 * 9;
    o.sgbm_mode = mode;
    double ts, td;
    report("sgbm 3x3 mode " + mode, o, &ts, &td);
    EXPECT_LE(ts, 5.0) << mode;
    EXPECT_LE(td, 16.0) << mode;
  }
}

TEST_F(MiddleburyTest, BlockMatchersWithAndWithoutFilling) {
  DisparityOptions bm;
  bm.algorithm = "bm";
  bm.correlation_window_size = 9;
  double ts, td;
  report("bm 9x9 + filling", bm, &ts, &td);
  EXPECT_LE(ts, 8.0);
  EXPECT_LE(td, 20.0);
  // The original head's matcher alone: holes (left-right check, uniqueness, speckles and the
  // left border) count as bad, hence the looser bound.
  DisparityOptions sad;
  sad.algorithm = "sad";
  sad.fill_holes = false;
  report("sad 11x11, no filling", sad, &ts, &td);
  EXPECT_LE(ts, 15.0);
  sad.fill_holes = true;
  sad.left_right_check = false;
  report("sad 11x11, no lr-check, filling", sad, &ts, &td);
  EXPECT_LE(ts, 8.0);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
