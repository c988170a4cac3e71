#pragma once
// Per-pixel ray maps of one camera for the simulated rig: the normalised undistorted direction
// (x, y, 1) of every raw pixel centre, so that renderers never undistort per frame. The
// Jacobian d(x, y)/d(u, v), which sizes the anti-aliasing filters, is cheap to evaluate
// analytically where needed; storing it would cost more in memory traffic than it saves.
//
// Threading: plain data; computeCameraRays() uses cv::parallel_for_ internally.
#include <opencv2/core.hpp>

#include "embedded_calibration_stereo/core/geometry/camera_model.h"

namespace embedded_calibration_stereo::core {
namespace sim {

struct CameraRays {
  PinholeCamera camera;   // the intrinsics the maps were computed for
  cv::Mat x, y;           // CV_32F: undistorted normalised ray (x, y, 1) through each pixel centre
  double max_radius = 0;  // largest |(x, y)| over the image (bounds the visible cone)
  // The pyramid x/z in [x_min, x_max], y/z in [y_min, y_max] holds every pixel's ray.
  double x_min = 0, x_max = 0, y_min = 0, y_max = 0;

  // d(x, y)/d(u, v) at the ray (x, y), row-major (dx/du, dx/dv, dy/du, dy/dv).
  void jacobian(double x, double y, double J[4]) const;
};

CameraRays computeCameraRays(const PinholeCamera& camera);

// True when both cameras have identical intrinsics (the ray maps can be reused).
bool sameIntrinsics(const PinholeCamera& a, const PinholeCamera& b);

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
