#pragma once
// When the CameraDriver marks the calibration in force as verified GOOD on disk (its
// calibration/verified topic, docs/nodelets.md#cameradriver): when the calibration health says
// GOOD by a verification against the boards (not by the scene rows alone), once per
// calibration epoch.
//
// Threading: plain values; used by one thread (the health subscriber's callback).
#include <cstdint>
#include <optional>

namespace embedded_calibration_stereo::core {

class VerifiedMarking {
 public:
  /// Whether the health's verdict (`good`, the age of its verification against the boards,
  /// negative or NaN for none, and the epoch it judged) calls for a marking.
  bool due(bool good, double verification_age_s, uint32_t epoch) const;
  /// The epoch was marked (or found nothing to mark): not again.
  void done(uint32_t epoch) { done_epoch_ = epoch; }

 private:
  std::optional<uint32_t> done_epoch_;
};

}  // namespace embedded_calibration_stereo::core
