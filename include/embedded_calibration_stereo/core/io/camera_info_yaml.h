#pragma once
// Camera calibration files in the YAML layout of camera_calibration_parsers (what
// camera_info_manager reads and ROS camera_calibration writes), produced without ROS. Write them
// with writeFileAtomically (atomic_file.h).
//
// Threading: pure functions, safe from any thread (two writers of the same path: the last
// rename wins, a reader never sees a partial file).
#include <array>
#include <opencv2/core.hpp>
#include <string>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/core/io/atomic_file.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

// The fields of sensor_msgs/CameraInfo that a calibration file holds.
struct CameraInfoFile {
  int image_width = 0, image_height = 0;
  std::string camera_name;
  cv::Matx33d K = cv::Matx33d::eye();
  std::string distortion_model = "plumb_bob";
  std::vector<double> D;
  cv::Matx33d R = cv::Matx33d::eye();
  cv::Matx34d P = cv::Matx34d::zeros();
};

// The left and right files of a calibrated stereo rig with its rectification: K and D of each
// camera, R1/R2 as rectification_matrix, P1/P2 as projection_matrix (right Tx = -fx' * baseline).
std::pair<CameraInfoFile, CameraInfoFile> stereoCameraInfoFiles(
    const StereoRig& rig, const RectificationGeometry& rectification, const std::string& left_name,
    const std::string& right_name);

// The text of the file, numbers with 17 significant digits (doubles round-trip exactly).
std::string cameraInfoYaml(const CameraInfoFile& file);

}  // namespace embedded_calibration_stereo::core
