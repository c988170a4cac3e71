// Serial light backend against a pseudo-terminal opened by the test: the configured byte
// strings arrive unchanged (raw mode), once per switch.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <pty.h>
#include <unistd.h>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/light_backend.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;

namespace {

struct Pty {
  int master = -1, slave = -1;
  std::string slave_name;
  Pty() {
    char name[256];
    EXPECT_EQ(openpty(&master, &slave, name, nullptr, nullptr), 0);
    slave_name = name;
  }
  ~Pty() {
    close(master);
    close(slave);
  }
  // Reads whatever arrives within `timeout_ms` after the first byte.
  std::string readAvailable(int timeout_ms = 500) const {
    std::string out;
    pollfd p{master, POLLIN, 0};
    while (poll(&p, 1, out.empty() ? timeout_ms : 50) > 0) {
      char buf[256];
      const ssize_t n = read(master, buf, sizeof(buf));
      if (n <= 0) break;
      out.append(buf, static_cast<size_t>(n));
    }
    return out;
  }
};

core::LightState state(bool on) {
  core::LightState s;
  s.light_on = on;
  return s;
}

std::string unescaped(const std::string& text) {
  std::string bytes, error;
  EXPECT_TRUE(unescapeBytes(text, &bytes, &error)) << error;
  return bytes;
}

}  // namespace

TEST(UnescapeBytes, DecodesEscapes) {
  EXPECT_EQ(unescaped("ON\\n"), "ON\n");
  EXPECT_EQ(unescaped("\\x01\\xFf\\r\\t\\\\"), std::string("\x01\xff\r\t\\"));
  EXPECT_EQ(unescaped("a\\0b"), std::string("a\0b", 3));
  std::string bytes, error;
  EXPECT_FALSE(unescapeBytes("\\x4", &bytes, &error));
  EXPECT_FALSE(unescapeBytes("\\q", &bytes, &error));
  EXPECT_FALSE(unescapeBytes("abc\\", &bytes, &error));
  EXPECT_NE(error.find("backslash"), std::string::npos) << error;
}

TEST(SerialLight, WritesTheConfiguredStringsOncePerSwitch) {
  Pty pty;
  SerialLightParams params;
  params.port = pty.slave_name;
  params.baud = 9600;
  params.on_bytes = unescaped("\\x02LIGHT 1\\r\\n");
  params.off_bytes = unescaped("\\x02LIGHT 0\\r\\n");
  auto light = makeSerialLight(params);
  std::string error;
  ASSERT_TRUE(light->apply(state(false), &error)) << error;  // initial state is written
  EXPECT_EQ(pty.readAvailable(), params.off_bytes);
  ASSERT_TRUE(light->apply(state(true), &error)) << error;
  EXPECT_EQ(pty.readAvailable(), params.on_bytes);
  ASSERT_TRUE(light->apply(state(true), &error)) << error;  // no switch: nothing written
  EXPECT_EQ(pty.readAvailable(100), "");
  ASSERT_TRUE(light->apply(state(false), &error)) << error;
  EXPECT_EQ(pty.readAvailable(), params.off_bytes);
}

TEST(SerialLight, BadConfigurationNamesTheParameter) {
  SerialLightParams params;
  params.port = "/dev/does_not_exist_ecs";
  try {
    makeSerialLight(params);
    FAIL() << "missing port accepted";
  } catch (const core::ConfigError& e) {
    EXPECT_EQ(e.parameter(), "serial_port");
    EXPECT_NE(std::string(e.what()).find("/dev/does_not_exist_ecs"), std::string::npos);
  }
  Pty pty;
  params.port = pty.slave_name;
  params.baud = 12345;
  try {
    makeSerialLight(params);
    FAIL() << "bad baud accepted";
  } catch (const core::ConfigError& e) {
    EXPECT_EQ(e.parameter(), "serial_baud");
  }
  params.baud = 115200;
  params.port = "/dev/null";  // exists but is not a tty
  try {
    makeSerialLight(params);
    FAIL() << "non-tty accepted";
  } catch (const core::ConfigError& e) {
    EXPECT_EQ(e.parameter(), "serial_port");
  }
}
