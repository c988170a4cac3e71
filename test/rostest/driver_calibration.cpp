// rostest: calibrations sent to the driver's set_camera_info services.
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <fstream>
#include <map>
#include <set>
#include <vector>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/ros/calibration_file.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using test_support::Collector;
using sensor_msgs::CameraInfo;

namespace {

const char* kName = "/stereo/camera_driver";

// The CameraInfo published with the calibration_mode of the same stamp (frames are matched by
// stamp, as consumers do with ExactTime).
struct Frame {
  CalibrationMode::ConstPtr mode;
  CameraInfo::ConstPtr left, right;
};

std::vector<Frame> matchFrames(Collector<CalibrationMode>& modes, Collector<CameraInfo>& left,
                               Collector<CameraInfo>& right) {
  std::vector<Frame> frames;
  const auto l = left.snapshot(), r = right.snapshot();
  for (const auto& m : modes.snapshot()) {
    Frame f{m, nullptr, nullptr};
    for (const auto& x : l)
      if (x->header.stamp == m->header.stamp) f.left = x;
    for (const auto& x : r)
      if (x->header.stamp == m->header.stamp) f.right = x;
    if (f.left && f.right) frames.push_back(f);
  }
  return frames;
}

bool callSet(const std::string& side, const CameraInfo& info, sensor_msgs::SetCameraInfo* srv) {
  srv->request.camera_info = info;
  return ros::service::call(std::string("/stereo/") + side + "/set_camera_info", *srv);
}

}  // namespace

TEST(DriverCalibration, SetCameraInfoPersistsAtomicallyAndSurvivesAReload) {
  ros::NodeHandle nh("/stereo");
  const test_support::TempDir temp("ecs_driver_calibration");
  const std::string& dir = temp.path;
  ASSERT_FALSE(dir.empty());
  { std::ofstream(dir + "/plain_file") << "not a directory"; }
  const std::string left_path = dir + "/left.yaml";
  test_support::InProcessManager manager;
  Collector<CalibrationMode> modes(nh, "calibration_mode");
  Collector<CameraInfo> left(nh, "left/camera_info"), right(nh, "right/camera_info");

  // 1. Unwritable URL (its parent is a regular file): false with a reason; the calibration in
  //    force and the epoch stay. Both files change together, so the left one is not stored
  //    either.
  ASSERT_TRUE(manager.load(kName, {{"backend", "sim"}, {"fps", 10.0}, {"left_camera_info_url", "file://" + left_path},
                                   {"right_camera_info_url", "file://" + dir + "/plain_file/right.yaml"}}));
  ASSERT_TRUE(modes.waitForCount(2, 20.0));
  ASSERT_TRUE(left.waitForCount(2, 5.0));
  ASSERT_TRUE(right.waitForCount(2, 5.0));
  const CameraInfo nominal_left = *left.snapshot().back();
  EXPECT_EQ(modes.snapshot().back()->calibration_epoch, 0u);
  EXPECT_GT(nominal_left.K[0], 0.0) << "no nominal calibration published before any file exists";
  CameraInfo updated = nominal_left;
  updated.K[0] += 7.5;  // K only: the rectified P, shared with the right camera, stays
  sensor_msgs::SetCameraInfo srv;
  ASSERT_TRUE(callSet("left", updated, &srv));
  EXPECT_FALSE(srv.response.success);
  EXPECT_NE(srv.response.status_message.find("plain_file"), std::string::npos) << srv.response.status_message;
  const size_t seen = modes.snapshot().size();
  ASSERT_TRUE(modes.waitForCount(seen + 3, 5.0));
  EXPECT_EQ(modes.snapshot().back()->calibration_epoch, 0u);
  EXPECT_EQ(left.snapshot().back()->K[0], nominal_left.K[0]);
  CameraInfo stored;
  std::string error;
  EXPECT_FALSE(embedded_calibration_stereo::readCalibrationFile(left_path, nullptr, &stored, &error))
      << "the left file was stored without the right one";
  ASSERT_TRUE(manager.unload(kName));

  // 2. Accepted: written to the URL, published with a new epoch from the next frames on.
  const test_support::InProcessManager::Params params = {{"backend", "sim"}, {"fps", 10.0},
                                                      {"left_camera_info_url", "file://" + left_path},
                                                      {"right_camera_info_url", "file://" + dir + "/right.yaml"}};
  modes.clear();
  left.clear();
  ASSERT_TRUE(manager.load(kName, params));
  ASSERT_TRUE(modes.waitForCount(2, 20.0));
  ASSERT_TRUE(callSet("left", updated, &srv));
  EXPECT_TRUE(srv.response.success) << srv.response.status_message;
  ASSERT_TRUE(embedded_calibration_stereo::readCalibrationFile(left_path, nullptr, &stored, &error)) << error;
  EXPECT_NEAR(stored.K[0], updated.K[0], 1e-9);
  ASSERT_TRUE(modes.waitFor([](const auto& m) { return m.back()->calibration_epoch == 1u; }, 5.0));
  ASSERT_TRUE(left.waitFor([&](const auto& m) { return m.back()->K[0] == updated.K[0]; }, 5.0));
  // Every frame's epoch matches the CameraInfo published with it.
  modes.waitForCount(modes.snapshot().size() + 2, 5.0);
  for (const auto& f : matchFrames(modes, left, right)) {
    EXPECT_EQ(f.left->K[0], f.mode->calibration_epoch == 0 ? nominal_left.K[0] : updated.K[0])
        << "epoch " << f.mode->calibration_epoch;
  }

  // 3. Non-positive focal length: refused, the file keeps the accepted calibration.
  CameraInfo broken = updated;
  broken.K[0] = 0.0;
  ASSERT_TRUE(callSet("left", broken, &srv));
  EXPECT_FALSE(srv.response.success);
  EXPECT_NE(srv.response.status_message.find("focal"), std::string::npos) << srv.response.status_message;
  ASSERT_TRUE(embedded_calibration_stereo::readCalibrationFile(left_path, nullptr, &stored, &error)) << error;
  EXPECT_NEAR(stored.K[0], updated.K[0], 1e-9);

  // 4. Reload: the stored calibration comes back from the URL.
  ASSERT_TRUE(manager.unload(kName));
  left.clear();
  ASSERT_TRUE(manager.load(kName, params));
  ASSERT_TRUE(left.waitForCount(1, 20.0));
  EXPECT_NEAR(left.snapshot().back()->K[0], updated.K[0], 1e-9);
  EXPECT_TRUE(manager.unload(kName));
}

