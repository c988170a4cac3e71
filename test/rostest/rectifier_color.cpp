// rostest: image_rect is mono8 and image_rect_color the input's colour (rectifier_color.test).
#include <cv_bridge/cv_bridge.h>
#include <gtest/gtest.h>
#include <nodelet/loader.h>

#include <fstream>
#include <opencv2/imgproc.hpp>
#include <regex>
#include <sstream>

#include "depth_test_utils.h"
#include "driver_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using sensor_msgs::Image;

TEST(RectifierColor, ImageRectIsMonoAndImageRectColorTheInputsColour) {
  const test_support::TempDir temp("ecs_rectifier_color");
  std::ifstream in(std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml");
  std::stringstream text;
  text << in.rdbuf();
  const std::string colour = std::regex_replace(text.str(), std::regex(R"(\nencoding: "mono8")"), "\nencoding: \"bgr8\"");
  ASSERT_NE(colour, text.str()) << "sim_rig.yaml has no encoding line";
  const std::string config = temp.path + "/sim_rig_bgr8.yaml";
  std::ofstream(config) << colour;

  for (const auto& [name, value] : std::map<std::string, XmlRpc::XmlRpcValue>{
           {"backend", "sim"}, {"sim_config", config}, {"fps", 10.0}, {"calibration_period_s", 0.0},
           {"left_camera_info_url", "file://" + temp.path + "/left.yaml"},
           {"right_camera_info_url", "file://" + temp.path + "/right.yaml"}})
    ros::param::set("/rc/camera_driver/" + name, value);
  nodelet::Loader loader(false);
  ASSERT_TRUE(loader.load("/rc/camera_driver", "embedded_calibration_stereo/CameraDriver", {}, {}));
  const ros::M_string remap{{"/rc/left/image_scene", "/rc/left/image_raw"},
                            {"/rc/right/image_scene", "/rc/right/image_raw"}};
  ASSERT_TRUE(loader.load("/rc/rectifier", "embedded_calibration_stereo/Rectifier", remap, {}));

  ros::NodeHandle nh("/rc");
  Collector<Image> mono(nh, "left/image_rect", 20), color(nh, "left/image_rect_color", 20);
  ASSERT_TRUE(mono.waitForCount(3, 30.0)) << "no image_rect";
  ASSERT_TRUE(color.waitForCount(3, 10.0)) << "no image_rect_color";
  // A frame on both, by stamp.
  Image::ConstPtr m, c;
  ASSERT_TRUE(color.waitFor(
      [&](const std::vector<Image::ConstPtr>& colours) {
        for (const auto& candidate : colours)
          if ((m = test_support::findByStamp(mono.snapshot(), candidate->header.stamp))) {
            c = candidate;
            return true;
          }
        return false;
      },
      10.0));
  EXPECT_EQ(m->encoding, "mono8");
  EXPECT_EQ(c->encoding, "bgr8");
  EXPECT_EQ(m->header.frame_id, c->header.frame_id);
  // The mono image is the colour one's grey (OpenCV's conversion, computed here).
  cv::Mat grey;
  cv::cvtColor(cv_bridge::toCvShare(c)->image, grey, cv::COLOR_BGR2GRAY);
  EXPECT_EQ(cv::norm(grey, cv_bridge::toCvShare(m)->image, cv::NORM_INF), 0.0);
  loader.unload("/rc/rectifier");
  loader.unload("/rc/camera_driver");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "rectifier_color_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
