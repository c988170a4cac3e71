// rostest: every bad configuration makes onInit fail loudly, naming the parameter.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "driver_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using Params = test_support::InProcessManager::Params;

namespace {

class DriverBadConfig : public testing::Test {
 protected:
  void SetUp() override {
    ASSERT_FALSE(dir_.empty());
    log_ = std::make_unique<Collector<rosgraph_msgs::Log>>(nh_, "/rosout", 1000);
  }

  // Loads the driver with `params` (plus writable calibration URLs) and expects onInit to fail
  // with a FATAL message naming `parameter`.
  void expectFailure(Params params, const std::string& parameter, const std::string& detail = "") {
    const std::string name = "/stereo/bad_" + std::to_string(++count_);
    if (!params.count("left_camera_info_url")) params["left_camera_info_url"] = "file://" + dir_ + "/l.yaml";
    if (!params.count("right_camera_info_url")) params["right_camera_info_url"] = "file://" + dir_ + "/r.yaml";
    log_->clear();
    EXPECT_FALSE(manager_.load(name, params)) << "the driver accepted a bad " << parameter;
    std::vector<std::string> needles = {"CameraDriver cannot start", parameter};
    if (!detail.empty()) needles.push_back(detail);
    std::string found;
    EXPECT_TRUE(test_support::waitForLog(*log_, needles, 10.0, &found)) << "no FATAL message naming " << parameter;
    std::printf("  %s -> \"%s\"\n", parameter.c_str(), found.c_str());
    manager_.unload(name);
  }

  std::string writeFile(const std::string& name, const std::string& text) {
    const std::string path = dir_ + "/" + name;
    std::ofstream(path) << text;
    return path;
  }

  ros::NodeHandle nh_;
  const test_support::TempDir temp_{"ecs_driver_bad_config"};
  const std::string& dir_ = temp_.path;
  std::unique_ptr<Collector<rosgraph_msgs::Log>> log_;
  test_support::InProcessManager manager_;
  int count_ = 0;
};

std::string simConfigText() {
  std::ifstream in(std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml");
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

}  // namespace

TEST_F(DriverBadConfig, MissingOrMalformedSimConfig) {
  expectFailure({{"backend", "sim"}, {"sim_config", dir_ + "/no_such_rig.yaml"}}, "sim_config", "no_such_rig.yaml");
  expectFailure({{"backend", "sim"}, {"sim_config", writeFile("garbage.yaml", "%YAML:1.0\n---\nrig: [unclosed\n")}},
                "sim_config");
}

TEST_F(DriverBadConfig, NonPositiveFocalLength) {
  std::string text = simConfigText();
  const size_t at = text.find("fx: ");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, text.find('\n', at) - at, "fx: -652.4");
  expectFailure({{"backend", "sim"}, {"sim_config", writeFile("negative_fx.yaml", text)}}, "sim_config", "fx");

  // A stored calibration with fx = 0 does not stop the driver: it starts on the previous or
  // the nominal calibration with an ERROR (calibration_corrupt_file.test).
}

TEST_F(DriverBadConfig, UnknownBackends) {
  expectFailure({{"backend", "kinect"}}, "backend", "kinect");
  expectFailure({{"backend", "sim"}, {"light_backend", "laser"}}, "light_backend", "laser");
}

TEST_F(DriverBadConfig, MissingDeviceOrDirectory) {
  expectFailure({{"backend", "v4l2"}, {"v4l2_left_device", "/dev/ecs_no_such_video"}}, "v4l2_left_device",
                "/dev/ecs_no_such_video");
  expectFailure({{"backend", "files"}, {"files_dir", dir_ + "/no_such_dir"}}, "files_dir", "no_such_dir");
  expectFailure({{"backend", "files"}}, "files_dir", "missing");
  expectFailure({{"backend", "sim"}, {"light_backend", "serial"}, {"serial_port", "/dev/ecs_no_such_tty"}},
                "serial_port", "/dev/ecs_no_such_tty");
}

TEST_F(DriverBadConfig, MalformedParameters) {
  expectFailure({{"backend", "sim"}, {"fps", "fast"}}, "fps");
  expectFailure({{"backend", "sim"}, {"fps", -5.0}}, "fps");
  expectFailure({{"backend", "sim"}, {"settle_frames", -1}}, "settle_frames");
  expectFailure({{"backend", "sim"}, {"left_camera_info_url", "http://example.com/left.yaml"}}, "left_camera_info_url");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "driver_bad_config_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