// A new rectified pair arrives as two calls, left then right. One that changes only cx' (P[2])
// or only Tx (P[3]) still forms a pair with the other camera in force, yet is half of a new
// pair: it is staged until the other half arrives, and no frame ever carries one camera's new
// half with the other's old one.
TEST(DriverCalibration, APairChangesAtomicallyWhateverFieldsChange) {
  ros::NodeHandle nh("/stereo");
  const test_support::TempDir temp("ecs_driver_pair_atomic");
  ASSERT_FALSE(temp.path.empty());
  test_support::InProcessManager manager;
  Collector<CalibrationMode> modes(nh, "calibration_mode", 1000);
  Collector<CameraInfo> left(nh, "left/camera_info", 1000), right(nh, "right/camera_info", 1000);
  ASSERT_TRUE(manager.load(kName, {{"backend", "sim"}, {"fps", 10.0},
                                   {"left_camera_info_url", "file://" + temp.path + "/left.yaml"},
                                   {"right_camera_info_url", "file://" + temp.path + "/right.yaml"}}));
  ASSERT_TRUE(modes.waitForCount(2, 20.0));
  ASSERT_TRUE(left.waitForCount(2, 5.0));
  ASSERT_TRUE(right.waitForCount(2, 5.0));
  const CameraInfo old_left = *left.snapshot().back(), old_right = *right.snapshot().back();
  sensor_msgs::SetCameraInfo srv;
  const auto framesLater = [&](size_t n) { return modes.waitForCount(modes.snapshot().size() + n, 5.0); };

  // 1. cx' of both cameras 4 px larger.
  CameraInfo new_left = old_left, new_right = old_right;
  new_left.P[2] += 4.0;
  new_right.P[2] += 4.0;
  ASSERT_TRUE(callSet("left", new_left, &srv));
  EXPECT_TRUE(srv.response.success) << srv.response.status_message;
  EXPECT_EQ(srv.response.status_message.rfind("staged:", 0), 0u) << srv.response.status_message;
  ASSERT_TRUE(framesLater(3));
  EXPECT_EQ(left.snapshot().back()->P[2], old_left.P[2]) << "the left half of the new pair is in force alone";
  ASSERT_TRUE(callSet("right", new_right, &srv));
  EXPECT_TRUE(srv.response.success) << srv.response.status_message;
  EXPECT_NE(srv.response.status_message.find("with the staged left"), std::string::npos)
      << srv.response.status_message;
  ASSERT_TRUE(left.waitFor([&](const auto& m) { return m.back()->P[2] == new_left.P[2]; }, 5.0));

  // 2. Tx alone (the baseline 1 % longer), right first: staged until the left call, which itself
  //    changes nothing.
  CameraInfo longer = new_right;
  longer.P[3] *= 1.01;
  ASSERT_TRUE(callSet("right", longer, &srv));
  EXPECT_EQ(srv.response.status_message.rfind("staged:", 0), 0u) << srv.response.status_message;
  ASSERT_TRUE(framesLater(3));
  EXPECT_EQ(right.snapshot().back()->P[3], new_right.P[3]) << "the new baseline is in force before its pair";
  ASSERT_TRUE(callSet("left", new_left, &srv));
  EXPECT_NE(srv.response.status_message.find("with the staged right"), std::string::npos)
      << srv.response.status_message;
  ASSERT_TRUE(right.waitFor([&](const auto& m) { return m.back()->P[3] == longer.P[3]; }, 5.0));
  ASSERT_TRUE(framesLater(2));

  // 3. Each epoch was published with one pair, and the pairs were the three above.
  std::map<uint32_t, std::set<std::vector<double>>> pairs;
  for (const auto& f : matchFrames(modes, left, right))
    pairs[f.mode->calibration_epoch].insert({f.left->P[2], f.right->P[2], f.right->P[3]});
  for (const auto& [epoch, seen] : pairs) EXPECT_EQ(seen.size(), 1u) << "epoch " << epoch << " mixed pairs";
  EXPECT_EQ(pairs.size(), 3u) << "the old pair and the two new ones, each with an epoch of its own";
  EXPECT_TRUE(manager.unload(kName));
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "driver_calibration_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
