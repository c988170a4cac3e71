#pragma once
// Pinhole camera with the plumb_bob distortion model of ROS CameraInfo / OpenCV
// (k1, k2, p1, p2, k3; unused terms zero; the arithmetic is plumb_bob_distortion.h's). Pixel
// convention: the centre of the top-left pixel is (0, 0), as in OpenCV and CameraInfo.
#include <Eigen/Core>
#include <array>
#include <string>

namespace embedded_calibration_stereo::core {

struct PinholeCamera {
  int width = 0;
  int height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  double skew = 0;  // K(0,1); zero for every camera we model, kept for completeness.
  // Distortion in CameraInfo.D order: k1, k2, p1, p2, k3.
  std::array<double, 5> dist{{0, 0, 0, 0, 0}};

  // Empty when usable; otherwise a message naming the bad field (e.g. "fx must be > 0").
  std::string validate() const;

  // Normalised undistorted coordinates (x/z, y/z) -> normalised distorted coordinates.
  Eigen::Vector2d distort(const Eigen::Vector2d& xn) const;
  // Inverse of distort() by Newton iteration; converges to 1e-12 inside the image.
  Eigen::Vector2d undistortNormalized(const Eigen::Vector2d& xd) const;

  // 3D point in the camera's optical frame (x right, y down, z forward) -> raw pixel.
  // Points with z <= 0 are not projectable; returns false for them.
  bool project(const Eigen::Vector3d& p_cam, Eigen::Vector2d* pixel) const;
  // Normalised undistorted -> raw (distorted) pixel.
  Eigen::Vector2d normalizedToPixel(const Eigen::Vector2d& xn) const;
  // Raw pixel -> normalised undistorted coordinates (ray direction (x, y, 1)).
  Eigen::Vector2d pixelToNormalized(const Eigen::Vector2d& pixel) const;
  // Undistorted ideal pixel (K * normalised), as used after rectification/undistortion.
  Eigen::Vector2d undistortPixel(const Eigen::Vector2d& pixel) const;

  bool inImage(const Eigen::Vector2d& pixel, double margin = 0.0) const {
    return pixel.x() >= margin && pixel.y() >= margin && pixel.x() <= width - 1 - margin &&
           pixel.y() <= height - 1 - margin;
  }
  Eigen::Matrix3d K() const;
  // Returns a copy with fx, fy scaled (a zoom step); the principal point stays.
  PinholeCamera withFocalScale(double scale) const;
};

}  // namespace embedded_calibration_stereo::core
