#include "embedded_calibration_stereo/test_support/run_command.h"

#include <sys/wait.h>

#include <cstdio>

namespace embedded_calibration_stereo::core {

int runCommand(const std::string& command, std::string* out) {
  out->clear();
  FILE* pipe = ::popen(command.c_str(), "r");
  if (!pipe) return -1;
  char buffer[4096];
  size_t n;
  while ((n = std::fread(buffer, 1, sizeof(buffer), pipe)) > 0) out->append(buffer, n);
  const int status = ::pclose(pipe);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace embedded_calibration_stereo::core
