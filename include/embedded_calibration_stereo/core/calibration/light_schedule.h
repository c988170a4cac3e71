#pragma once
// When the calibration light is on, and whether a frame was taken while it was still changing.
//
// The schedule is stepped once per stereo frame. The light is on
//  - while a request (set_light true) holds it on, until set_light false, or
//  - during a periodic calibration burst: every `period_s` seconds (0 = never; only on
//    request), starting with the first frame, for `settle_frames + calibration_frames` frames,
//    so that each burst yields `calibration_frames` settled frames.
// A switch takes effect at the next step(): `light_on` is the commanded state from that frame
// on, and the first `settle_frames` frames after a switch are reported unsettled. During them
// the physical light level ramps linearly (what the simulated rig renders).
//
// Threading: not thread-safe; the owner (the camera driver) guards it with its own mutex.
#include <cstdint>
#include <string>

namespace ecs {

struct LightScheduleConfig {
  double period_s = 0.0;       // time between calibration bursts; 0 = only on request
  int calibration_frames = 10; // settled frames with the light on per burst (>= 1)
  int settle_frames = 2;       // frames reported unsettled after each switch (>= 0)
  // Empty when usable; otherwise a message naming the bad field.
  std::string validate() const;
};

struct LightState {
  bool light_on = false;     // commanded state in force for this frame
  bool settled = true;       // false while the light is still changing
  double light_level = 0.0;  // physical level in [0, 1] (ramps during settling)
  bool switched = false;     // light_on differs from the previous frame (drive the hardware)
};

class LightSchedule {
 public:
  explicit LightSchedule(const LightScheduleConfig& config);

  // Holds the light on (true) or releases the hold and switches it off (false). Takes effect
  // at the next step(). Releasing also ends a periodic burst in progress.
  void request(bool on);
  bool requestedOn() const { return hold_on_; }

  // Advances one frame taken at `time_s` (monotonic seconds) and returns its light state.
  LightState step(double time_s);
  // Advances one frame whose light state is given from outside (e.g. a recorded CSV), only
  // tracking the settling after switches.
  LightState follow(bool light_on);

  const LightScheduleConfig& config() const { return config_; }

 private:
  LightState advance(bool commanded_on);

  LightScheduleConfig config_;
  bool hold_on_ = false;
  bool started_ = false;
  double next_burst_s_ = 0.0;
  int64_t burst_frames_left_ = 0;
  bool previous_on_ = false;
  int64_t frames_since_switch_ = 1 << 30;  // "long ago": the initial off state is settled
};

}  // namespace ecs
