#pragma once
// What switches the calibration device's light. One implementation per backend:
//  - none:   no light (frames are published with the schedule's state only);
//  - sim:    sets the light level rendered by the sim backend;
//  - serial: writes configurable byte strings to a tty (serial_light.cpp);
//  - gpio:   drives a libgpiod v1 line (gpio_light.cpp; needs ECS_HAVE_GPIOD).
// Construction opens the device and throws core::ConfigError naming the parameter on failure.
//
// Threading: apply() is called by one thread at a time (the driver's capture thread).
#include <memory>
#include <string>

#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/ros/frame_source.h"

namespace embedded_calibration_stereo {

class LightBackend {
 public:
  virtual ~LightBackend() = default;
  // Called once per frame, before the frame is grabbed, with the schedule's state for it.
  // Hardware backends write only when the commanded state differs from the last one written.
  // Returns false with the reason when the device could not be driven.
  virtual bool apply(const core::LightState& state, std::string* error) = 0;
};

struct SerialLightParams {
  std::string port;             // serial_port, e.g. /dev/ttyUSB0
  int baud = 115200;            // serial_baud
  std::string on_bytes = "ON\n";    // serial_on, after unescaping
  std::string off_bytes = "OFF\n";  // serial_off, after unescaping
};

struct GpioLightParams {
  std::string chip = "gpiochip0";  // gpio_chip: name, number or /dev path (gpiod_chip_open_lookup)
  int line = -1;                   // gpio_line: line offset on the chip
  bool active_low = false;         // gpio_active_low: drive 0 for "on"
};

// The light backend's parameters: light_backend and the chosen backend's serial_* or gpio_*.
struct LightBackendParams {
  std::string backend = "none";  // light_backend: sim | serial | gpio | none
  SerialLightParams serial;      // light_backend serial only
  GpioLightParams gpio;          // light_backend gpio only
};

class ParameterReader;
// The one reader of light_backend, serial_* and gpio_* (the CameraDriver's and the
// LightController's, docs/nodelets.md): light_backend one of sim, serial, gpio, none
// (`default_backend` when absent); serial: serial_port required and not empty, serial_baud,
// serial_on/serial_off with escapes (unescapeBytes); gpio: gpio_line required, >= 0, gpio_chip,
// gpio_active_low. The other backend's parameters are not read. Throws core::ConfigError naming
// the parameter. Whether sim fits the camera backend is the caller's check.
LightBackendParams readLightBackendParams(const ParameterReader& read, const std::string& default_backend);

// Decodes C-style escapes in a configured byte string: \n \r \t \0 \\ and \xHH.
// Returns false with the reason for an unknown or truncated escape.
bool unescapeBytes(const std::string& text, std::string* bytes, std::string* error);

std::unique_ptr<LightBackend> makeNoLight();
std::unique_ptr<LightBackend> makeSimLight(SharedLightLevel level);
// Also publishes the commanded state and its switches for the sim source (optional: null).
std::unique_ptr<LightBackend> makeSimLight(SharedLightLevel level, SharedLightCommand command);
std::unique_ptr<LightBackend> makeSerialLight(const SerialLightParams& params);
std::unique_ptr<LightBackend> makeGpioLight(const GpioLightParams& params);
// The backend `params` names (sim: on `level`, with `command` as above).
std::unique_ptr<LightBackend> makeLightBackend(const LightBackendParams& params, SharedLightLevel level,
                                               SharedLightCommand command = nullptr);

}  // namespace embedded_calibration_stereo
