#include "half_mirror_optics.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "device_renderer.h"

namespace embedded_calibration_stereo::core {
namespace sim {

namespace {
constexpr double kDegToRad = M_PI / 180.0;
}

double ghostSeparationM(const SimGhostConfig& g) {
  const double incidence = (90.0 - g.angle_deg) * kDegToRad;
  const double refracted = std::asin(std::sin(incidence) / g.refractive_index);
  return 2.0 * g.thickness_mm * 1e-3 * std::tan(refracted) * std::cos(incidence);
}

double ghostRelativeWeight(const SimGhostConfig& g, double front_reflectance) {
  if (!(front_reflectance > 0.0)) return 0.0;  // no device path at all
  const double transmitted = 1.0 - front_reflectance;
  return transmitted * transmitted * g.back_reflectance / front_reflectance;
}

Eigen::Isometry3d ghostCameraPose(const SimGhostConfig& g, const Eigen::Isometry3d& rig_from_camera) {
  // A camera moved by c sees a point at depth Z shifted by -f c / Z: move it against the
  // direction the ghost is to appear in.
  const double s = ghostSeparationM(g), a = g.direction_deg * kDegToRad;
  Eigen::Isometry3d moved = Eigen::Isometry3d::Identity();
  moved.translation() = -s * Eigen::Vector3d(std::cos(a), std::sin(a), 0.0);
  return rig_from_camera * moved;
}

cv::Mat vignettingFactor(const CameraRays& rays, double strength) {
  // cos(theta) = 1 / sqrt(1 + x^2 + y^2) for the ray (x, y, 1): cos^(4 s) = (1 + r^2)^(-2 s).
  cv::Mat r2 = rays.x.mul(rays.x) + rays.y.mul(rays.y) + 1.0;
  cv::Mat factor;
  cv::pow(r2, -2.0 * strength, factor);
  return factor;
}

void renderGhost(const SimOpticsConfig& optics, const std::vector<VirtualBoard>& boards, const CameraRays& rays,
                 const Eigen::Isometry3d& rig_from_camera, cv::Mat* ghost) {
  ghost->release();
  if (!(ghostRelativeWeight(optics.ghost, optics.reflectance) > 0.0)) return;
  renderDevice(boards, rays, ghostCameraPose(optics.ghost, rig_from_camera), optics.device_white,
               optics.device_black, ghost);
  if (optics.psf_sigma_px > 0)
    cv::GaussianBlur(*ghost, *ghost, cv::Size(), optics.psf_sigma_px, 0, cv::BORDER_REPLICATE);
}

void applyDeviceOptics(const SimOpticsConfig& optics, const cv::Mat& ghost, const cv::Mat& device_vignetting,
                       cv::Mat* device) {
  if (!ghost.empty()) cv::scaleAdd(ghost, ghostRelativeWeight(optics.ghost, optics.reflectance), *device, *device);
  if (!device_vignetting.empty()) cv::multiply(*device, device_vignetting, *device);
}

double deviceShiftPx(const std::vector<VirtualBoard>& boards, const PinholeCamera& camera,
                     const Eigen::Isometry3d& rig_from_camera_a, const Eigen::Isometry3d& rig_from_camera_b) {
  const Eigen::Isometry3d a_from_rig = rig_from_camera_a.inverse(), b_from_rig = rig_from_camera_b.inverse();
  double shift = 0.0;
  for (const VirtualBoard& board : boards) {
    const int last = board.cornerCount() - 1;
    for (int id : {0, board.cols - 1, last - (board.cols - 1), last}) {
      const Eigen::Vector3d p = board.cornerInRig(id);
      Eigen::Vector2d pa, pb;
      if (!camera.project(a_from_rig * p, &pa) || !camera.project(b_from_rig * p, &pb)) return HUGE_VAL;
      shift = std::max(shift, (pa - pb).norm());
    }
  }
  return shift;
}

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
