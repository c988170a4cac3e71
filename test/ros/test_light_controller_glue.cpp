// The LightController's and the CameraDriver's ROS glue, without a master: the one reader of
// the light backend's parameters (each caller's default and rules), the LightController's
// parameters, the drivers' "staged" set_camera_info answer, the epoch counted from an external
// driver's camera_info, and the calibration_store "file" (refusals, staging, reloads).
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/parameter_table.h"
#include "embedded_calibration_stereo/rectified_pair.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/driver_calibration_watch.h"
#include "embedded_calibration_stereo/ros/light_backend.h"
#include "embedded_calibration_stereo/ros/light_controller_params.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/reloading_calibration_store.h"
#include "embedded_calibration_stereo/ros/set_camera_info_answer.h"
#include "embedded_calibration_stereo/temp_dir.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;
using sensor_msgs::CameraInfo;
using XmlRpc::XmlRpcValue;

namespace {

using Params = embedded_calibration_stereo::test_support::ParameterTable;

// The parameter named by the ConfigError `f` throws ("" when it does not throw).
template <class F>
std::string refused(F f) {
  try {
    f();
  } catch (const core::ConfigError& e) {
    return e.parameter();
  }
  return "";
}

LightBackendParams readBackend(const Params& p, const std::string& default_backend = "none") {
  return readLightBackendParams(p.reader(), default_backend);
}

}  // namespace

TEST(LightBackendParams, TheCallersDefaultAppliesWhenLightBackendIsAbsent) {
  EXPECT_EQ(readBackend(Params(), "sim").backend, "sim");    // the CameraDriver with the sim backend
  EXPECT_EQ(readBackend(Params(), "none").backend, "none");  // the LightController, other backends
  EXPECT_EQ(readBackend(Params().set("light_backend", std::string("sim")), "none").backend, "sim");
  EXPECT_EQ(refused([] { readBackend(Params().set("light_backend", std::string("laser"))); }), "light_backend");
}

TEST(LightBackendParams, SerialNeedsAPortAndDecodesItsByteStrings) {
  Params p;
  p.set("light_backend", std::string("serial"));
  EXPECT_EQ(refused([&] { readBackend(p); }), "serial_port") << "absent";
  p.set("serial_port", std::string(""));
  EXPECT_EQ(refused([&] { readBackend(p); }), "serial_port") << "empty";
  p.set("serial_port", std::string("/dev/ttyUSB0")).set("serial_on", std::string("L1\\r\\x01"));
  const LightBackendParams read = readBackend(p);
  EXPECT_EQ(read.serial.port, "/dev/ttyUSB0");
  EXPECT_EQ(read.serial.baud, 115200);
  EXPECT_EQ(read.serial.on_bytes, std::string("L1\r\x01"));
  EXPECT_EQ(read.serial.off_bytes, "OFF\n");
  p.set("serial_off", std::string("\\q"));
  EXPECT_EQ(refused([&] { readBackend(p); }), "serial_off");
}

TEST(LightBackendParams, GpioNeedsALineAndTheOtherBackendsParametersAreNotRead) {
  Params p;
  p.set("light_backend", std::string("gpio")).set("serial_port", 5);  // wrongly typed, but not read
  EXPECT_EQ(refused([&] { readBackend(p); }), "gpio_line");
  p.set("gpio_line", -2);
  EXPECT_EQ(refused([&] { readBackend(p); }), "gpio_line");
  p.set("gpio_line", 17).set("gpio_active_low", true);
  const LightBackendParams read = readBackend(p);
  EXPECT_EQ(read.gpio.line, 17);
  EXPECT_EQ(read.gpio.chip, "gpiochip0");
  EXPECT_TRUE(read.gpio.active_low);
  Params none;
  none.set("gpio_line", std::string("x")).set("serial_baud", std::string("fast"));
  EXPECT_EQ(refused([&] { readBackend(none); }), "") << "light_backend none read a backend's parameters";
}

