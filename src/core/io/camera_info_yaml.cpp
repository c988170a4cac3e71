#include "embedded_calibration_stereo/core/io/camera_info_yaml.h"


#include <cstdio>
#include <sstream>
#include <stdexcept>

namespace embedded_calibration_stereo::core {

namespace {

CameraInfoFile cameraFile(const PinholeCamera& camera, const cv::Matx33d& r, const cv::Matx34d& p,
                          const std::string& name) {
  CameraInfoFile f;
  f.image_width = camera.width;
  f.image_height = camera.height;
  f.camera_name = name;
  f.K = cameraMatrix(camera);
  f.D.assign(camera.dist.begin(), camera.dist.end());
  f.R = r;
  f.P = p;
  return f;
}

std::string matrixYaml(int rows, int cols, const double* values) {
  std::ostringstream s;
  s.precision(17);
  s << "  rows: " << rows << "\n  cols: " << cols << "\n  data: [";
  for (int i = 0; i < rows * cols; ++i) s << (i ? ", " : "") << values[i];
  s << "]\n";
  return s.str();
}

}  // namespace

std::pair<CameraInfoFile, CameraInfoFile> stereoCameraInfoFiles(
    const StereoRig& rig, const RectificationGeometry& rectification, const std::string& left_name,
    const std::string& right_name) {
  return {cameraFile(rig.left, rectification.R1, rectification.P1, left_name),
          cameraFile(rig.right, rectification.R2, rectification.P2, right_name)};
}

std::string cameraInfoYaml(const CameraInfoFile& f) {
  std::ostringstream s;
  s << "image_width: " << f.image_width << "\nimage_height: " << f.image_height
    << "\ncamera_name: " << f.camera_name << "\ncamera_matrix:\n"
    << matrixYaml(3, 3, f.K.val) << "distortion_model: " << f.distortion_model
    << "\ndistortion_coefficients:\n"
    << matrixYaml(1, static_cast<int>(f.D.size()), f.D.data()) << "rectification_matrix:\n"
    << matrixYaml(3, 3, f.R.val) << "projection_matrix:\n"
    << matrixYaml(3, 4, f.P.val);
  return s.str();
}

}  // namespace embedded_calibration_stereo::core
