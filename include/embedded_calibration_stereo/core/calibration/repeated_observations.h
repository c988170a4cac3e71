#pragma once
// Recognises an observation that repeats one seen recently, by its content (every board's
// corners and every scene match, not its stamp). A copy of a window already solved (a publisher
// in a loop, a bag replayed beside the live head) teaches nothing new: solving it again would
// count the same evidence twice, and a calibration "refined" by it would be committed on no new
// data. Exact copies only: a copy with noise added differs, and the calibrator's gate judges it.
//
// Threading: not thread-safe; the owner guards it.
#include <cstddef>
#include <cstdint>
#include <deque>

#include "embedded_calibration_stereo/core/geometry/observation.h"

namespace embedded_calibration_stereo::core {

// A 64-bit digest (FNV-1a) of an observation's content: board ids, corner ids, the bits of every
// coordinate, scene matches; the stamp is left out.
uint64_t contentDigest(const StereoObservation& observation);

class RepeatedObservations {
 public:
  // Remembers the digests of the last `capacity` (>= 1) observations.
  explicit RepeatedObservations(size_t capacity = 32) : capacity_(capacity < 1 ? 1 : capacity) {}
  // True when an observation of the same content is among the remembered ones; otherwise false,
  // and it is remembered.
  bool repeats(const StereoObservation& observation);

 private:
  size_t capacity_;
  std::deque<uint64_t> recent_;
};

}  // namespace embedded_calibration_stereo::core
