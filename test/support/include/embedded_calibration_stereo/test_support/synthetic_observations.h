#pragma once
// Simulated corner observations for tests and benches: projects the corners of the virtual
// boards with the cameras of a StereoRig, keeps those inside the image and adds seeded Gaussian
// corner noise. No rendering is involved, so the truth is exact up to the stated noise.
//
// Threading: free functions without shared state; safe to call from any thread.
#include <cstdint>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

struct SyntheticObservationOptions {
  int frames = 1;
  double noise_sigma_px = 0.2;  // standard deviation of each corner coordinate
  uint64_t seed = 1;
  double margin_px = 0.0;  // corners closer than this to the image border are not seen
  // Drop corners of boards whose front side (local +z) faces away from the camera. Off by
  // default: whether a virtual board's +z points to the viewer depends on the device model.
  bool cull_back_facing = false;
  double first_stamp_s = 0.0;
  double frame_period_s = 1.0 / 30.0;
};

// One StereoObservation per frame; every frame sees the same boards (they are fixed to the
// rig), only the noise differs. Boards with no visible corner in a camera are omitted there.
std::vector<StereoObservation> generateSyntheticObservations(
    const StereoRig& rig, const std::vector<VirtualBoard>& boards,
    const SyntheticObservationOptions& options);

// A layout of virtual boards spread over the left image, for tests and benches when no device
// file is at hand. Boards are placed on a grid of image positions (3 x 2 for six boards) at
// `distance_m`, tilted alternately by +-tilt_deg about the x and y axes; every second board
// is `mirrored` (its local y axis negated, as a mirror copy is).
struct SpreadBoardsOptions {
  int count = 6;
  int cols = 8, rows = 6;  // inner corners
  double square_m = 0.025;
  double distance_m = 1.2;
  double tilt_deg = 25.0;
  // Fraction of the image half-size the grid of board centres spans (0: all at the centre).
  double spread = 0.7;
};
std::vector<VirtualBoard> makeSpreadVirtualBoards(const PinholeCamera& left,
                                                  const SpreadBoardsOptions& options);

// A rig like the simulated head's: 752x480, fx ~650, fy ~648, cx ~370, cy ~245, k1 ~-0.28,
// k2 ~0.07 (p1 = p2 = k3 = 0), baseline 0.12 m, right camera rotated by ~0.5 deg.
StereoRig makeSimLikeStereoRig();

// The nominal device of a real one: the truth moved by manufacturing tolerances. The device pose
// is rotated by `angle_deg` about a random axis and shifted by `position_m` in a random
// direction; each mirror plane is tilted by `angle_deg` about a random in-plane axis and
// shifted by +-position_m along its normal. Seeded, so tests are repeatable.
// The calibration in force after a drift: fx and fy of both cameras scaled by focal_scale
// (a zoom) and the right camera turned about its centre by rotation_deg (rotation vector,
// degrees, applied in the right optical frame, as the simulator's right_rotation_deg).
StereoRig driftedRig(const StereoRig& truth, double focal_scale,
                     const Eigen::Vector3d& rotation_deg);

CalibrationDevice perturbDevice(const CalibrationDevice& device, double position_m,
                                double angle_deg, uint64_t seed);

// Each board of `device` moved by a uniform offset within +-position_m per axis and turned by a
// uniform rotation vector within +-angle_deg per axis (its placement in the housing off by a
// manufacturing tolerance; the device pose and the mirror planes are kept). Seeded.
CalibrationDevice perturbBoardPlacement(const CalibrationDevice& device, double position_m,
                                        double angle_deg, uint64_t seed);

// Scene correspondences of a corridor-like scene (StereoObservation::scene): `count` points
// spread over the left image at inverse depths uniform between 1/22 m and 1/1.5 m, seen by both
// cameras of `rig`, noisy by `noise_px` per coordinate; a share `wrong` of them are wrong
// matches (repeated texture): displaced by up to 10 px along the rows and by 1-3 px across them
// (a match wrong only along its epipolar line is a wrong depth, which an epipolar constraint
// neither sees nor minds). *wrong_count (optional): how many. Seeded.
std::vector<SceneMatch> generateSyntheticSceneMatches(const StereoRig& rig, int count, double noise_px,
                                                      double wrong, uint64_t seed, int* wrong_count = nullptr);

// Errors of an estimated rig against the truth, per camera (0 left, 1 right) where it applies.
struct RigErrors {
  double fx_rel[2], fy_rel[2];  // |estimate - truth| / truth
  double cx_px[2], cy_px[2];
  double k1[2], k2[2];  // absolute
  double baseline_rel;
  double rotation_deg;  // angle between the estimated and true right_from_left rotations
};
RigErrors compareRigs(const StereoRig& estimate, const StereoRig& truth);

}  // namespace embedded_calibration_stereo::core
