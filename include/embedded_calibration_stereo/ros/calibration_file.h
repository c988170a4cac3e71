#pragma once
// Calibration files of camera_info_manager URLs, written atomically.
//
// URL resolution follows camera_info_manager: an empty URL means
// file://${ROS_HOME}/camera_info/${NAME}.yaml; ${NAME} and ${ROS_HOME} (default ~/.ros) are
// substituted in one pass; file:// takes an absolute path and package://PKG/PATH a path inside
// a ROS package. Other schemes are not writable files and are rejected.
//
// writeCalibrationFileAtomic() writes the camera_calibration_parsers format (YAML, or INI for a
// .ini name) to a temporary file in the target's directory, fsyncs it, renames it over the
// target and fsyncs the directory, so a crash at any point leaves either the old or the new
// complete file, never a truncated one.
// All functions are thread-safe (no shared state).
#include <sensor_msgs/CameraInfo.h>
#include <string>

namespace embedded_calibration_stereo {

// Resolves `url` for camera `camera_name` to a local file path. Returns false and the reason
// in *error for an unsupported scheme, an unknown package or an empty path.
bool resolveCalibrationUrl(const std::string& url, const std::string& camera_name,
                           std::string* path, std::string* error);

// Writes `info` for `camera_name` to `path` atomically, creating missing parent directories.
// Returns false and the reason (with the OS error) in *error; the previous file, if any, is
// then unchanged and no temporary file is left behind.
bool writeCalibrationFileAtomic(const std::string& path, const std::string& camera_name,
                                const sensor_msgs::CameraInfo& info, std::string* error);

// Reads a calibration file. Returns false and the reason in *error when it is missing or
// cannot be parsed.
bool readCalibrationFile(const std::string& path, std::string* camera_name,
                         sensor_msgs::CameraInfo* info, std::string* error);

}  // namespace embedded_calibration_stereo
