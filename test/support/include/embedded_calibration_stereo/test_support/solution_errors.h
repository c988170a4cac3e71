#pragma once
// How far a bundle-adjustment solution is from a known truth, in units of the standard
// deviations it reports: the figure behind every "true error within 3 sd" check.
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"

namespace embedded_calibration_stereo::core {

// |estimate - truth| / reported sd for fx, fy, cx, cy, k1, k2 of the left then the right
// camera, then the baseline and the stereo rotation angle (14 values).
std::vector<double> errorsInReportedStddevs(const BundleAdjustmentSummary& solution,
                                            const StereoRig& truth);

}  // namespace embedded_calibration_stereo::core
