#include "embedded_calibration_stereo/test_support/solution_errors.h"

#include <cmath>

namespace embedded_calibration_stereo::core {

std::vector<double> errorsInReportedStddevs(const BundleAdjustmentSummary& s,
                                            const StereoRig& truth) {
  std::vector<double> z;
  const PinholeCamera* est[2] = {&s.rig.left, &s.rig.right};
  const PinholeCamera* tru[2] = {&truth.left, &truth.right};
  const CameraStddev* sd[2] = {&s.left_stddev, &s.right_stddev};
  for (int c = 0; c < 2; ++c) {
    z.push_back(std::abs(est[c]->fx - tru[c]->fx) / sd[c]->fx);
    z.push_back(std::abs(est[c]->fy - tru[c]->fy) / sd[c]->fy);
    z.push_back(std::abs(est[c]->cx - tru[c]->cx) / sd[c]->cx);
    z.push_back(std::abs(est[c]->cy - tru[c]->cy) / sd[c]->cy);
    z.push_back(std::abs(est[c]->dist[0] - tru[c]->dist[0]) / sd[c]->dist[0]);
    z.push_back(std::abs(est[c]->dist[1] - tru[c]->dist[1]) / sd[c]->dist[1]);
  }
  z.push_back(std::abs(s.rig.baseline() - truth.baseline()) / s.baseline_stddev_m);
  z.push_back(rotationAngleDeg(s.rig.right_from_left.linear(), truth.right_from_left.linear()) /
              s.rotation_stddev_deg);
  return z;
}

}  // namespace embedded_calibration_stereo::core
