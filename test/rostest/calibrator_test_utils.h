#pragma once
// Helpers shared by the OnlineCalibrator's rostest nodes.
#include <sensor_msgs/CameraInfo.h>

#include <algorithm>
#include <cmath>
#include <optional>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"

namespace embedded_calibration_stereo::test_support {

// The calibration_epoch the driver stamped on its first frame (calibration_mode) whose left and
// right camera_info carry the intrinsics of `status` (fx, fy, cx, cy of both sides), observed
// on the driver's own topics, independently of how the calibrator found its epoch. Waits up to
// `timeout_s` for that frame; nullopt without it.
inline std::optional<uint32_t> epochPublishedWith(const embedded_calibration_stereo::CalibrationStatus& status,
                                                  Collector<embedded_calibration_stereo::CalibrationMode>& modes,
                                                  Collector<sensor_msgs::CameraInfo>& left,
                                                  Collector<sensor_msgs::CameraInfo>& right, double timeout_s = 5.0) {
  if (status.left_intrinsics.size() < 4 || status.right_intrinsics.size() < 4) return std::nullopt;
  const auto carries = [](const sensor_msgs::CameraInfo& info, const std::vector<double>& intrinsics) {
    const auto same = [](double a, double b) { return std::abs(a - b) <= 1e-9 * std::abs(b); };
    return same(info.K[0], intrinsics[0]) && same(info.K[4], intrinsics[1]) && same(info.K[2], intrinsics[2]) &&
           same(info.K[5], intrinsics[3]);
  };
  using Modes = std::vector<embedded_calibration_stereo::CalibrationMode::ConstPtr>;
  const auto find = [&](const Modes& frames) -> std::optional<uint32_t> {
    const auto lefts = left.snapshot(), rights = right.snapshot();
    for (const auto& mode : frames) {
      const auto at = [&](const auto& infos) {
        const auto it = std::find_if(infos.begin(), infos.end(),
                                     [&](const auto& i) { return i->header.stamp == mode->header.stamp; });
        return it == infos.end() ? nullptr : *it;
      };
      const auto l = at(lefts), r = at(rights);
      if (l && r && carries(*l, status.left_intrinsics) && carries(*r, status.right_intrinsics))
        return mode->calibration_epoch;
    }
    return std::nullopt;
  };
  std::optional<uint32_t> epoch;
  // Re-evaluated at every new calibration_mode (under the collector's lock: its messages are
  // the argument): the camera_info of a frame arrives beside it.
  modes.waitFor([&](const Modes& frames) { return (epoch = find(frames)).has_value(); }, timeout_s);
  return epoch;
}

}  // namespace embedded_calibration_stereo::test_support
