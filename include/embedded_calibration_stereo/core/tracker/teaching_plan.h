#pragma once
// When the PatternTracker teaches its prior, on what, and what a light burst that ends is used
// for (teaching, tracking as a window, or dropped). The nodelet hands it the facts of each frame
// and burst and does what it answers (docs/nodelets.md#patterntracker).
//
// Threading: not thread-safe; one owner (the tracker nodelet's callback queue).
#include <cstddef>
#include <string>

#include "embedded_calibration_stereo/core/driver/status_summary.h"

namespace embedded_calibration_stereo::core {

enum class PriorState { kLoaded, kMissing, kCorrupt, kTeaching, kTeachFailed };
const char* toString(PriorState state);

// What teaching is done on: a light burst's learned device image, a light-on frame minus the
// latest light-off frame, or (tests only) a light-on frame minus the simulator's scene.
enum class TeachFrom { kBurst, kLightOff, kGroundTruth };

class TeachingPlan {
 public:
  // Teaching from a burst under way starts once it has this many settled light-on frames (or
  // at its end): a forced recalibration holds the light on until it has observations.
  static constexpr int kTeachLightOnFrames = 8;

  explicit TeachingPlan(TeachFrom from = TeachFrom::kBurst) : from_(from) {}

  // At start, no prior file: teach at once when `teach_on_start`, otherwise idle.
  void priorMissing(bool teach_on_start);
  // At start, a prior file that cannot be used (`error` says why): idle until ~teach.
  void priorUnusable(const std::string& error);
  // A prior (loaded or taught) is in use.
  void tracking();

  // ~teach. False (busy) while teaching runs; otherwise teaching waits for its frames.
  bool request();

  // What a settled light-on frame does for teaching before it is tracked.
  enum class LightOnStep {
    kNone,                  // no teaching waits
    kTeachOnBurstUnderWay,  // teach on the burst under way (its light-on frames so far)
    kTeachOnLightOff,       // teach on this frame and the latest light-off frame
    kMatchGroundTruth,      // teach on this frame minus the simulator's scene, once it came
    kWaitForBurst,          // teaching waits for a longer burst, or for one to end
    kWaitForLightOff,       // teaching waits for a light-off frame of this frame's format
  };
  // `burst_light_on_frames`: the burst under way's settled light-on frames kept, this one
  // included; `light_off_matches`: a light-off frame of this frame's format was seen.
  LightOnStep lightOn(int burst_light_on_frames, bool light_off_matches) const;

  // What a light burst that ended is used for.
  enum class BurstStep {
    kIgnore,          // nothing to do with it
    kTeach,           // teach on it
    kTeachThenTrack,  // teach on it, then track it with the prior it teaches (window tracking)
    kTrackOncePrior,  // teaching runs: track it with the prior being taught (window tracking)
    kTrack,           // track it as a window
    kDropUnusable,    // window tracking drops it: its frames cannot be used
    kDropNoPrior,     // window tracking drops it: no prior to track with
    kCannotTeach,     // teaching waits for a burst, and this one's frames cannot be used
  };
  // `usable`: the collector kept its frames (no problem); `window_tracking`: bursts are tracked.
  BurstStep burstEnded(bool usable, bool window_tracking) const;

  // Teaching has started on a worker. `burst_under_way`: on a burst not ended yet.
  void teachingStarted(bool burst_under_way);
  // After tracking() with a newly taught prior: true when it was taught on a burst under way and
  // misses some of the device's boards; then teaching waits for the end of a burst (once).
  bool teachAgainIfBoardsMissing(size_t left_boards, size_t right_boards, size_t device_boards);
  // Teaching failed or taught an unusable prior: idle until ~teach.
  void teachFailed(const std::string& error);

  // The frames are needed whoever listens (teaching waits for them, or runs).
  bool needsInputs() const { return requested_ || state_ == PriorState::kTeaching; }
  // The simulator's scene is needed (teaching from it waits for a frame).
  bool needsGroundTruth() const { return from_ == TeachFrom::kGroundTruth && requested_; }

  // The same summary as the driver's and the LightController's (one mapping to diagnostics).
  using Summary = StatusSummary;
  using Level = StatusSummary::Level;
  // The diagnostics summary. `prior_unwritten`: the prior in use is not in the file yet, for
  // `write_error`.
  Summary summary(bool prior_unwritten, const std::string& write_error) const;
  // Why the tracker is idle, after "prior file 'X' ": "is missing", "is unusable (...)".
  std::string idleReason() const;
  // What teaching waits for once requested ("teaching at the next light burst").
  const char* teachesAt() const;

  PriorState state() const { return state_; }
  const std::string& error() const { return error_; }  // why the prior is unusable or not taught
  bool teachRequested() const { return requested_; }
  TeachFrom from() const { return from_; }

 private:
  TeachFrom from_;
  PriorState state_ = PriorState::kMissing;
  std::string error_;
  bool requested_ = false;     // teaching waits for its frames
  bool at_burst_end_ = false;  // ... at the end of a burst only
  bool partial_ = false;       // the teaching running is on a burst under way
};

}  // namespace embedded_calibration_stereo::core
