#pragma once
// YAML loading (OpenCV FileStorage) of the core's configuration structures, with validation.
// Every function throws ConfigError naming the parameter path on missing or invalid values.
#include <opencv2/core/persistence.hpp>
#include <optional>
#include <string>

#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

// Opens a YAML file for reading; throws ConfigError(path, ...) when missing or unparsable.
cv::FileStorage openYaml(const std::string& path);

// camera node: {width, height, fx, fy, cx, cy, [skew], [distortion: [k1,k2,p1,p2,k3]]}
PinholeCamera loadCamera(const cv::FileNode& node, const std::string& path);
// rig node: {left: camera, right: camera, right_from_left: {rotation_deg: [rx,ry,rz]
// (rotation vector, degrees), translation_m: [x,y,z]}}
StereoRig loadStereoRig(const cv::FileNode& node, const std::string& path);
// pose node: {rotation_deg: [rx,ry,rz], translation_m: [x,y,z]}
Eigen::Isometry3d loadPose(const cv::FileNode& node, const std::string& path);
// device node: {boards: [{cols, rows, square_m, pose: pose}], pose: pose,
// copies: [[{normal: [x,y,z], distance_m: d}, ...], ...]}
CalibrationDevice loadDevice(const cv::FileNode& node, const std::string& path);

// A device_config file: the device (its boards, mirror copies) and, when the file has a rig
// section, the nominal cameras of the drawing (never the simulator's truth).
struct DeviceDescription {
  CalibrationDevice device;
  std::optional<StereoRig> nominal;
};
// Reads `file`'s device and rig sections. Any problem throws ConfigError(parameter, "'file': "
// + what is wrong): `parameter` is the setting that named the file (device_config).
DeviceDescription loadDeviceDescription(const std::string& file, const std::string& parameter);
// Only the rig section (a driver needs no boards); nothing when the file has none.
std::optional<StereoRig> loadNominalRig(const std::string& file, const std::string& parameter);

// Helpers shared by the loaders.
double readPositive(const cv::FileNode& node, const std::string& key, const std::string& path);
double readDouble(const cv::FileNode& node, const std::string& key, const std::string& path,
                  double fallback);
Eigen::Vector3d readVector3(const cv::FileNode& node, const std::string& key,
                            const std::string& path);

}  // namespace embedded_calibration_stereo::core
