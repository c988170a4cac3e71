#pragma once
// The one-line state a nodelet's diagnostics lead with (the PatternTracker's TeachingPlan gives
// one too), and for the CameraDriver and the LightController which of their problems a user sees
// first (docs/nodelets.md, each nodelet's "Diagnostics").
//
// Threading: pure functions.
#include <cstdint>
#include <string>

namespace embedded_calibration_stereo::core {

struct StatusSummary {
  enum class Level { kOk, kWarn, kError };
  Level level = Level::kOk;
  std::string text;
};

// The CameraDriver: a capture error, then a problem with the calibration in force (ERROR), then
// a frame rate below 90 % of `fps` (WARN); "publishing" otherwise.
StatusSummary driverSummary(const std::string& capture_error, const std::string& calibration_problem,
                            double rate_fps, double fps);

// What the LightController knows of its inputs and its light.
struct LightControllerState {
  std::string backend_error;  // the light backend failed (set_light, its device)
  std::string fault;          // the light does not do what was commanded (confirmation)
  std::string held_back;      // inputs missing: frames held back
  bool uncalibrated = false;  // the driver's camera_info of either side is uncalibrated
  uint64_t frames_out = 0;    // frames passed on since the start
};

// The LightController: the backend, then a light not working, then frames held back (ERROR),
// then an uncalibrated camera_info, then no frame yet (WARN); "confirming the light" otherwise.
StatusSummary lightControllerSummary(const LightControllerState& state);

}  // namespace embedded_calibration_stereo::core
