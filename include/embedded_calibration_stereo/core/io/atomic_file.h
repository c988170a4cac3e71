#pragma once
// Atomic file replacement: a reader (or a crash) sees either the old file or the complete new
// one, never a partial write. Used for everything the head persists (calibration files, the
// tracker's prior, calibrate_images' outputs).
//
// Threading: safe from any thread; two writers of the same path: the last rename wins.
#include <string>

namespace embedded_calibration_stereo::core {

// Writes `content` to `path` through a temporary file in the same directory (mkstemp), fsync,
// rename over the target and fsync of the directory. The file gets 0666 minus the umask. Throws
// std::runtime_error naming the path and the system's reason (missing directory, no permission,
// disk full...); the target is then unchanged and no temporary file is left.
void writeFileAtomically(const std::string& path, const std::string& content);

}  // namespace embedded_calibration_stereo::core
