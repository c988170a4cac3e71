// rostest: set_camera_info refuses calibrations no consumer could use, and stores nothing
// (calibration_refusals.test).
#include <gtest/gtest.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <functional>
#include <limits>

#include "calibration_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using embedded_calibration_stereo::CalibrationMode;
using sensor_msgs::CameraInfo;

namespace {

// Each field no consumer could use, in either camera's calibration (`in_force`: left, right),
// is refused by set_camera_info with a message naming the field and the service.
void expectBadFieldsRefused(const CameraInfo& left_in_force, const CameraInfo& right_in_force) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const struct {
    const char* name;
    std::function<void(CameraInfo&)> mutate;
    const char* field;  // the refusal names it
  } cases[] = {
      {"NaN skew", [&](CameraInfo& i) { i.K[1] = nan; }, "K[1]"},
      {"NaN in R", [&](CameraInfo& i) { i.R[4] = nan; }, "R[4]"},
      {"NaN in P", [&](CameraInfo& i) { i.P[2] = nan; }, "P[2]"},
      {"infinite Tx", [](CameraInfo& i) { i.P[3] = std::numeric_limits<double>::infinity(); }, "P[3]"},
      {"all-zero P", [](CameraInfo& i) { i.P.fill(0.0); }, "P is all zero"},
      {"R not a rotation", [](CameraInfo& i) { i.R[0] = 2.0; }, "R: not a rotation"},
      {"wrong size", [](CameraInfo& i) { i.width = 640; }, "640x480"},
      {"binning 1000", [](CameraInfo& i) { i.binning_x = i.binning_y = 1000; }, "binning"},
      {"cy' far below", [](CameraInfo& i) { i.P[6] += 100000; }, "P[6]"},
      {"cx' off the image", [](CameraInfo& i) { i.P[2] += 5000; }, "P[2]"},
      {"cx off the image", [](CameraInfo& i) { i.K[2] += 5000; }, "K[2]"},
      {"focal 1.3x nominal",
       [](CameraInfo& i) {
         for (const size_t k : {0, 4}) i.K[k] *= 1.3;
         for (const size_t k : {0, 3, 5}) i.P[k] *= 1.3;
       },
       "fx (K[0]) "},
  };
  for (const auto& c : cases) {
    for (const std::string side : {"left", "right"}) {
      sensor_msgs::SetCameraInfo srv;
      srv.request.camera_info = side == "left" ? left_in_force : right_in_force;
      c.mutate(srv.request.camera_info);
      ASSERT_TRUE(ros::service::call("/stereo/" + side + "/set_camera_info", srv)) << "the driver is gone";
      EXPECT_FALSE(srv.response.success) << side << " " << c.name << " accepted: " << srv.response.status_message;
      EXPECT_NE(srv.response.status_message.find(c.field), std::string::npos)
          << side << " " << c.name << ": " << srv.response.status_message;
      EXPECT_NE(srv.response.status_message.find(side + "/set_camera_info"), std::string::npos)
          << srv.response.status_message;
      if (side == "left") std::printf("  %-18s -> %s\n", c.name, srv.response.status_message.c_str());
    }
  }
}

}  // namespace

TEST(CalibrationRefusals, BadFieldsAreRefusedAndNothingIsPersisted) {
  ros::NodeHandle nh("/stereo");
  const test_support::TempDir temp("ecs_calibration_refusals");
  ASSERT_FALSE(temp.path.empty());
  const std::string left_path = temp.path + "/left.yaml", right_path = temp.path + "/right.yaml";
  test_support::InProcessManager manager;
  ASSERT_TRUE(manager.load("/stereo/camera_driver", {{"backend", "sim"},
                                                     {"fps", 10.0},
                                                     {"left_camera_info_url", "file://" + left_path},
                                                     {"right_camera_info_url", "file://" + right_path}}));
  Collector<CalibrationMode> modes(nh, "calibration_mode");
  Collector<CameraInfo> left(nh, "left/camera_info"), right(nh, "right/camera_info");
  ASSERT_TRUE(modes.waitForCount(2, 20.0));
  ASSERT_TRUE(left.waitForCount(1, 5.0));
  ASSERT_TRUE(right.waitForCount(1, 5.0));

  // Control: a valid change (k1 of each camera, P unchanged) is accepted and stored.
  double k1[2];
  for (const int i : {0, 1}) {
    sensor_msgs::SetCameraInfo srv;
    srv.request.camera_info = *(i == 0 ? left : right).snapshot().back();
    srv.request.camera_info.D[0] -= 0.01;
    k1[i] = srv.request.camera_info.D[0];
    ASSERT_TRUE(ros::service::call(std::string("/stereo/") + (i == 0 ? "left" : "right") + "/set_camera_info", srv));
    ASSERT_TRUE(srv.response.success) << i << ": " << srv.response.status_message;
  }
  ASSERT_TRUE(modes.waitFor([](const auto& m) { return m.back()->calibration_epoch == 2u; }, 5.0));
  ASSERT_TRUE(left.waitFor([&](const auto& m) { return m.back()->D[0] == k1[0]; }, 5.0));
  ASSERT_TRUE(right.waitFor([&](const auto& m) { return m.back()->D[0] == k1[1]; }, 5.0));
  const CameraInfo left_in_force = *left.snapshot().back(), right_in_force = *right.snapshot().back();
  const std::string left_bytes = test_support::fileBytes(left_path), right_bytes = test_support::fileBytes(right_path);
  ASSERT_FALSE(left_bytes.empty());
  ASSERT_FALSE(right_bytes.empty());

  expectBadFieldsRefused(left_in_force, right_in_force);
  // Nothing persisted, nothing put in force.
  EXPECT_EQ(test_support::fileBytes(left_path), left_bytes);
  EXPECT_EQ(test_support::fileBytes(right_path), right_bytes);
  const size_t seen = modes.snapshot().size();
  ASSERT_TRUE(modes.waitForCount(seen + 3, 5.0));
  EXPECT_EQ(modes.snapshot().back()->calibration_epoch, 2u);
  CameraInfo published = *left.snapshot().back(), expected = left_in_force;
  published.header = expected.header = std_msgs::Header();
  EXPECT_EQ(published, expected);
  published = *right.snapshot().back();
  expected = right_in_force;
  published.header = expected.header = std_msgs::Header();
  EXPECT_EQ(published, expected);
  EXPECT_TRUE(manager.unload("/stereo/camera_driver"));
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibration_refusals_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
