// rostest: a committed calibration refined by the next window (calibrator_refinement.test).
// After a 3 % zoom the calibrator commits a window's solve; the next window, solved with that
// solve as the prior of the groups it does not contradict, confirms the calibration in force
// and is better known (its predicted hypot of misalignment and disparity bias below refine_ratio,
// 0.85, times the committed one's): it is committed too. The refined calibration is no further
// from the simulator's truth than the one it refines (within that one's prediction), and a
// third window confirms without committing again (no churn).
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>

#include <cmath>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using test_support::Collector;
using sensor_msgs::CameraInfo;
using Statuses = std::vector<CalibrationStatus::ConstPtr>;

namespace {

double predicted(const CalibrationStatus& s) {
  return std::hypot(s.predicted_misalignment_rms_px, s.predicted_disparity_bias_rms_px);
}

// hypot(misalignment, bias) RMS of the published calibration of the newest frame of `epoch`
// against that frame's truth; negative when not found.
double trueError(Collector<CalibrationMode>& modes, Collector<CameraInfo>& left, Collector<CameraInfo>& right,
                 Collector<CameraInfo>& truth_left, Collector<CameraInfo>& truth_right, uint32_t epoch) {
  const auto m = modes.snapshot();
  for (auto it = m.rbegin(); it != m.rend(); ++it) {
    if ((*it)->calibration_epoch != epoch) continue;
    const ros::Time stamp = (*it)->header.stamp;
    const auto at = [&](Collector<CameraInfo>& c) -> CameraInfo::ConstPtr {
      for (const auto& i : c.snapshot())
        if (i->header.stamp == stamp) return i;
      return nullptr;
    };
    const auto l = at(left), r = at(right), tl = at(truth_left), tr = at(truth_right);
    if (!(l && r && tl && tr)) continue;
    core::StereoRig published, truth;
    std::string error;
    if (!embedded_calibration_stereo::fromStereoCameraInfo(*l, *r, &published, &error) ||
        !embedded_calibration_stereo::fromStereoCameraInfo(*tl, *tr, &truth, &error))
      return -1.0;
    const core::StereoAccuracy a = core::evaluateStereoAccuracy(published, truth);
    return std::hypot(a.misalignment_px.rms, a.disparity_bias_px.rms);
  }
  return -1.0;
}

}  // namespace

TEST(CalibratorRefinement, TheNextWindowRefinesACommit) {
  ros::NodeHandle nh;
  Collector<CalibrationStatus> status(nh, "calibration/status", 100);
  Collector<CalibrationMode> modes(nh, "calibration_mode", 3000);
  Collector<CameraInfo> left(nh, "left/camera_info", 3000), right(nh, "right/camera_info", 3000);
  Collector<CameraInfo> truth_left(nh, "ground_truth/left/camera_info", 3000);
  Collector<CameraInfo> truth_right(nh, "ground_truth/right/camera_info", 3000);
  ASSERT_TRUE(status.waitForCount(1, 40.0)) << "no first solve";
  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.03;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  const size_t before = status.snapshot().size();
  // The zoom's commit, then the refinement, then a window that confirms.
  ASSERT_TRUE(status.waitFor(
      [&](const Statuses& m) {
        int accepted = 0;
        for (size_t i = before; i < m.size(); ++i) accepted += m[i]->accepted;
        return accepted >= 2 && !m.back()->accepted;
      },
      30.0))
      << "statuses since the zoom: " << status.snapshot().size() - before;
  const Statuses all = status.snapshot();
  std::vector<CalibrationStatus::ConstPtr> accepted;
  for (size_t i = before; i < all.size(); ++i)
    if (all[i]->accepted) accepted.push_back(all[i]);
  const CalibrationStatus& zoom = *accepted[0];
  const CalibrationStatus& refined = *accepted[1];
  std::printf("zoom committed (epoch %u): predicted %.4f px; refined (epoch %u): predicted %.4f px; then: %s\n",
              zoom.epoch, predicted(zoom), refined.epoch, predicted(refined), all.back()->reason.c_str());
  EXPECT_GT(refined.epoch, zoom.epoch);
  EXPECT_LT(predicted(refined), 0.85 * predicted(zoom));
  EXPECT_EQ(all.back()->reason.rfind(embedded_calibration_stereo::kInForceConfirmedReason, 0), 0u)
      << all.back()->reason;
  // Against the truth: the refinement is no further from it than the zoom's commit was, beyond
  // what that one's prediction allows.
  ASSERT_TRUE(modes.waitForCount(modes.snapshot().size() + 3, 5.0));
  const double zoom_error = trueError(modes, left, right, truth_left, truth_right, zoom.epoch);
  const double refined_error = trueError(modes, left, right, truth_left, truth_right, refined.epoch);
  std::printf("against the truth: zoom's commit %.4f px, refined %.4f px\n", zoom_error, refined_error);
  ASSERT_GE(zoom_error, 0.0);
  ASSERT_GE(refined_error, 0.0);
  EXPECT_LE(refined_error, zoom_error + 2.0 * predicted(zoom));
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibrator_refinement_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
