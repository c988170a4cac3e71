#pragma once
// A process's resident memory as Linux reports it (/proc/PID/status), for tests and benches.
#include <string>

namespace embedded_calibration_stereo::test_support {

// The /proc/PID/status field `key` ("VmRSS", "VmHWM", ...) of `pid` (0: this process), in kB;
// -1 when unknown.
long processStatusKb(int pid, const std::string& key);

// Resets this process's peak resident memory (VmHWM) to its current one (clear_refs 5).
void resetPeakMemory();

}  // namespace embedded_calibration_stereo::test_support
