#include "embedded_calibration_stereo/core/calibration/verified_marking.h"

namespace embedded_calibration_stereo::core {

bool VerifiedMarking::due(bool good, double verification_age_s, uint32_t epoch) const {
  if (!good || !(verification_age_s >= 0.0)) return false;
  return done_epoch_ != epoch;  // once per epoch (epochs only grow)
}

}  // namespace embedded_calibration_stereo::core
