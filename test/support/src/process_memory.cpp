#include "embedded_calibration_stereo/test_support/process_memory.h"

#include <fstream>

namespace embedded_calibration_stereo::test_support {

long processStatusKb(int pid, const std::string& key) {
  std::ifstream in("/proc/" + (pid > 0 ? std::to_string(pid) : std::string("self")) + "/status");
  const std::string prefix = key + ":";
  for (std::string line; std::getline(in, line);)
    if (line.rfind(prefix, 0) == 0) return std::stol(line.substr(prefix.size()));
  return -1;
}

void resetPeakMemory() { std::ofstream("/proc/self/clear_refs") << "5"; }

}  // namespace embedded_calibration_stereo::test_support
