#pragma once
// When the calibration light is on, and whether a frame was taken while it was still changing.
//
// The schedule is stepped once per stereo frame. The light is on
//  - while a request (set_light true) holds it on, until set_light false, or
//  - during a calibration burst, for `settle_frames` frames and then its settled frames: either
//    `calibration_frames` of them, or, when calibration_frames is 0, as many as span
//    `calibration_duration_s` at the rate the frames come (round(duration x rate): 30 at 30 fps
//    and 15 at 15 fps for 1 s), so that a burst lasts as long at any frame rate. Bursts start
//      - trigger kPeriodic: every `period_s` seconds (0 = never; only on request), starting
//        `first_burst_delay_s` after the first frame;
//      - trigger kOnDemand: while demand(true) holds (the calibration is not healthy), at the
//        earliest `min_interval_s` after the previous burst ended (a burst cut short by
//        request(false): after it started), and as a safety net `period_s` after the previous
//        burst (0 = no safety net), the first one as with kPeriodic; or
//  - during a verification flash, for `settle_frames + 1` frames (one settled light-on frame,
//    for checking the calibration in force against the boards): every `verification_period_s`
//    (0 = none) after the previous flash or burst, and at the next frame after verifySoon()
//    (a new calibration came into force) unless lit frames to come verify already. A burst cuts
//    a flash short and verifies instead.
// A switch takes effect at the next step(): `light_on` is the commanded state from that frame
// on, and the first `settle_frames` frames after a switch are reported unsettled. During them
// the physical light level ramps linearly (what the simulated rig renders).
//
// Threading: not thread-safe; the owner (the camera driver) guards it with its own mutex.
#include <cstdint>
#include <optional>
#include <string>
#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo::core {

enum class CalibrationTrigger { kPeriodic, kOnDemand };

struct LightScheduleConfig {
  double period_s = 0.0;       // time between calibration bursts (kOnDemand: the longest); 0 = only on request
  int calibration_frames = 10; // settled frames with the light on per burst; 0: by duration
  // With calibration_frames 0: the time a burst's settled light-on frames cover (> 0).
  double calibration_duration_s = 0.0;
  int settle_frames = 2;       // frames reported unsettled after each switch (>= 0)
  CalibrationTrigger trigger = CalibrationTrigger::kPeriodic;
  // kOnDemand: shortest time from a burst's last lit frame to the next burst: the window's time
  // to be tracked, solved and committed, however long the burst was.
  double min_interval_s = 0.0;
  double verification_period_s = 0.0;  // time between verification flashes; 0 = none
  // Light-off time before the first burst: learning a burst's device image pairs its light-on
  // frames with settled light-off frames before it (the drivers use 0.5 s).
  double first_burst_delay_s = 0.0;
  // Empty when usable; otherwise a message naming the bad field.
  std::string validate() const;  // problem().text()
  ConfigProblem problem() const;
};

struct LightState {
  bool light_on = false;     // commanded state in force for this frame
  bool settled = true;       // false while the light is still changing
  double light_level = 0.0;  // physical level in [0, 1] (ramps during settling)
  bool switched = false;     // light_on differs from the previous frame (drive the hardware)
  bool verification = false; // on for a verification flash, not a calibration burst
};

class LightSchedule {
 public:
  explicit LightSchedule(const LightScheduleConfig& config);

  // Holds the light on (true) or releases the hold and switches it off (false). Takes effect
  // at the next step(). Releasing also ends a periodic burst in progress.
  void request(bool on);
  bool requestedOn() const { return hold_on_; }
  // kOnDemand: whether the calibration needs a burst (true while it is not healthy). Takes
  // effect at the next step(), subject to min_interval_s. Ignored with kPeriodic (demanded()
  // stays false).
  void demand(bool needed) { demand_ = needed && config_.trigger == CalibrationTrigger::kOnDemand; }
  bool demanded() const { return demand_; }
  // A verification flash at the next step(), unless the light is on for a burst, a request or
  // a flash (their settled frames to come verify); no effect when verification_period_s is 0.
  void verifySoon() { verify_soon_ = config_.verification_period_s > 0.0; }
  // The calibration epoch in force for the coming frame: a calibration that came into force
  // since the previous call is verified at once (verifySoon()); the first call only records it
  // (what is in force at start-up is verified on the schedule).
  void calibrationInForce(uint32_t epoch);

  // Advances one frame taken at `time_s` (monotonic seconds) and returns its light state.
  LightState step(double time_s);
  // Advances one frame whose light state is given from outside (e.g. a recorded CSV), only
  // tracking the settling after switches.
  LightState follow(bool light_on);

  const LightScheduleConfig& config() const { return config_; }

 private:
  LightState advance(bool commanded_on);
  void startBurst(double time_s);
  // step()'s decisions: a periodic or demanded burst; a verification flash.
  void startBurstIfDue(double time_s);
  void startFlashIfDue(double time_s);
  // Counts a burst frame at time_s down; a timed burst (calibration_frames 0) ends on the frame
  // whose settled frames cover calibration_duration_s.
  void countBurstFrame(double time_s);

  LightScheduleConfig config_;
  bool hold_on_ = false;
  bool started_ = false;
  bool demand_ = false;
  bool verify_soon_ = false;
  std::optional<uint32_t> epoch_;  // the calibration epoch in force, once told
  double next_burst_s_ = 0.0;    // the next periodic burst (kOnDemand: the safety net's)
  double last_burst_end_s_ = 0.0;  // the latest burst's last lit frame (after started_)
  double next_flash_s_ = 0.0;    // the next verification flash
  int64_t burst_frames_left_ = 0;
  int64_t burst_frame_index_ = 0;  // frames of the burst so far, this one excluded
  double burst_start_s_ = 0.0;     // the burst's first frame
  double burst_settled_s_ = 0.0;   // its first settled frame (a timed burst)
  double previous_step_s_ = 0.0;   // the previous step()'s frame (after started_)
  int64_t flash_frames_left_ = 0;
  bool previous_on_ = false;
  int64_t frames_since_switch_ = 1 << 30;  // "long ago": the initial off state is settled
};

}  // namespace embedded_calibration_stereo::core
