// rostest: stereo_image_proc/image_proc interoperability (depth_interop.test). Both disparity
// images of one driver frame come from the same scene and calibration (the Bouguet R/P of the
// driver's CameraInfo), one through our Rectifier + stock matcher, the other through stock
// rectification + our matcher: where both matchers found a disparity, they agree per pixel.
#include <gtest/gtest.h>

#include "depth_test_utils.h"
#include "driver_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using stereo_msgs::DisparityImage;

TEST(DepthInterop, StockAndOwnPipelinesAgreePerPixel) {
  ros::NodeHandle nh;
  Collector<DisparityImage> stock(nh, "stock/disparity", 20);  // stock matcher on our image_rect
  Collector<DisparityImage> own(nh, "proc/disparity", 20);     // our matcher on image_proc's image_rect
  DisparityImage::ConstPtr a, b;
  ASSERT_TRUE(own.waitFor(
      [&](const std::vector<DisparityImage::ConstPtr>& m) {
        for (const auto& o : m) {
          if (const auto s = test_support::findByStamp(stock.snapshot(), o->header.stamp)) {
            a = s;
            b = o;
            return true;
          }
        }
        return false;
      },
      25.0))
      << "no frame with both stock/disparity (" << stock.snapshot().size() << " received) and proc/disparity ("
      << own.snapshot().size() << " received)";

  const auto left = ros::topic::waitForMessage<sensor_msgs::CameraInfo>("left/camera_info", ros::Duration(5));
  const auto right = ros::topic::waitForMessage<sensor_msgs::CameraInfo>("right/camera_info", ros::Duration(5));
  ASSERT_TRUE(left && right);
  image_geometry::StereoCameraModel model;
  ASSERT_TRUE(model.fromCameraInfo(left, right));
  for (const auto& msg : {a, b}) {
    EXPECT_NEAR(msg->T, model.baseline(), 1e-6);
    EXPECT_NEAR(msg->f, model.right().fx(), 1e-3);
    ASSERT_EQ(msg->image.width, left->width);
    ASSERT_EQ(msg->image.height, left->height);
  }
  const float* da = reinterpret_cast<const float*>(a->image.data.data());
  const float* db = reinterpret_cast<const float*>(b->image.data.data());
  std::vector<double> differences;
  for (size_t i = 0; i < size_t(left->width) * left->height; ++i)
    if (da[i] >= a->min_disparity && db[i] >= b->min_disparity) differences.push_back(std::abs(da[i] - db[i]));
  ASSERT_GT(differences.size(), left->width * left->height / 4) << "few pixels valid in both";
  const double median = test_support::median(differences);
  const double within_1px = std::count_if(differences.begin(), differences.end(), [](double e) { return e < 1.0; }) /
                            double(differences.size());
  std::printf("stock vs own pipeline over %zu pixels valid in both: median |difference| %.3f px, %.1f %% within 1 px\n",
              differences.size(), median, 100 * within_1px);
  EXPECT_LT(median, 0.3);
  EXPECT_GT(within_1px, 0.8);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "depth_interop_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
