#pragma once
// The embedded calibration device (three planar chessboards in a rigid housing) and its
// virtual copies seen through planar mirrors.
//
// Board frame: origin at inner corner (0,0), x along columns, y along rows, z = 0 on the board
// surface, z = x cross y (away from a camera that sees x to the right and y down, as in OpenCV).
// Corner id = row * cols + col.
// A mirror reflection flips handedness. A virtual board keeps a proper rotation by flipping
// its local y axis (`mirrored` = true): the corner with id `row * cols + col` is still the
// reflection of the physical corner with the same id, and sits at local (col*s, -row*s, 0).
#include <Eigen/Geometry>
#include <string>
#include <vector>

namespace embedded_calibration_stereo::core {

struct Chessboard {
  int id = 0;            // index in the device, 0..n-1
  int cols = 0;          // inner corners per row
  int rows = 0;          // inner corners per column
  double square = 0.0;   // metres
  Eigen::Isometry3d device_from_board = Eigen::Isometry3d::Identity();
  int cornerCount() const { return cols * rows; }
  Eigen::Vector3d cornerInBoard(int corner_id) const {
    return Eigen::Vector3d((corner_id % cols) * square, (corner_id / cols) * square, 0.0);
  }
};

// A plane n . x = d (n unit) in the frame it is expressed in.
struct MirrorPlane {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  double distance = 0.0;
  // Householder reflection as a 4x4 affine transform (determinant -1).
  Eigen::Matrix4d reflection() const;
  Eigen::Vector3d reflect(const Eigen::Vector3d& p) const;
};

// One board as one camera rig sees it: a physical board reflected by one mirror copy.
struct VirtualBoard {
  int virtual_id = 0;    // copy * boards + board: the board_id of observations
  int board_index = 0;   // physical board index in the device
  int copy_index = 0;    // which mirror copy
  int cols = 0, rows = 0;
  double square = 0.0;
  bool mirrored = false;
  // Proper rigid pose of the virtual board in the left optical (rig) frame.
  Eigen::Isometry3d rig_from_board = Eigen::Isometry3d::Identity();
  // Local coordinates of a corner in the virtual board frame (y negated when mirrored).
  Eigen::Vector3d cornerInBoard(int corner_id) const {
    const double y = (corner_id / cols) * square;
    return Eigen::Vector3d((corner_id % cols) * square, mirrored ? -y : y, 0.0);
  }
  Eigen::Vector3d cornerInRig(int corner_id) const { return rig_from_board * cornerInBoard(corner_id); }
  int cornerCount() const { return cols * rows; }
};

struct CalibrationDevice {
  std::vector<Chessboard> boards;
  // Pose of the physical device in the rig (left optical) frame.
  Eigen::Isometry3d rig_from_device = Eigen::Isometry3d::Identity();
  // One chain of mirror planes (in the rig frame) per virtual copy, applied in order from the
  // device toward the camera. An odd chain flips handedness.
  std::vector<std::vector<MirrorPlane>> copies;

  std::string validate() const;
  // Every board of every copy, in virtual_id order.
  std::vector<VirtualBoard> virtualBoards() const;
  int virtualBoardCount() const { return static_cast<int>(boards.size() * copies.size()); }
};

}  // namespace embedded_calibration_stereo::core
