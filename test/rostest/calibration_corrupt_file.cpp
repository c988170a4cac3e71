// rostest: the driver starts on the previous calibration when its files are corrupt or
// inconsistent (calibration_corrupt_file.test).
#include <gtest/gtest.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <fstream>

#include "calibration_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using sensor_msgs::CameraInfo;

namespace {

const char* kName = "/stereo/camera_driver";

class CalibrationCorruptFile : public testing::Test {
 protected:
  void SetUp() override { ASSERT_FALSE(temp_.path.empty()); }

  test_support::InProcessManager::Params params() const {
    return {{"backend", "sim"},
            {"fps", 10.0},
            {"left_camera_info_url", "file://" + left_path_},
            {"right_camera_info_url", "file://" + right_path_}};
  }

  // Stores the pairs of fx' `focals` one after the other through set_camera_info (left, then
  // right, as a stereo calibration does), then unloads the driver.
  void storePairs(const std::vector<double>& focals) {
    ASSERT_TRUE(manager_.load(kName, params()));
    for (const double fx : focals) {
      const auto pair = test_support::pairWithFocal(fx);
      for (const bool left : {true, false}) {
        sensor_msgs::SetCameraInfo srv;
        srv.request.camera_info = left ? pair.first : pair.second;
        ASSERT_TRUE(ros::service::call(std::string("/stereo/") + (left ? "left" : "right") + "/set_camera_info", srv));
        ASSERT_TRUE(srv.response.success) << srv.response.status_message;
      }
    }
    const auto shown = test_support::shownFocals(left_path_, right_path_);
    const double stored = test_support::pairWithFocal(focals.back()).first.P[0];
    ASSERT_NEAR(shown.first, stored, 1e-3);
    ASSERT_NEAR(shown.second, stored, 1e-3);
    ASSERT_TRUE(manager_.unload(kName));
  }

  // Loads the driver and expects it to run on a consistent pair of fx' `expected_fx` (0: the
  // simulator's nominal calibration) with an ERROR naming `needle` in diagnostics and log.
  void expectStartsOn(double expected_fx, const std::string& needle) {
    ros::NodeHandle nh("/stereo");
    Collector<CameraInfo> left(nh, "left/camera_info"), right(nh, "right/camera_info");
    Collector<diagnostic_msgs::DiagnosticArray> diagnostics(nh, "/diagnostics", 100);
    Collector<rosgraph_msgs::Log> log(nh, "/rosout", 1000);
    ASSERT_TRUE(test_support::waitForRosoutPipe(log, 10.0));
    // Only frames of this driver: a pair the previous one (unloaded) published may still be
    // on its way to the collectors.
    const ros::Time loaded = ros::Time::now();
    ASSERT_TRUE(manager_.load(kName, params())) << "the driver refused to start";
    // A published pair of one stamp: consistent, and the expected calibration.
    CameraInfo::ConstPtr l, r;
    ASSERT_TRUE(right.waitFor(
        [&](const auto& rights) {
          for (const auto& ri : rights)
            for (const auto& li : left.snapshot())
              if (li->header.stamp == ri->header.stamp && ri->header.stamp >= loaded) {
                l = li;
                r = ri;
                return true;
              }
          return false;
        },
        20.0));
    EXPECT_EQ(test_support::pairProblem(*l, *r), "") << "the driver publishes a pair image_geometry would abort on";
    const auto rectified = [](double fx) { return test_support::pairWithFocal(fx).first.P[0]; };
    if (expected_fx > 0) {
      EXPECT_NEAR(l->P[0], rectified(expected_fx), 1e-3) << "not the expected calibration";
    } else {  // the simulator's nominal calibration: none of the test's
      for (const double fx : {560.0, 572.0, 600.0}) EXPECT_GT(std::abs(l->P[0] - rectified(fx)), 1.0);
    }
    std::string status;
    EXPECT_TRUE(
        test_support::waitForDriverStatus(diagnostics, diagnostic_msgs::DiagnosticStatus::ERROR, needle, 10.0, &status))
        << "no ERROR diagnostics naming " << needle;
    std::printf("  diagnostics: %s\n", status.c_str());
    EXPECT_TRUE(log.waitFor(
        [&](const auto& messages) {
          for (const auto& m : messages)
            if (m->level == rosgraph_msgs::Log::ERROR && m->msg.find(needle) != std::string::npos) return true;
          return false;
        },
        5.0))
        << "no ERROR on /rosout naming " << needle;
    EXPECT_TRUE(manager_.unload(kName));
  }

  const test_support::TempDir temp_{"ecs_calibration_corrupt_file"};
  const std::string left_path_ = temp_.path + "/left.yaml", right_path_ = temp_.path + "/right.yaml";
  test_support::InProcessManager manager_;
};

}  // namespace

TEST_F(CalibrationCorruptFile, TruncatedFileStartsOnThePreviousCalibration) {
  storePairs({560.0, 600.0});
  const std::string text = test_support::fileBytes(right_path_);
  { std::ofstream(right_path_, std::ios::trunc) << text.substr(0, text.size() / 3); }
  expectStartsOn(560.0, "right_camera_info_url");
}

// What a user running camera_calibration on the left camera alone leaves behind, written
// in place as camera_info_manager writes: a left P that does not match the right one.
TEST_F(CalibrationCorruptFile, OneCameraRecalibratedStartsOnThePreviousCalibration) {
  storePairs({560.0, 600.0});
  std::string error;
  const std::string mono = temp_.path + "/mono.yaml";
  ASSERT_TRUE(embedded_calibration_stereo::writeCalibrationFileAtomic(mono, "stereo_left",
                                                                      test_support::pairWithFocal(572.0).first, &error))
      << error;
  { std::ofstream(left_path_, std::ios::trunc) << test_support::fileBytes(mono); }
  expectStartsOn(560.0, "fx'");
}

TEST_F(CalibrationCorruptFile, CorruptFileWithoutHistoryStartsOnTheNominalCalibration) {
  { std::ofstream(left_path_) << "image_width: 752\nimage_height: [480\ncamera_matrix: {{{\n"; }
  std::string error;
  ASSERT_TRUE(embedded_calibration_stereo::writeCalibrationFileAtomic(right_path_, "stereo_right",
                                                                      test_support::pairWithFocal(600.0).second, &error))
      << error;
  expectStartsOn(0.0, "left_camera_info_url");
}

TEST_F(CalibrationCorruptFile, ZeroFocalLengthStartsOnTheNominalCalibration) {
  auto pair = test_support::pairWithFocal(600.0);
  pair.first.K[0] = 0.0;
  std::string error;
  ASSERT_TRUE(embedded_calibration_stereo::writeCalibrationFileAtomic(left_path_, "stereo_left", pair.first, &error));
  ASSERT_TRUE(
      embedded_calibration_stereo::writeCalibrationFileAtomic(right_path_, "stereo_right", pair.second, &error));
  expectStartsOn(0.0, "focal");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibration_corrupt_file_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
