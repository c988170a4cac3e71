// rostest: automatic calibration at the end of each light-on window of the driver's schedule.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <tf2_msgs/TFMessage.h>

#include "calibrator_test_utils.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/SetRigDrift.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using test_support::Collector;
using sensor_msgs::CameraInfo;

TEST(CalibratorAuto, CommitsADriftedFocalLengthAtTheNextWindow) {
  ros::NodeHandle nh;
  Collector<CalibrationMode> modes(nh, "calibration_mode");
  Collector<CameraInfo> left(nh, "left/camera_info"), right(nh, "right/camera_info");
  Collector<CalibrationStatus> status(nh, "calibration/status");
  Collector<tf2_msgs::TFMessage> tf_static(nh, "/tf_static");
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics(nh, "/diagnostics");
  ASSERT_TRUE(ros::service::waitForService("calibration/recalibrate", 20000));
  ASSERT_TRUE(left.waitForCount(1, 20.0));
  const double fx_before = left.snapshot().back()->K[0];

  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.05;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  const uint32_t epoch = modes.waitForCount(1, 5.0) ? modes.snapshot().back()->calibration_epoch : 0;

  // Windows start every 3 s: the first complete one after the drift is solved and accepted.
  ASSERT_TRUE(status.waitFor([](const auto& m) { return !m.empty() && m.back()->accepted; }, 12.0))
      << (status.snapshot().empty() ? "no status" : "last status: " + status.snapshot().back()->reason);
  const CalibrationStatus accepted = *status.snapshot().back();
  std::printf("accepted: %u frames, %u corners, rms %.4f / %.4f px, %.0f ms\n", accepted.frames_used,
              accepted.corners_used, accepted.rms_left_px, accepted.rms_right_px, accepted.solve_ms);
  EXPECT_GE(accepted.frames_used, 8u);
  EXPECT_LE(accepted.frames_used, 10u) << "frames of one window only";
  // The epoch reported is the one the driver stamps on its first frame carrying the commit.
  const std::optional<uint32_t> published = test_support::epochPublishedWith(accepted, modes, left, right);
  ASSERT_TRUE(published) << "the driver never published the committed calibration";
  EXPECT_NE(*published, epoch);
  EXPECT_EQ(accepted.epoch, *published);
  ASSERT_TRUE(left.waitForCount(left.snapshot().size() + 2, 5.0));
  EXPECT_NEAR(left.snapshot().back()->K[0] / fx_before, 1.05, 1e-4);
  EXPECT_TRUE(tf_static.waitForCount(1, 2.0));

  // Diagnostics report the accepted solve and the age of the calibration.
  std::string age;
  EXPECT_TRUE(diagnostics.waitFor(
      [&](const auto& arrays) {
        for (const auto& array : arrays)
          for (const auto& s : array->status) {
            if (s.name.find("online_calibrator") == std::string::npos || s.message != "last solve accepted") continue;
            for (const auto& kv : s.values)
              if (kv.key == "calibration age (s)" && std::stod(kv.value) >= 0.0) age = kv.value;
          }
        return !age.empty();
      },
      4.0));
  std::printf("calibration age in diagnostics: %s s\n", age.c_str());
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibrator_auto_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
