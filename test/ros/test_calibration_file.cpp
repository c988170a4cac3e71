// Calibration files: URL resolution like camera_info_manager, and atomic writing (a crash at
// any moment leaves the old or the new complete file, never a broken one).
#include <dirent.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <thread>

#include "embedded_calibration_stereo/ros/calibration_file.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/temp_dir.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;

namespace {

// A temporary directory removed with everything in it when the test ends.
// A fresh folder per test.
struct TempDir : test_support::TempDir {
  TempDir() : test_support::TempDir("ecs_calibration_file") {}
};

std::vector<std::string> listDir(const std::string& dir) {
  std::vector<std::string> names;
  if (DIR* d = opendir(dir.c_str())) {
    while (dirent* e = readdir(d)) {
      const std::string n = e->d_name;
      if (n != "." && n != "..") names.push_back(n);
    }
    closedir(d);
  }
  return names;
}

sensor_msgs::CameraInfo calibration(double fx) {
  core::PinholeCamera c;
  c.width = 752;
  c.height = 480;
  c.fx = fx;
  c.fy = fx + 1;
  c.cx = 376;
  c.cy = 240;
  c.dist = {{-0.1, 0.02, 0.001, 0.002, 0.0}};
  return toCameraInfo(c);
}

}  // namespace

TEST(CalibrationUrl, ResolvesLikeCameraInfoManager) {
  std::string path, error;
  ASSERT_TRUE(resolveCalibrationUrl("file:///data/cal/${NAME}.yaml", "left_cam", &path, &error)) << error;
  EXPECT_EQ(path, "/data/cal/left_cam.yaml");
  ASSERT_TRUE(resolveCalibrationUrl("FILE:///x.yaml", "c", &path, &error)) << error;
  EXPECT_EQ(path, "/x.yaml");
  setenv("ROS_HOME", "/tmp/some_ros_home", 1);
  ASSERT_TRUE(resolveCalibrationUrl("", "right_cam", &path, &error)) << error;
  EXPECT_EQ(path, "/tmp/some_ros_home/camera_info/right_cam.yaml");
  ASSERT_TRUE(resolveCalibrationUrl("file://${ROS_HOME}/a/${NAME}.ini", "n", &path, &error)) << error;
  EXPECT_EQ(path, "/tmp/some_ros_home/a/n.ini");
  unsetenv("ROS_HOME");
}

TEST(CalibrationUrl, RefusesWhatIsNotALocalFile) {
  std::string path, error;
  EXPECT_FALSE(resolveCalibrationUrl("http://example.com/cal.yaml", "c", &path, &error));
  EXPECT_NE(error.find("http://example.com/cal.yaml"), std::string::npos) << error;
  EXPECT_FALSE(resolveCalibrationUrl("file://relative/path.yaml", "c", &path, &error));
  EXPECT_FALSE(resolveCalibrationUrl("package://no_such_package_ecs_test/cal.yaml", "c", &path, &error));
  EXPECT_NE(error.find("package"), std::string::npos) << error;
}

TEST(CalibrationFile, WritesAReadableFileAndNoTemporaryIsLeft) {
  const TempDir temp;
  const std::string& dir = temp.path;
  const std::string path = dir + "/sub/dir/left.yaml";  // parents are created
  std::string error;
  const sensor_msgs::CameraInfo written = calibration(612.5);
  ASSERT_TRUE(writeCalibrationFileAtomic(path, "left_cam", written, &error)) << error;
  std::string name;
  sensor_msgs::CameraInfo read;
  ASSERT_TRUE(readCalibrationFile(path, &name, &read, &error)) << error;
  EXPECT_EQ(name, "left_cam");
  EXPECT_EQ(read.width, written.width);
  for (int i = 0; i < 9; ++i) EXPECT_NEAR(read.K[i], written.K[i], 1e-9);
  ASSERT_EQ(read.D.size(), 5u);
  for (int i = 0; i < 5; ++i) EXPECT_NEAR(read.D[i], written.D[i], 1e-12);
  for (int i = 0; i < 12; ++i) EXPECT_NEAR(read.P[i], written.P[i], 1e-9);
  // Overwrite: the new content replaces the old one, and only the target remains.
  ASSERT_TRUE(writeCalibrationFileAtomic(path, "left_cam", calibration(700.0), &error)) << error;
  ASSERT_TRUE(readCalibrationFile(path, &name, &read, &error)) << error;
  EXPECT_NEAR(read.K[0], 700.0, 1e-9);
  EXPECT_EQ(listDir(dir + "/sub/dir"), std::vector<std::string>{"left.yaml"});
}

TEST(CalibrationFile, IniNameWritesTheIniFormat) {
  const TempDir temp;
  const std::string path = temp.path + "/cam.ini";
  std::string error;
  ASSERT_TRUE(writeCalibrationFileAtomic(path, "cam", calibration(600.0), &error)) << error;
  std::ifstream in(path);
  std::string first_line;
  std::getline(in, first_line);
  EXPECT_EQ(first_line.find("# Camera intrinsics"), 0u) << first_line;
  sensor_msgs::CameraInfo read;
  ASSERT_TRUE(readCalibrationFile(path, nullptr, &read, &error)) << error;
  EXPECT_NEAR(read.K[0], 600.0, 1e-6);
}

TEST(CalibrationFile, UnwritableTargetFailsWithAReasonAndLeavesNothingBehind) {
  const TempDir temp;
  const std::string& dir = temp.path;
  std::string error;
  // Parent is a regular file: no directory can be created there (even as root).
  { std::ofstream(dir + "/plain_file") << "x"; }
  EXPECT_FALSE(writeCalibrationFileAtomic(dir + "/plain_file/cal.yaml", "c", calibration(600), &error));
  EXPECT_NE(error.find("plain_file"), std::string::npos) << error;
  // Target is a directory: rename fails; the temporary file must be removed.
  ASSERT_EQ(mkdir((dir + "/target.yaml").c_str(), 0755), 0);
  { std::ofstream(dir + "/target.yaml/keep") << "x"; }
  error.clear();
  EXPECT_FALSE(writeCalibrationFileAtomic(dir + "/target.yaml", "c", calibration(600), &error));
  EXPECT_NE(error.find("rename"), std::string::npos) << error;
  auto names = listDir(dir);
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"plain_file", "target.yaml"}));
}

TEST(CalibrationFile, CrashAtAnyMomentLeavesAnOldOrNewCompleteFile) {
  const TempDir temp;
  const std::string& dir = temp.path;
  const std::string path = dir + "/cal.yaml";
  std::string error;
  ASSERT_TRUE(writeCalibrationFileAtomic(path, "c", calibration(500.0), &error)) << error;
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> delay_us(0, 3000);
  for (int trial = 0; trial < 25; ++trial) {
    const pid_t child = fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      // Alternate two calibrations as fast as possible until killed.
      for (int i = 0;; ++i) writeCalibrationFileAtomic(path, "c", calibration(i % 2 ? 600.0 : 500.0), nullptr);
    }
    std::this_thread::sleep_for(std::chrono::microseconds(delay_us(rng)));
    kill(child, SIGKILL);
    int status = 0;
    waitpid(child, &status, 0);
    sensor_msgs::CameraInfo read;
    ASSERT_TRUE(readCalibrationFile(path, nullptr, &read, &error)) << "trial " << trial << ": " << error;
    EXPECT_TRUE(read.K[0] == 500.0 || read.K[0] == 600.0) << read.K[0];
    EXPECT_EQ(read.width, 752u);
    EXPECT_EQ(read.D.size(), 5u);
  }
}
