// rostest: our Disparity loads stereo_image_proc's default parameters (depth_stock_params.test).
#include <gtest/gtest.h>
#include <nodelet/loader.h>
#include <stereo_image_proc/DisparityConfig.h>
#include <stereo_msgs/DisparityImage.h>

#include "driver_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;

TEST(DepthStockParams, OurDisparityRunsOnStereoImageProcsDefaults) {
  // Stock's defaults, as its dynamic_reconfigure server would leave them on the parameter server.
  const stereo_image_proc::DisparityConfig stock = stereo_image_proc::DisparityConfig::__getDefault__();
  ros::NodeHandle private_nh("/stereo/disparity");
  stock.__toServer__(private_nh);
  double p1 = 0.0;
  ASSERT_TRUE(private_nh.getParam("P1", p1));
  ASSERT_EQ(p1, stock.P1) << "stock's P1 (a double) is on the server";

  ros::NodeHandle nh("/stereo");
  Collector<stereo_msgs::DisparityImage> disparity(nh, "disparity", 5);
  nodelet::Loader loader(false);
  ASSERT_TRUE(loader.load("/stereo/disparity", "embedded_calibration_stereo/Disparity", ros::M_string(),
                          std::vector<std::string>()))
      << "our Disparity refused stereo_image_proc's parameters";
  ASSERT_TRUE(disparity.waitForCount(3, 30.0)) << "no disparity on stock's parameters";
  const auto d = disparity.snapshot().back();
  EXPECT_EQ(d->max_disparity - d->min_disparity + 1, stock.disparity_range);
  EXPECT_EQ(d->min_disparity, stock.min_disparity);
  // The matcher stock chose (stereo_algorithm 0: StereoBM), and its values, as the server keeps them.
  std::string algorithm;
  ASSERT_TRUE(private_nh.getParam("algorithm", algorithm));
  EXPECT_EQ(algorithm, stock.stereo_algorithm == 0 ? "bm" : "sgbm");
  int window = 0;
  ASSERT_TRUE(private_nh.getParam("correlation_window_size", window));
  EXPECT_EQ(window, stock.correlation_window_size);
  std::printf("stock defaults: stereo_algorithm %d -> %s, window %d, range %d, P1 %.0f, P2 %.0f: disparity flows\n",
              stock.stereo_algorithm, algorithm.c_str(), window, stock.disparity_range, stock.P1, stock.P2);
  loader.unload("/stereo/disparity");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "depth_stock_params_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
