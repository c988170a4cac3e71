#pragma once
// When a new calibration is rolled back, and to what. A new calibration is tested: its first
// verdict after a verification against the boards must be GOOD, or no worse than its reference's
// state; otherwise the reference is restored. The reference is the newest calibration that had a
// verdict while in force and was not itself rejected: usually the calibration the new one
// replaces; when that one was replaced before its first verdict, or failed its test (a chain of
// commits faster than verifications), the last one that passed before the chain. So a rollback
// never restores a calibration nobody verified, nor one found worse.
// A reference keeps the state of its latest verdict: under a rig that drifted, a new
// calibration need only do better than the old one does now. Until this run has a reference, the
// calibration verified GOOD in an earlier run (kept on disk by the driver) is the reference.
//
// Threading: not thread-safe; the owner (the CalibrationHealth nodelet) uses it from one queue.
#include <cstdint>
#include <optional>
#include <utility>

#include "embedded_calibration_stereo/core/calibration/calibration_monitor.h"

namespace embedded_calibration_stereo::core {

// 0 GOOD, 1 DEGRADED, 2 BAD; -1 no verdict.
inline int healthRank(CalibrationHealth state) {
  switch (state) {
    case CalibrationHealth::kGood: return 0;
    case CalibrationHealth::kDegraded: return 1;
    case CalibrationHealth::kBad: return 2;
    default: return -1;
  }
}

template <class Calibration>
class RollbackPolicy {
 public:
  struct Reference {
    uint32_t epoch;
    Calibration calibration;
    CalibrationHealth state;
  };
  enum class Outcome { kUndecided, kKept, kRestore };
  struct Decision {
    Outcome outcome = Outcome::kUndecided;
    std::optional<Reference> reference;  // kKept, kRestore: what it was tested against
  };

  // The epoch of a reference from an earlier run.
  static constexpr uint32_t kEarlierRun = UINT32_MAX;

  // A calibration verified GOOD in an earlier run: the reference while this run has none.
  void seedEarlierRun(const Calibration& calibration) {
    if (!latest_) latest_ = Reference{kEarlierRun, calibration, CalibrationHealth::kGood};
  }
  // The calibration a new one would be tested against now, if any.
  const std::optional<Reference>& reference() const { return latest_; }

  // A calibration comes into force as `epoch`; `test`: it must pass a test (rollback on, and not
  // a restore). Returns its reference when it is tested.
  std::optional<Reference> start(uint32_t epoch, bool test) {
    under_test_.reset();
    if (test && latest_ && latest_->epoch != epoch) under_test_ = UnderTest{epoch, *latest_};
    return under_test_ ? std::optional<Reference>(under_test_->reference) : std::nullopt;
  }
  // Any verdict on the calibration in force: it becomes the reference of later ones, unless it
  // is under test or was rejected.
  void observe(uint32_t epoch, const Calibration& calibration, CalibrationHealth state) {
    if (healthRank(state) < 0 || (under_test_ && under_test_->epoch == epoch) || rejected_ == epoch) return;
    latest_ = Reference{epoch, calibration, state};
  }
  // After a verification against the boards of the calibration in force, verdict `state`.
  Decision decide(uint32_t epoch, const Calibration& calibration, CalibrationHealth state) {
    Decision decision;
    if (!under_test_ || under_test_->epoch != epoch || healthRank(state) < 0) return decision;
    decision.reference = under_test_->reference;
    under_test_.reset();
    if (worse(state, *decision.reference)) {
      rejected_ = epoch;
      decision.outcome = Outcome::kRestore;
    } else {
      latest_ = Reference{epoch, calibration, state};
      decision.outcome = Outcome::kKept;
    }
    return decision;
  }
  bool testing(uint32_t epoch) const { return under_test_ && under_test_->epoch == epoch; }

  static bool worse(CalibrationHealth verified, const Reference& reference) {
    if (healthRank(verified) < 0 || verified == CalibrationHealth::kGood) return false;
    return reference.state == CalibrationHealth::kGood || healthRank(verified) > healthRank(reference.state);
  }

 private:
  struct UnderTest {
    uint32_t epoch;
    Reference reference;
  };
  std::optional<Reference> latest_;
  std::optional<UnderTest> under_test_;
  std::optional<uint32_t> rejected_;
};

}  // namespace embedded_calibration_stereo::core
