// The light backends without hardware (none, sim) and the byte-string escapes.
#include "embedded_calibration_stereo/ros/light_backend.h"

namespace embedded_calibration_stereo {
namespace {

class NoLight : public LightBackend {
 public:
  bool apply(const ecs::LightState&, std::string*) override { return true; }
};

class SimLight : public LightBackend {
 public:
  SimLight(SharedLightLevel level, SharedLightCommand command)
      : level_(std::move(level)), command_(std::move(command)) {}
  // The sim renders the ramping level, so the settling frames really show a half-lit device
  // (or, with a light response model, the level that follows the command).
  bool apply(const ecs::LightState& state, std::string*) override {
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

}  // namespace

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

}  // namespace embedded_calibration_stereo
