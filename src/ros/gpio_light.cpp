// The gpio light backend: one output line of a GPIO chip through the libgpiod v1 C API.
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/light_backend.h"

#ifdef ECS_HAVE_GPIOD
#include <gpiod.h>

#include <cerrno>
#include <cstring>
#endif

namespace embedded_calibration_stereo {

#ifdef ECS_HAVE_GPIOD
namespace {

class GpioLight : public LightBackend {
 public:
  explicit GpioLight(const GpioLightParams& params) : params_(params) {
    if (params_.chip.empty()) throw core::ConfigError("gpio_chip", "missing");
    if (params_.line < 0) throw core::ConfigError("gpio_line", "missing or negative line offset");
    chip_ = gpiod_chip_open_lookup(params_.chip.c_str());
    if (!chip_) throw core::ConfigError("gpio_chip", "cannot open GPIO chip '" + params_.chip + "': " + std::strerror(errno));
    line_ = gpiod_chip_get_line(chip_, static_cast<unsigned>(params_.line));
    if (!line_) {
      gpiod_chip_close(chip_);
      throw core::ConfigError("gpio_line", "chip '" + params_.chip + "' has no line " + std::to_string(params_.line));
    }
    if (gpiod_line_request_output(line_, "embedded_calibration_stereo", level(false)) != 0) {
      const std::string reason = std::strerror(errno);
      gpiod_chip_close(chip_);
      throw core::ConfigError("gpio_line", "cannot request line " + std::to_string(params_.line) + " as output: " + reason);
    }
  }

  ~GpioLight() override {
    gpiod_line_release(line_);
    gpiod_chip_close(chip_);
  }

  bool apply(const core::LightState& state, std::string* error) override {
    if (written_ && *written_ == state.light_on) return true;
    if (gpiod_line_set_value(line_, level(state.light_on)) != 0) {
      if (error) *error = std::string("gpiod_line_set_value failed: ") + std::strerror(errno);
      written_.reset();
      return false;
    }
    written_ = state.light_on;
    return true;
  }

 private:
  int level(bool on) const { return (on != params_.active_low) ? 1 : 0; }

  GpioLightParams params_;
  gpiod_chip* chip_ = nullptr;
  gpiod_line* line_ = nullptr;
  std::optional<bool> written_;
};

}  // namespace

std::unique_ptr<LightBackend> makeGpioLight(const GpioLightParams& params) {
  return std::make_unique<GpioLight>(params);
}

#else

std::unique_ptr<LightBackend> makeGpioLight(const GpioLightParams&) {
  throw core::ConfigError("light_backend", "gpio: this build has no libgpiod support");
}

#endif

}  // namespace embedded_calibration_stereo
