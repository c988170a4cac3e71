#pragma once
// The half-mirror and lens effects of a real head on the simulated rig's cached layers:
//  - the second-surface ghost: the part of the device's light that enters the glass plate,
//    reflects off its back surface and leaves again, parallel to the main reflection but
//    displaced sideways by s = 2 d tan(theta_t) cos(theta_i) (plate thickness d, incidence
//    theta_i = 90 deg - angle to the optical axis, sin(theta_t) = sin(theta_i) / n). A ray
//    displaced by s sees what a camera displaced by s sees: the ghost is the device rendered
//    from the camera translated by s against the configured image direction (shift f s / Z
//    pixels for a point at depth Z). Its weight relative to the main device image is
//    (1 - R)^2 R_b / R (front reflectance R = optics.reflectance, back reflectance R_b);
//    higher-order internal reflections (~R_b^2) are left out;
//  - vignetting: cos(theta)^(4 * strength) of the field angle theta of each pixel's true ray,
//    separately for the scene and the device path, applied after the lens blur.
//
// Threading: stateless functions.
#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <vector>

#include "camera_rays.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {
namespace sim {

// Lateral separation of the back-surface reflection from the front-surface one, metres.
double ghostSeparationM(const SimGhostConfig& ghost);
// Ghost radiance relative to the main device image (0 without a ghost).
double ghostRelativeWeight(const SimGhostConfig& ghost, double front_reflectance);
// The pose of the camera that sees the ghost where this camera sees the device.
Eigen::Isometry3d ghostCameraPose(const SimGhostConfig& ghost, const Eigen::Isometry3d& rig_from_camera);
// cos(theta)^(4 * strength) per pixel (CV_32F), theta the angle of the pixel's ray to the axis.
cv::Mat vignettingFactor(const CameraRays& rays, double strength);

// The ghost of the device (blurred like it, not yet weighted) as the camera at rig_from_camera
// sees it through the plate; left empty when the optics have no ghost.
void renderGhost(const SimOpticsConfig& optics, const std::vector<VirtualBoard>& boards, const CameraRays& rays,
                 const Eigen::Isometry3d& rig_from_camera, cv::Mat* ghost);

// Adds the ghost (renderGhost(); empty: none) at its relative weight to `device` and applies
// the device path's vignetting (vignettingFactor(rays, optics.vignetting.device), which the
// caller keeps; empty when there is none), in place. Does nothing when both are empty.
void applyDeviceOptics(const SimOpticsConfig& optics, const cv::Mat& ghost, const cv::Mat& device_vignetting,
                       cv::Mat* device);

// The largest displacement in the image, pixels, of the boards' outer corners between the
// camera at rig_from_camera_a and at rig_from_camera_b (a drift's step): how far a device layer
// rendered at one pose is from the other.
double deviceShiftPx(const std::vector<VirtualBoard>& boards, const PinholeCamera& camera,
                     const Eigen::Isometry3d& rig_from_camera_a, const Eigen::Isometry3d& rig_from_camera_b);

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
