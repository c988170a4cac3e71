// rostest: files backend replay and serial light backend, driver loaded in-process.
#include <gtest/gtest.h>
#include <poll.h>
#include <pty.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/SetBool.h>
#include <unistd.h>

#include <fstream>
#include <map>
#include <opencv2/imgcodecs.hpp>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using test_support::Collector;

TEST(DriverBackends, FilesReplayPublishesTheImagesWithTheirCsvLightStates) {
  const test_support::TempDir temp("ecs_driver_files");
  const std::string& dir = temp.path;
  ASSERT_FALSE(dir.empty());
  // Pair i: left filled with 20*i+3, right with 20*i+13; light pattern from the CSV.
  const int kFrames = 8;
  const bool light[kFrames] = {false, false, true, true, true, true, false, false};
  std::ofstream csv(dir + "/light.csv");
  csv << "frame,light_on\n";
  for (int i = 0; i < kFrames; ++i) {
    char name[64];
    std::snprintf(name, sizeof(name), "/left_%02d.png", i);
    cv::imwrite(dir + name, cv::Mat(30, 40, CV_8UC1, cv::Scalar(20 * i + 3)));
    std::snprintf(name, sizeof(name), "/right_%02d.png", i);
    cv::imwrite(dir + name, cv::Mat(30, 40, CV_8UC1, cv::Scalar(20 * i + 13)));
    csv << i << "," << (light[i] ? 1 : 0) << "\n";
  }
  csv.close();

  ros::NodeHandle nh("/files");
  Collector<sensor_msgs::Image> left(nh, "left/image_raw"), right(nh, "right/image_raw");
  Collector<CalibrationMode> modes(nh, "calibration_mode");
  test_support::InProcessManager manager;
  ASSERT_TRUE(manager.load("/files/camera_driver",
                           {{"backend", "files"}, {"files_dir", dir}, {"files_light_csv", dir + "/light.csv"},
                            {"fps", 20.0}, {"settle_frames", 1},
                            {"left_camera_info_url", "file://" + dir + "/cal/left.yaml"},
                            {"right_camera_info_url", "file://" + dir + "/cal/right.yaml"}}));
  ASSERT_TRUE(modes.waitForCount(2 * kFrames + 2, 20.0));
  ASSERT_TRUE(left.waitForCount(2 * kFrames, 5.0));
  ASSERT_TRUE(right.waitForCount(2 * kFrames, 5.0));
  manager.unload("/files/camera_driver");

  std::map<ros::Time, int> right_values;
  for (const auto& r : right.snapshot()) right_values[r->header.stamp] = r->data[0];
  std::map<ros::Time, CalibrationMode::ConstPtr> mode_by_stamp;
  for (const auto& m : modes.snapshot()) mode_by_stamp[m->header.stamp] = m;
  int checked = 0, previous_index = -1;
  for (const auto& l : left.snapshot()) {
    ASSERT_EQ(l->encoding, "mono8");
    ASSERT_EQ(l->width, 40u);
    const int value = l->data[0];
    ASSERT_EQ((value - 3) % 20, 0) << "left pixel " << value << " is no generated frame";
    const int index = (value - 3) / 20;
    if (previous_index >= 0) {
      EXPECT_EQ(index, (previous_index + 1) % kFrames) << "frames out of name order";
    }
    previous_index = index;
    ASSERT_TRUE(right_values.count(l->header.stamp)) << "no right image with the left stamp";
    EXPECT_EQ(right_values[l->header.stamp], 20 * index + 13);
    ASSERT_TRUE(mode_by_stamp.count(l->header.stamp)) << "no calibration_mode with the left stamp";
    const auto& mode = mode_by_stamp[l->header.stamp];
    EXPECT_EQ(mode->light_on, light[index]) << "frame " << index;
    // settle_frames 1: the frame of each recorded switch is unsettled, the others settled.
    const bool switched = light[index] != light[(index + kFrames - 1) % kFrames];
    if (checked > 0) {
      EXPECT_EQ(mode->settled, !switched) << "frame " << index;
    }
    ++checked;
  }
  EXPECT_GE(checked, 2 * kFrames);
}

TEST(DriverBackends, SerialLightWritesTheConfiguredStrings) {
  int master = -1, slave = -1;
  char slave_name[256];
  ASSERT_EQ(openpty(&master, &slave, slave_name, nullptr, nullptr), 0);
  // Reads until `expected.size()` bytes arrived or the deadline passed.
  auto readBytes = [master](size_t count, int timeout_ms) {
    std::string out;
    pollfd p{master, POLLIN, 0};
    while (out.size() < count && poll(&p, 1, timeout_ms) > 0) {
      char buf[64];
      const ssize_t n = read(master, buf, std::min(sizeof(buf), count - out.size()));
      if (n <= 0) break;
      out.append(buf, static_cast<size_t>(n));
    }
    return out;
  };
  const test_support::TempDir temp("ecs_driver_serial");
  const std::string& dir = temp.path;
  ros::NodeHandle nh("/serial");
  Collector<CalibrationMode> modes(nh, "calibration_mode");
  test_support::InProcessManager manager;
  ASSERT_TRUE(manager.load("/serial/camera_driver",
                           {{"backend", "sim"}, {"light_backend", "serial"}, {"serial_port", std::string(slave_name)},
                            {"serial_baud", 57600}, {"serial_on", "\\x02LAMP ON\\r\\n"}, {"serial_off", "LAMP OFF\\n"},
                            {"fps", 10.0}, {"settle_frames", 1},
                            {"left_camera_info_url", "file://" + dir + "/left.yaml"},
                            {"right_camera_info_url", "file://" + dir + "/right.yaml"}}));
  const std::string on = "\x02LAMP ON\r\n", off = "LAMP OFF\n";
  EXPECT_EQ(readBytes(off.size(), 10000), off) << "initial state not written";
  std_srvs::SetBool srv;
  srv.request.data = true;
  ASSERT_TRUE(ros::service::call("/serial/set_light", srv));
  EXPECT_EQ(readBytes(on.size(), 5000), on);
  ASSERT_TRUE(modes.waitFor([](const auto& m) { return !m.empty() && m.back()->light_on; }, 5.0));
  srv.request.data = false;
  ASSERT_TRUE(ros::service::call("/serial/set_light", srv));
  EXPECT_EQ(readBytes(off.size(), 5000), off);
  // No switch, nothing written.
  EXPECT_EQ(readBytes(1, 300), "");
  manager.unload("/serial/camera_driver");
  close(master);
  close(slave);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "driver_backends_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
