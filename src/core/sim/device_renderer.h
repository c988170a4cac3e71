#pragma once
// Renders the lit calibration device as one camera sees it: every virtual board's chessboard
// (a white margin of one square around (cols+1) x (rows+1) squares) on the dark housing.
//
// Anti-aliasing is analytic: per pixel, the board coordinates (in squares) and their Jacobian
// with respect to the pixel give the pixel footprint in board coordinates; the pattern is
// written as sums of products of 1D step/square-wave functions of the column and row
// coordinates, each averaged exactly over the pixel area (second differences of
// antiderivatives). Straight edges get the exact pixel-area profile; the filters are
// symmetric, so every grid line and the saddle at each inner corner stay exactly where the
// geometry puts them. Pixels with no edge under them are point sampled (the fast path).
//
// Threading: stateless; renderDevice() uses cv::parallel_for_ internally.
#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <vector>

#include "camera_rays.h"
#include "embedded_calibration_stereo/core/geometry/calibration_device.h"

namespace embedded_calibration_stereo::core {
namespace sim {

// Device radiance as a fraction of full scale (CV_32F): `white` on lit white squares and the
// margin, `black` on black squares and on the housing (every pixel no board covers).
void renderDevice(const std::vector<VirtualBoard>& boards, const CameraRays& rays,
                  const Eigen::Isometry3d& rig_from_camera, double white, double black,
                  cv::Mat* radiance);

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
