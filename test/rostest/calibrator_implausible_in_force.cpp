// rostest: "calibration in force confirmed" is never said of an implausible calibration
// (calibrator_implausible_in_force.test).
#include <gtest/gtest.h>
#include <ros/package.h>

#include <fstream>
#include <regex>
#include <sstream>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::kInForceConfirmedReason;
using embedded_calibration_stereo::Recalibrate;

namespace {

// config/sim_rig.yaml with the rig's focal lengths (fx, fy of both cameras) scaled.
std::string scaledDevice(const std::string& dir, double scale) {
  std::ifstream in(ros::package::getPath("embedded_calibration_stereo") + "/config/sim_rig.yaml");
  std::stringstream text;
  text << in.rdbuf();
  std::string yaml = text.str(), out;
  const std::regex focal(R"(^(\s+f[xy]:\s*)([0-9.]+))");
  std::istringstream lines(yaml);
  int scaled = 0;
  for (std::string line; std::getline(lines, line);) {
    std::smatch m;
    if (std::regex_search(line, m, focal)) {
      line = m[1].str() + std::to_string(std::stod(m[2].str()) * scale) + m.suffix().str();
      ++scaled;
    }
    out += line + "\n";
  }
  EXPECT_EQ(scaled, 4) << "fx, fy of both cameras";
  const std::string path = dir + "/device_x" + std::to_string(scale) + ".yaml";
  std::ofstream(path) << out;
  return path;
}

// A dry-run request of 5 frames to a calibrator loaded with `device_config`; its status' reason.
std::string dryRunReason(test_support::InProcessManager* manager, const std::string& device_config) {
  const std::string name = "/stereo/online_calibrator";
  EXPECT_TRUE(manager->load(name, {{"device_config", device_config}, {"auto_calibrate", false}},
                            "embedded_calibration_stereo/OnlineCalibrator",
                            {{"/stereo/calibration/observations", "/stereo/ground_truth/observations"}}));
  EXPECT_TRUE(ros::service::waitForService("/stereo/calibration/recalibrate", 20000));
  Recalibrate srv;
  srv.request.frames = 5;
  srv.request.timeout_s = 10.0;
  srv.request.dry_run = true;
  EXPECT_TRUE(ros::service::call("/stereo/calibration/recalibrate", srv));
  manager->unload(name);
  std::printf("device %s: %s; status: %s\n", device_config.c_str(), srv.response.message.c_str(),
              srv.response.status.reason.c_str());
  return srv.response.status.reason;
}

}  // namespace

TEST(CalibratorImplausibleInForce, NeverConfirmsACalibrationFarFromTheNominalCameras) {
  ros::NodeHandle nh("/stereo");
  ASSERT_TRUE(ros::service::waitForService("/stereo/set_light", 20000));
  const test_support::TempDir temp("ecs_calibrator_implausible");
  test_support::InProcessManager manager;
  // Control: the head's own description; the calibration in force is the truth: confirmed.
  const std::string control = dryRunReason(&manager, scaledDevice(temp.path, 1.0));
  EXPECT_EQ(control.rfind(kInForceConfirmedReason, 0), 0u) << control;
  // Nominal cameras 1.3x longer: the calibration in force (the truth) is 1/1.3 of them.
  const std::string far = dryRunReason(&manager, scaledDevice(temp.path, 1.3));
  EXPECT_NE(far.rfind(kInForceConfirmedReason, 0), 0u) << far;
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibrator_implausible_in_force_test");
  ros::AsyncSpinner spinner(3);
  spinner.start();
  return RUN_ALL_TESTS();
}