TEST(LightControllerParams, DefaultsAndTheFileStoresRequiredUrls) {
  Params p;
  const LightControllerParams d = loadLightControllerParams(p.reader(), "/tmp/prior.yaml");
  EXPECT_EQ(d.light.backend, "none");
  EXPECT_EQ(d.schedule.settle_frames, 5) << "the external driver's delay: more than the CameraDriver's 2";
  EXPECT_EQ(d.schedule.calibration_frames, 0) << "a burst's length is a time by default";
  EXPECT_GT(d.schedule.calibration_duration_s, 0.0);
  Params untimed;
  untimed.set("calibration_duration_s", 0.0);
  EXPECT_EQ(refused([&] { loadLightControllerParams(untimed.reader(), ""); }), "calibration_duration_s");
  untimed.set("calibration_frames", 12);
  EXPECT_EQ(loadLightControllerParams(untimed.reader(), "").schedule.calibration_frames, 12);
  EXPECT_EQ(d.prior_file, "/tmp/prior.yaml");
  EXPECT_EQ(d.calibration_store, "driver");
  p.set("calibration_store", std::string("file"));
  EXPECT_EQ(refused([&] { loadLightControllerParams(p.reader(), ""); }), "left_camera_info_url");
  p.set("left_camera_info_url", std::string("file:///tmp/l.yaml"));
  EXPECT_EQ(refused([&] { loadLightControllerParams(p.reader(), ""); }), "right_camera_info_url");
  p.set("light_backend", std::string("serial"));
  EXPECT_EQ(refused([&] { loadLightControllerParams(p.reader(), ""); }), "serial_port")
      << "the light backend is read as the CameraDriver reads it";
}

TEST(SetCameraInfoAnswer, OnlyASuccessfulAnswerWithThePrefixIsStaged) {
  sensor_msgs::SetCameraInfo::Response res;
  res.success = true;
  res.status_message = stagedAnswer("P does not match");
  EXPECT_EQ(res.status_message, "staged: P does not match");
  EXPECT_TRUE(isStagedAnswer(res));
  EXPECT_TRUE(isStagedAnswer(res.status_message));
  res.success = false;
  EXPECT_FALSE(isStagedAnswer(res)) << "a refusal is never staged";
  res.success = true;
  for (const std::string& other : {"stored in /a", "", "stage", "rejected: staged: x", " staged: x"}) {
    res.status_message = other;
    EXPECT_FALSE(isStagedAnswer(res)) << "'" << other << "' (a stock driver's answer) read as staged";
  }
}

namespace {

constexpr uint32_t kWidth = test_support::kPairWidth, kHeight = test_support::kPairHeight;

using test_support::pairWithFocal;

}  // namespace

TEST(DriverCalibrationWatch, CountsEachCamerasCalibrationChangesNotTheFirstNorTheHeader) {
  DriverCalibrationWatch watch;
  auto pair = pairWithFocal(600);
  EXPECT_FALSE(watch.update(0, pair.first)) << "the first camera_info is no change";
  EXPECT_FALSE(watch.update(1, pair.second));
  pair.first.header.stamp = ros::Time(5);
  EXPECT_FALSE(watch.update(0, pair.first)) << "a new stamp is no new calibration";
  EXPECT_EQ(watch.epoch(), 0u);
  const auto next = pairWithFocal(640);
  EXPECT_TRUE(watch.update(0, next.first));
  EXPECT_TRUE(watch.update(1, next.second));
  EXPECT_EQ(watch.epoch(), 2u) << "one per camera, as the CameraDriver counts set_camera_info calls";
  EXPECT_FALSE(watch.uncalibrated(0));
  CameraInfo blank = next.first;
  blank.K.fill(0.0);
  watch.update(0, blank);
  EXPECT_TRUE(watch.uncalibrated(0));
  EXPECT_FALSE(watch.uncalibrated(1));
  ASSERT_TRUE(watch.latest()[1]);
  EXPECT_EQ(watch.latest()[1]->P[0], 640.0);
}

