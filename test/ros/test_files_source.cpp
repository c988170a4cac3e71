// Files backend: replays a generated set of image pairs in name order, with the light states
// of its CSV, loops, and refuses bad input naming the parameter.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/frame_source.h"
#include "embedded_calibration_stereo/temp_dir.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;

namespace {

// A temporary directory removed with everything in it when the test ends.
// A fresh folder per test.
struct TempDir : test_support::TempDir {
  TempDir() : test_support::TempDir("ecs_files_source") {}
};

// Pair i: left filled with 10*i+1, right with 10*i+5. Written in reverse order so that
// directory order differs from name order.
void writePairs(const std::string& dir, int count) {
  for (int i = count - 1; i >= 0; --i) {
    char name[64];
    std::snprintf(name, sizeof(name), "/left_%03d.png", i);
    cv::imwrite(dir + name, cv::Mat(24, 32, CV_8UC1, cv::Scalar(10 * i + 1)));
    std::snprintf(name, sizeof(name), "/right_%03d.png", i);
    cv::imwrite(dir + name, cv::Mat(24, 32, CV_8UC1, cv::Scalar(10 * i + 5)));
  }
}

std::string expectConfigError(const FilesSourceParams& params) {
  try {
    makeFilesFrameSource(params);
  } catch (const core::ConfigError& e) {
    return e.parameter();
  }
  return "(accepted)";
}

}  // namespace

TEST(FilesFrameSource, ReplaysPairsInNameOrderWithCsvLightStates) {
  const TempDir temp;
  const std::string& dir = temp.path;
  writePairs(dir, 5);
  std::ofstream(dir + "/light.csv") << "frame,light_on\n0,0\n1,1\n2,1\n3,0\n4,true\n";
  FilesSourceParams params;
  params.dir = dir;
  params.left_glob = "left_*.png";
  params.right_glob = "right_*.png";
  params.light_csv = dir + "/light.csv";
  auto source = makeFilesFrameSource(params);
  EXPECT_TRUE(source->recordsLightState());
  EXPECT_EQ(source->imageSize(), cv::Size(32, 24));
  const bool expected_light[] = {false, true, true, false, true};
  for (int loop = 0; loop < 2; ++loop) {
    for (int i = 0; i < 5; ++i) {
      StereoFrame frame;
      std::string error;
      ASSERT_TRUE(source->grab(0.0, &frame, &error)) << error;
      EXPECT_EQ(frame.encoding, "mono8");
      ASSERT_EQ(frame.left.type(), CV_8UC1);
      EXPECT_EQ(frame.left.at<uint8_t>(3, 3), 10 * i + 1) << "loop " << loop << " frame " << i;
      EXPECT_EQ(frame.right.at<uint8_t>(3, 3), 10 * i + 5) << "loop " << loop << " frame " << i;
      ASSERT_TRUE(frame.light_on.has_value());
      EXPECT_EQ(*frame.light_on, expected_light[i]) << "frame " << i;
    }
  }
}

TEST(FilesFrameSource, StopsAtTheEndWithoutLoopAndKeepsLastCsvState) {
  const TempDir temp;
  const std::string& dir = temp.path;
  writePairs(dir, 3);
  std::ofstream(dir + "/light.csv") << "1,1\n";  // frame 0 unlisted: off; frame 2 keeps frame 1's
  FilesSourceParams params;
  params.dir = dir;
  params.loop = false;
  params.encoding = "bgr8";
  params.light_csv = dir + "/light.csv";
  auto source = makeFilesFrameSource(params);
  const bool expected_light[] = {false, true, true};
  StereoFrame frame;
  std::string error;
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(source->grab(0.0, &frame, &error)) << error;
    EXPECT_EQ(frame.left.type(), CV_8UC3);
    EXPECT_EQ(*frame.light_on, expected_light[i]) << i;
  }
  EXPECT_FALSE(source->grab(0.0, &frame, &error));
  EXPECT_NE(error.find("end"), std::string::npos) << error;
}

TEST(FilesFrameSource, ReplaysTwoVideos) {
  const TempDir temp;
  const std::string& dir = temp.path;
  cv::VideoWriter left(dir + "/left.avi", cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 10, cv::Size(64, 48), false);
  cv::VideoWriter right(dir + "/right.avi", cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 10, cv::Size(64, 48), false);
  if (!left.isOpened() || !right.isOpened()) GTEST_SKIP() << "this OpenCV cannot write MJPG .avi";
  for (int i = 0; i < 4; ++i) {
    left.write(cv::Mat(48, 64, CV_8UC1, cv::Scalar(40 * i + 20)));
    right.write(cv::Mat(48, 64, CV_8UC1, cv::Scalar(40 * i + 30)));
  }
  left.release();
  right.release();
  FilesSourceParams params;
  params.left_video = dir + "/left.avi";
  params.right_video = dir + "/right.avi";
  auto source = makeFilesFrameSource(params);
  EXPECT_FALSE(source->recordsLightState());
  for (int i = 0; i < 6; ++i) {  // loops after the 4th frame
    StereoFrame frame;
    std::string error;
    ASSERT_TRUE(source->grab(0.0, &frame, &error)) << error;
    EXPECT_NEAR(frame.left.at<uint8_t>(24, 32), 40 * (i % 4) + 20, 3) << i;  // JPEG is lossy
    EXPECT_NEAR(frame.right.at<uint8_t>(24, 32), 40 * (i % 4) + 30, 3) << i;
    EXPECT_FALSE(frame.light_on.has_value());
  }
}

TEST(FilesFrameSource, BadInputNamesTheParameter) {
  const TempDir temp;
  const std::string& dir = temp.path;
  FilesSourceParams params;
  params.dir = dir + "/missing";
  EXPECT_EQ(expectConfigError(params), "files_dir");
  params.dir = dir;  // exists but empty
  EXPECT_EQ(expectConfigError(params), "files_left_glob");
  writePairs(dir, 3);
  std::remove((dir + "/right_002.png").c_str());
  EXPECT_EQ(expectConfigError(params), "files_right_glob");
  writePairs(dir, 3);
  params.light_csv = dir + "/missing.csv";
  EXPECT_EQ(expectConfigError(params), "files_light_csv");
  std::ofstream(dir + "/bad.csv") << "frame,light_on\n0,1\n1,maybe\n";
  params.light_csv = dir + "/bad.csv";
  EXPECT_EQ(expectConfigError(params), "files_light_csv");
  params.light_csv.clear();
  params.encoding = "rgb16";
  EXPECT_EQ(expectConfigError(params), "encoding");
  FilesSourceParams videos;
  videos.left_video = dir + "/nope.avi";
  videos.right_video = dir + "/nope.avi";
  EXPECT_EQ(expectConfigError(videos), "files_left_video");
}
