#pragma once
// Parameter blocks of the bundle adjuster's rigid device model (BoardPoseMode::kDeviceModel):
// one rig_from_device, each board's placement in the device (device_from_board) and the mirror
// planes of every copy's chain, with their manifolds, their priors and their alignment to freely
// estimated virtual boards.
//
// Gauge. Each copy's virtual device is observable as one rigid (improper) pose, 6 DoF. The
// model has 6 (device pose) + 3 per plane. With the sim's two single-plane copies that is 12
// parameters, but the two virtual copies are tied: V1 V0^-1 = R1 R0 is the product of two
// reflections, a rotation about the planes' intersection line L (5 DoF, no screw along L), so
// the data determine 11 of them. The 12th is a gauge: turning both planes about L by phi and
// the device about L by 2 phi leaves every virtual corner where it is. Longer chains add 3
// gauge DoF per extra plane (any improper motion is already reached with three planes, and
// two planes only define one motion about their line). Rather than hold a chain-dependent
// choice of parameters, a weak prior around the nominal device (50 deg, 0.1 m by default: a
// hundred times looser than the manufacturing tolerances) fixes every gauge direction and
// hardly informs the observable ones (BundleAdjustmentOptions::device_prior_angle_deg gives
// figures); the cameras' parameters and covariance are gauge-invariant.
// With the planes held (refine_mirror_planes = false) only the device pose is estimated and
// nothing is in the gauge, but a plane off by 0.5 deg then moves its copy by ~1 deg.
// Board placement. A housing holds its boards to a manufacturing tolerance (about 1 mm and
// 0.3 deg): a board off by that misplaces its corners by a few tenths of a pixel in every
// frame, which no camera parameter explains. Each board's placement is therefore a block of
// its own (refine_placement). The corners determine it: each board is seen through two copies
// whose relative motion all boards share, and its grid is exact. Only moving every board one
// way and the device pose the other leaves the virtual corners where they are: a gauge, fixed
// by the same weak prior. A prior at the tolerance itself would pull the cameras toward the
// drawing's error (bench: test_device_model_adjustment prints both).
// Chains are independent: a plane shared by several copies (the half-mirror) is modelled once
// per copy.
//
// Threading: used only inside BundleAdjuster::Solve(), on the caller's stack.
#include <ceres/problem.h>

#include <array>
#include <map>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/calibration_device.h"

namespace embedded_calibration_stereo::core {

struct DeviceModelPriors {
  double angle_tolerance_rad = 0.0;
  double position_tolerance_m = 0.0;
  bool refine_planes = true;
  bool refine_placement = true;  // each board's device_from_board (otherwise held)
};

class DeviceModelBlocks {
 public:
  // Starts from the given (nominal) device, plane normals made unit.
  explicit DeviceModelBlocks(const CalibrationDevice& nominal);
  // Ceres keeps pointers into the blocks.
  DeviceModelBlocks(const DeviceModelBlocks&) = delete;
  DeviceModelBlocks& operator=(const DeviceModelBlocks&) = delete;

  // Parameter blocks of a corner residual (DeviceCornerReprojectionCost): intrinsics, device
  // pose, the board's placement, extrinsics (right camera only: pass nullptr for the left), the
  // copy's planes.
  std::vector<double*> residualBlocks(const VirtualBoard& board, double* intrinsics,
                                      double* extrinsics);
  int planeCount(int copy) const { return static_cast<int>(planes_.at(copy).size()); }
  // A physical corner in its board's frame (the printed grid, held).
  Eigen::Vector3d cornerInBoard(int board_index, int corner_id) const;

  // Manifolds (unit quaternion; unit normal on the sphere + distance), the prior residuals
  // and, when `hold` or the planes (placements) are not refined, the constant blocks. Call once all corner
  // residuals are in `problem`. Returns the prior residual blocks (for their cost).
  std::vector<ceres::ResidualBlockId> configure(ceres::Problem* problem,
                                                const DeviceModelPriors& priors, bool hold);

  // Moves the device pose (and the planes and placements when refined) so that the model's virtual boards
  // match freely estimated ones (rig_from_board by virtual id, as BundleAdjustmentSummary
  // gives them): least squares on the corner positions, with the same prior. Returns the RMS
  // corner distance (m) after alignment, or a negative value when nothing could be aligned.
  double alignTo(const std::vector<VirtualBoard>& layout,
                 const std::map<int, Eigen::Isometry3d>& rig_from_board,
                 const DeviceModelPriors& priors);

  // The device with the current pose, placements and planes.
  CalibrationDevice device() const;

 private:
  CalibrationDevice nominal_;
  std::array<double, 7> nominal_pose_{};
  std::array<double, 7> pose_{};
  std::vector<std::array<double, 7>> nominal_placements_, placements_;  // per board
  std::vector<std::vector<std::array<double, 4>>> nominal_planes_, planes_;
};

}  // namespace embedded_calibration_stereo::core
