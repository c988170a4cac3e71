#include "embedded_calibration_stereo/core/calibration/epipolar_error.h"

#include <cmath>
#include <map>

namespace embedded_calibration_stereo::core {

double epipolarRms(const StereoRig& rig, const std::vector<BoardView>& views) {
  std::map<std::pair<int, int>, const BoardView*> left;
  for (const BoardView& v : views)
    if (v.camera == CameraSide::kLeft) left[{v.frame, v.board}] = &v;
  Eigen::Matrix3d tx;
  const Eigen::Vector3d t = rig.right_from_left.translation();
  tx << 0, -t.z(), t.y(), t.z(), 0, -t.x(), -t.y(), t.x(), 0;
  const Eigen::Matrix3d essential = tx * rig.right_from_left.linear();
  const double focal = std::sqrt(rig.right.fx * rig.right.fy);
  double sum = 0;
  int n = 0;
  for (const BoardView& r : views) {
    if (r.camera != CameraSide::kRight) continue;
    const auto l = left.find({r.frame, r.board});
    if (l == left.end()) continue;
    std::map<int, Eigen::Vector2d> left_pixels;
    for (size_t i = 0; i < l->second->size(); ++i)
      left_pixels[l->second->corner_ids[i]] = l->second->pixels[i];
    for (size_t i = 0; i < r.size(); ++i) {
      const auto lp = left_pixels.find(r.corner_ids[i]);
      if (lp == left_pixels.end()) continue;
      const Eigen::Vector3d xl = rig.left.pixelToNormalized(lp->second).homogeneous();
      const Eigen::Vector3d xr = rig.right.pixelToNormalized(r.pixels[i]).homogeneous();
      const Eigen::Vector3d line = essential * xl;
      const double d = xr.dot(line) / line.head<2>().norm() * focal;
      sum += d * d;
      ++n;
    }
  }
  return n > 0 ? std::sqrt(sum / n) : 0.0;
}

}  // namespace embedded_calibration_stereo::core
