// rostest: the health leaves GOOD and asks for a calibration when depth's valid fraction
// collapses against its own history, recovers with it, and calls a calibration in force with
// implausible focal lengths BAD (health_depth_watch.test).
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <atomic>
#include <random>
#include <string>
#include <utility>

#include "driver_test_utils.h"
#include "health_test_utils.h"
#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/DisparityCoverage.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationHealth;
using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::DisparityCoverage;
using test_support::Collector;
using test_support::lastHealth;
using test_support::latestPair;
using sensor_msgs::CameraInfo;
using Healths = std::vector<CalibrationHealth::ConstPtr>;
using Modes = std::vector<CalibrationMode::ConstPtr>;

namespace {

// Publishes, for every light-off frame of the driver, the valid fraction `level` (+-0.03), as
// the Disparity nodelet would.
class CoverageSource {
 public:
  explicit CoverageSource(ros::NodeHandle& nh) {
    pub_ = nh.advertise<DisparityCoverage>("disparity_coverage", 30);
    sub_ = nh.subscribe<CalibrationMode>("calibration_mode", 30, [this](const CalibrationMode::ConstPtr& mode) {
      if (mode->light_on) return;
      DisparityCoverage msg;
      msg.header.stamp = mode->header.stamp;
      std::lock_guard<std::mutex> lock(mutex_);
      msg.valid_fraction = static_cast<float>(level_ + noise_(rng_));
      pub_.publish(msg);
    });
  }
  ~CoverageSource() { sub_.shutdown(); }
  void setLevel(double level) {
    std::lock_guard<std::mutex> lock(mutex_);
    level_ = level;
  }

 private:
  ros::Publisher pub_;
  ros::Subscriber sub_;
  std::mutex mutex_;
  double level_ = 0.6;
  std::mt19937 rng_{7};
  std::uniform_real_distribution<double> noise_{-0.03, 0.03};
};

// A calibration burst since `from`: more settled light-on frames in a row than a verification
// flash has (one). The driver's default burst is 0.33 s, 5 frames at this test's 15 fps.
bool burstSince(const Modes& m, size_t from) {
  int run = 0;
  for (size_t i = from; i < m.size(); ++i) {
    run = m[i]->light_on && m[i]->settled ? run + 1 : 0;
    if (run >= 4) return true;
  }
  return false;
}

// Puts a calibration pair in force through the driver's set_camera_info services.
void setCalibration(const std::pair<CameraInfo, CameraInfo>& pair) {
  for (const auto& [service, info] : {std::make_pair("left/set_camera_info", pair.first),
                                      std::make_pair("right/set_camera_info", pair.second)}) {
    sensor_msgs::SetCameraInfo srv;
    srv.request.camera_info = info;
    ASSERT_TRUE(ros::service::call(service, srv));
    ASSERT_TRUE(srv.response.success) << srv.response.status_message;
  }
}

}  // namespace

TEST(HealthDepthWatch, ACollapseOfDepthLeavesGoodAndAnImplausibleCalibrationIsBad) {
  ros::NodeHandle nh;
  Collector<CalibrationHealth> health(nh, "calibration/health", 2000);
  Collector<CalibrationMode> modes(nh, "calibration_mode", 3000);
  Collector<CameraInfo> left(nh, "left/camera_info", 50), right(nh, "right/camera_info", 50);
  CoverageSource coverage(nh);
  ASSERT_TRUE(ros::service::waitForService("left/set_camera_info", 20000));

  // 0. The driver's device description has no cameras, so it starts uncalibrated (it never
  // publishes the simulator's truth): the simulated cameras are put in force, as a calibration.
  ASSERT_TRUE(left.waitForCount(1, 20.0)) << "no left/camera_info";
  EXPECT_EQ(left.snapshot().front()->K[0], 0.0) << "the driver published a calibration its device description has not";
  const core::StereoRig truth = core::loadSimRigConfig(std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml").rig;
  setCalibration(embedded_calibration_stereo::toStereoCameraInfo(truth));

  // 1. GOOD, and still GOOD once the coverage history spans its 10 s.
  const auto good = [](const Healths& m) {
    return !m.empty() && m.back()->state == CalibrationHealth::GOOD && m.back()->verification_age_s >= 0.0;
  };
  ASSERT_TRUE(health.waitFor(good, 20.0)) << lastHealth(health);
  const ros::WallTime history_full = ros::WallTime::now() + ros::WallDuration(13.0);
  ASSERT_FALSE(health.waitFor([&](const Healths& m) { return ros::WallTime::now() > history_full && !good(m); },
                              14.0))
      << "left GOOD with steady depth: " << lastHealth(health);

  // 2. Depth collapses (3 % valid against 60 %): not GOOD, a calibration wanted, a burst.
  const size_t modes_before = modes.snapshot().size();
  coverage.setLevel(0.03);
  const ros::WallTime collapsed = ros::WallTime::now();
  ASSERT_TRUE(health.waitFor(
      [](const Healths& m) {
        return !m.empty() && m.back()->state >= CalibrationHealth::DEGRADED && m.back()->calibration_wanted &&
               m.back()->reason.find("valid disparity") != std::string::npos;
      },
      5.0))
      << lastHealth(health);
  std::printf("depth collapsed: left GOOD after %.2f s: %s\n", (ros::WallTime::now() - collapsed).toSec(),
              health.snapshot().back()->reason.c_str());
  EXPECT_TRUE(modes.waitFor([&](const Modes& m) { return burstSince(m, modes_before); }, 6.0))
      << "no calibration burst after depth collapsed";

  // 3. Depth back: GOOD again.
  coverage.setLevel(0.6);
  ASSERT_TRUE(health.waitFor(good, 10.0)) << lastHealth(health);

  // 4. A calibration whose focal lengths are 1.3x the device's nominal ones (the limit is 1.25x).
  CameraInfo in_force_left, in_force_right;
  ASSERT_TRUE(latestPair(left, right, &in_force_left, &in_force_right));
  core::StereoRig rig;
  std::string error;
  ASSERT_TRUE(embedded_calibration_stereo::fromStereoCameraInfo(in_force_left, in_force_right, &rig, &error)) << error;
  rig.left = rig.left.withFocalScale(1.3);
  rig.right = rig.right.withFocalScale(1.3);
  const uint32_t epoch_before = modes.snapshot().back()->calibration_epoch;
  setCalibration(embedded_calibration_stereo::toStereoCameraInfo(rig));
  ASSERT_TRUE(health.waitFor(
      [&](const Healths& m) {
        return !m.empty() && m.back()->epoch != epoch_before && m.back()->state == CalibrationHealth::BAD &&
               m.back()->calibration_wanted && m.back()->reason.find("not plausible") != std::string::npos &&
               m.back()->reason.find("fx") != std::string::npos;
      },
      5.0))
      << lastHealth(health);
  std::printf("implausible calibration: %s\n", health.snapshot().back()->reason.c_str());
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "health_depth_watch_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
