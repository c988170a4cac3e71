#pragma once
// Runs a shell command for tests that drive a tool end to end: its exit status (-1 when it did
// not exit normally) and its standard output.
//
// Threading: reentrant.
#include <string>

namespace embedded_calibration_stereo::core {

int runCommand(const std::string& command, std::string* out);

}  // namespace embedded_calibration_stereo::core
