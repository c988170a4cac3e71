#include "embedded_calibration_stereo/core/geometry/calibration_device.h"

#include <Eigen/LU>
#include <cmath>

namespace embedded_calibration_stereo::core {

Eigen::Matrix4d MirrorPlane::reflection() const {
  const Eigen::Vector3d n = normal.normalized();
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() -= 2.0 * n * n.transpose();
  m.topRightCorner<3, 1>() = 2.0 * distance * n;
  return m;
}

Eigen::Vector3d MirrorPlane::reflect(const Eigen::Vector3d& p) const {
  const Eigen::Vector3d n = normal.normalized();
  return p - 2.0 * (n.dot(p) - distance) * n;
}

std::string CalibrationDevice::validate() const {
  if (boards.empty()) return "boards: at least one board is required";
  for (size_t i = 0; i < boards.size(); ++i) {
    const Chessboard& b = boards[i];
    const std::string key = "boards[" + std::to_string(i) + "]";
    if (b.cols < 2) return key + ".cols must be >= 2";
    if (b.rows < 2) return key + ".rows must be >= 2";
    if (!(b.square > 0)) return key + ".square_m must be > 0";
  }
  if (copies.empty()) return "copies: at least one mirror copy is required";
  for (size_t c = 0; c < copies.size(); ++c)
    for (size_t m = 0; m < copies[c].size(); ++m)
      if (!(copies[c][m].normal.norm() > 1e-9))
        return "copies[" + std::to_string(c) + "][" + std::to_string(m) + "].normal must be non-zero";
  return "";
}

std::vector<VirtualBoard> CalibrationDevice::virtualBoards() const {
  std::vector<VirtualBoard> out;
  for (size_t c = 0; c < copies.size(); ++c) {
    // Composite of the chain: device-side mirror first.
    Eigen::Matrix4d chain = Eigen::Matrix4d::Identity();
    for (const MirrorPlane& m : copies[c]) chain = m.reflection() * chain;
    const bool mirrored = copies[c].size() % 2 == 1;
    for (size_t b = 0; b < boards.size(); ++b) {
      const Chessboard& board = boards[b];
      VirtualBoard vb;
      vb.virtual_id = static_cast<int>(c * boards.size() + b);
      vb.board_index = static_cast<int>(b);
      vb.copy_index = static_cast<int>(c);
      vb.cols = board.cols;
      vb.rows = board.rows;
      vb.square = board.square;
      vb.mirrored = mirrored;
      // Physical board pose in the rig, reflected: M * T. For an odd chain its rotation has
      // determinant -1; composing with F = diag(1,-1,1) on the board side restores a proper
      // rotation, and cornerInBoard() negates y to match, so each id keeps its physical corner.
      const Eigen::Matrix4d physical = (rig_from_device * board.device_from_board).matrix();
      Eigen::Matrix4d virt = chain * physical;
      if (mirrored) {
        Eigen::Matrix4d flip = Eigen::Matrix4d::Identity();
        flip(1, 1) = -1.0;
        virt = virt * flip;
      }
      vb.rig_from_board.matrix() = virt;
      out.push_back(vb);
    }
  }
  return out;
}

}  // namespace embedded_calibration_stereo::core
