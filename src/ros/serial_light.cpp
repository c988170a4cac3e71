// The serial light backend: writes the configured "on"/"off" byte strings to a tty in raw mode.
#include <fcntl.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/light_backend.h"

namespace embedded_calibration_stereo {
namespace {

speed_t baudConstant(int baud) {
  switch (baud) {
    case 1200: return B1200;
    case 2400: return B2400;
    case 4800: return B4800;
    case 9600: return B9600;
    case 19200: return B19200;
    case 38400: return B38400;
    case 57600: return B57600;
    case 115200: return B115200;
    case 230400: return B230400;
    case 460800: return B460800;
    case 921600: return B921600;
    default: return B0;
  }
}

class SerialLight : public LightBackend {
 public:
  explicit SerialLight(const SerialLightParams& params) : params_(params) {
    if (params_.port.empty()) throw core::ConfigError("serial_port", "missing");
    const speed_t speed = baudConstant(params_.baud);
    if (speed == B0) throw core::ConfigError("serial_baud", "unsupported baud rate " + std::to_string(params_.baud));
    struct stat st;
    if (stat(params_.port.c_str(), &st) != 0) throw core::ConfigError("serial_port", "device does not exist: '" + params_.port + "'");
    fd_ = ::open(params_.port.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (fd_ < 0) throw core::ConfigError("serial_port", "cannot open '" + params_.port + "': " + std::strerror(errno));
    struct termios tio;
    if (tcgetattr(fd_, &tio) != 0) fail("not a tty");
    cfmakeraw(&tio);  // no translation: the configured bytes go out exactly
    tio.c_cflag |= CLOCAL | CREAD;
    if (cfsetispeed(&tio, speed) != 0 || cfsetospeed(&tio, speed) != 0 || tcsetattr(fd_, TCSANOW, &tio) != 0)
      fail("cannot configure");
  }

  ~SerialLight() override {
    if (fd_ >= 0) ::close(fd_);
  }

  bool apply(const core::LightState& state, std::string* error) override {
    if (written_ && *written_ == state.light_on) return true;
    const std::string& bytes = state.light_on ? params_.on_bytes : params_.off_bytes;
    size_t done = 0;
    while (done < bytes.size()) {
      const ssize_t n = ::write(fd_, bytes.data() + done, bytes.size() - done);
      if (n < 0) {
        if (errno == EINTR) continue;
        if (error) *error = "write to '" + params_.port + "' failed: " + std::strerror(errno);
        written_.reset();  // unknown state: rewrite at the next frame
        return false;
      }
      done += static_cast<size_t>(n);
    }
    written_ = state.light_on;
    return true;
  }

 private:
  [[noreturn]] void fail(const std::string& what) {
    const std::string reason = what + " '" + params_.port + "': " + std::strerror(errno);
    ::close(fd_);
    fd_ = -1;
    throw core::ConfigError("serial_port", reason);
  }

  SerialLightParams params_;
  int fd_ = -1;
  std::optional<bool> written_;
};

}  // namespace

std::unique_ptr<LightBackend> makeSerialLight(const SerialLightParams& params) {
  return std::make_unique<SerialLight>(params);
}

}  // namespace embedded_calibration_stereo
