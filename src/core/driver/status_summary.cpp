#include "embedded_calibration_stereo/core/driver/status_summary.h"

#include <cstdio>

namespace embedded_calibration_stereo::core {

StatusSummary driverSummary(const std::string& capture_error, const std::string& calibration_problem,
                            double rate_fps, double fps) {
  using Level = StatusSummary::Level;
  if (!capture_error.empty()) return {Level::kError, capture_error};
  if (!calibration_problem.empty()) return {Level::kError, calibration_problem};
  if (rate_fps < 0.9 * fps) {
    char text[64];
    std::snprintf(text, sizeof(text), "%.1f fps, below %.1f", rate_fps, fps);
    return {Level::kWarn, text};
  }
  return {Level::kOk, "publishing"};
}

StatusSummary lightControllerSummary(const LightControllerState& state) {
  using Level = StatusSummary::Level;
  if (!state.backend_error.empty()) return {Level::kError, "light backend: " + state.backend_error};
  if (!state.fault.empty()) return {Level::kError, "light not working: " + state.fault};
  if (!state.held_back.empty()) return {Level::kError, "frames held back: " + state.held_back};
  if (state.uncalibrated) return {Level::kWarn, "driver's camera_info uncalibrated"};
  if (state.frames_out == 0) return {Level::kWarn, "no frame from the driver yet"};
  return {Level::kOk, "confirming the light"};
}

}  // namespace embedded_calibration_stereo::core