namespace {

// A fresh folder per test.
struct TempDir : test_support::TempDir {
  TempDir() : test_support::TempDir("ecs_reloading_store") {}
};

struct StoreFixture {
  TempDir dir;
  std::vector<std::pair<std::string, std::string>> reloads;  // service, url
  bool reload_available = true;
  std::vector<std::string> log;
  ReloadingCalibrationStore store{
      {{"stereo_left", "file://" + dir.path + "/left.yaml", "left_camera_info_url"}, "left_driver/set_parameters"},
      {{"stereo_right", "file://" + dir.path + "/right.yaml", "right_camera_info_url"}, "right_driver/set_parameters"},
      10.0, [this](ReloadingCalibrationStore::Severity, const std::string& text) { log.push_back(text); },
      [this](const std::string& service, const std::string& url) {
        reloads.emplace_back(service, url);
        return reload_available;
      }};
  std::optional<CameraInfo> in_force[2];

  sensor_msgs::SetCameraInfo::Response set(bool left, const CameraInfo& info) {
    sensor_msgs::SetCameraInfo::Response res;
    store.set(left, info, in_force, &res);
    return res;
  }
};

}  // namespace

TEST(ReloadingCalibrationStore, RefusesBeforeTheDriversImageSizeIsKnownAndOtherSizes) {
  StoreFixture f;
  const auto pair = pairWithFocal(640);
  auto res = f.set(true, pair.first);
  EXPECT_FALSE(res.success);
  EXPECT_NE(res.status_message.find("no camera_info from the driver yet"), std::string::npos) << res.status_message;
  const auto in_force = pairWithFocal(600);
  f.in_force[0] = in_force.first;
  f.in_force[1] = in_force.second;
  CameraInfo other_size = pair.first;
  other_size.width = 640;
  res = f.set(true, other_size);
  EXPECT_FALSE(res.success);
  EXPECT_NE(res.status_message.find("but the driver's images are 752x480"), std::string::npos) << res.status_message;
  EXPECT_TRUE(f.reloads.empty());
  EXPECT_FALSE(std::filesystem::exists(f.dir.path + "/left.yaml"));
}

TEST(ReloadingCalibrationStore, AStagedHalfReloadsNothingAStoredPairReloadsBothDrivers) {
  StoreFixture f;
  const auto in_force = pairWithFocal(600);
  f.in_force[0] = in_force.first;
  f.in_force[1] = in_force.second;
  const auto pair = pairWithFocal(640);
  auto res = f.set(true, pair.first);
  EXPECT_TRUE(isStagedAnswer(res)) << res.status_message;
  EXPECT_TRUE(f.reloads.empty()) << "a staged calibration (nothing written) made a driver reload";
  res = f.set(false, pair.second);
  EXPECT_TRUE(res.success) << res.status_message;
  EXPECT_FALSE(isStagedAnswer(res));
  ASSERT_EQ(f.reloads.size(), 2u);
  EXPECT_EQ(f.reloads[0], std::make_pair(std::string("left_driver/set_parameters"), "file://" + f.dir.path + "/left.yaml"));
  EXPECT_EQ(f.reloads[1].first, "right_driver/set_parameters");
  EXPECT_TRUE(std::filesystem::exists(f.dir.path + "/left.yaml"));
}

TEST(ReloadingCalibrationStore, AReloadServiceNotAvailableFailsTheCall) {
  StoreFixture f;
  f.reload_available = false;
  const auto in_force = pairWithFocal(600);
  f.in_force[0] = in_force.first;
  f.in_force[1] = in_force.second;
  const auto pair = pairWithFocal(640);
  f.set(true, pair.first);
  const auto res = f.set(false, pair.second);
  EXPECT_FALSE(res.success);
  EXPECT_NE(res.status_message.find("but the driver did not reload it: left_driver/set_parameters is not available"),
            std::string::npos)
      << res.status_message;
}
