// The light backends without hardware (none, sim), the byte-string escapes and the backend's
// parameters.
#include "embedded_calibration_stereo/ros/light_backend.h"

#include "embedded_calibration_stereo/ros/parameter_reader.h"

namespace embedded_calibration_stereo {
namespace {

class NoLight : public LightBackend {
 public:
  bool apply(const core::LightState&, std::string*) override { return true; }
};

class SimLight : public LightBackend {
 public:
  SimLight(SharedLightLevel level, SharedLightCommand command)
      : level_(std::move(level)), command_(std::move(command)) {}
  // The sim renders the ramping level, so the settling frames really show a half-lit device
  // (or, with a light response model, the level that follows the command).
  bool apply(const core::LightState& state, std::string*) override {
    level_->store(state.light_level);
    if (command_) {
      if (state.switched) switches_ += 1;
      command_->store(2 * switches_ + (state.light_on ? 1 : 0));
    }
    return true;
  }

 private:
  SharedLightLevel level_;
  SharedLightCommand command_;
  uint64_t switches_ = 0;
};

int hexDigit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

// A byte string written with escapes (unescapeBytes).
std::string readBytes(const ParameterReader& read, const std::string& name, const std::string& fallback) {
  std::string decoded, error;
  if (!unescapeBytes(read.get(name, fallback), &decoded, &error)) throw core::ConfigError(name, error);
  return decoded;
}

}  // namespace

LightBackendParams readLightBackendParams(const ParameterReader& read, const std::string& default_backend) {
  LightBackendParams p;
  p.backend = read.choice("light_backend", default_backend, {"sim", "serial", "gpio", "none"});
  if (p.backend == "serial") {
    p.serial.port = read.required<std::string>("serial_port");
    if (p.serial.port.empty()) throw core::ConfigError("serial_port", "missing");
    p.serial.baud = read.get("serial_baud", p.serial.baud);
    p.serial.on_bytes = readBytes(read, "serial_on", "ON\\n");
    p.serial.off_bytes = readBytes(read, "serial_off", "OFF\\n");
  } else if (p.backend == "gpio") {
    p.gpio.chip = read.get("gpio_chip", p.gpio.chip);
    p.gpio.line = read.get("gpio_line", p.gpio.line);
    p.gpio.active_low = read.get("gpio_active_low", p.gpio.active_low);
    if (p.gpio.line < 0) throw core::ConfigError("gpio_line", "missing or negative line offset");
  }
  return p;
}

bool unescapeBytes(const std::string& text, std::string* bytes, std::string* error) {
  std::string out;
  for (size_t i = 0; i < text.size(); ++i) {
    if (text[i] != '\\') {
      out += text[i];
      continue;
    }
    if (++i >= text.size()) {
      if (error) *error = "trailing backslash in '" + text + "'";
      return false;
    }
    switch (text[i]) {
      case 'n': out += '\n'; break;
      case 'r': out += '\r'; break;
      case 't': out += '\t'; break;
      case '0': out += '\0'; break;
      case '\\': out += '\\'; break;
      case 'x': {
        const int hi = i + 1 < text.size() ? hexDigit(text[i + 1]) : -1;
        const int lo = i + 2 < text.size() ? hexDigit(text[i + 2]) : -1;
        if (hi < 0 || lo < 0) {
          if (error) *error = "\\x needs two hex digits in '" + text + "'";
          return false;
        }
        out += static_cast<char>(hi * 16 + lo);
        i += 2;
        break;
      }
      default:
        if (error) *error = std::string("unknown escape \\") + text[i] + " in '" + text + "'";
        return false;
    }
  }
  *bytes = out;
  return true;
}

std::unique_ptr<LightBackend> makeNoLight() { return std::make_unique<NoLight>(); }

std::unique_ptr<LightBackend> makeSimLight(SharedLightLevel level) {
  return std::make_unique<SimLight>(std::move(level), nullptr);
}

std::unique_ptr<LightBackend> makeSimLight(SharedLightLevel level, SharedLightCommand command) {
  return std::make_unique<SimLight>(std::move(level), std::move(command));
}

std::unique_ptr<LightBackend> makeLightBackend(const LightBackendParams& params, SharedLightLevel level,
                                               SharedLightCommand command) {
  if (params.backend == "sim") return makeSimLight(std::move(level), std::move(command));
  if (params.backend == "serial") return makeSerialLight(params.serial);
  if (params.backend == "gpio") return makeGpioLight(params.gpio);
  return makeNoLight();
}

}  // namespace embedded_calibration_stereo
