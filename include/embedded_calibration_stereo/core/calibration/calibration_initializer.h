#pragma once
// Starting point of the stereo bundle adjustment: either Zhang's closed form on the boards'
// homographies (cv::initCameraMatrix2D on the virtual boards of one frame, each board a view;
// mirrored boards use VirtualBoard::cornerInBoard, a proper planar pattern with z = 0), or the
// calibration in force. Board poses come from a planar PnP (IPPE) with the chosen cameras.
//
// Threading: pure functions, safe from any thread.
#include <Eigen/Geometry>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/calibration/observation_validator.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

struct ZhangInitialization {
  bool ok = false;
  std::string message;  // why it failed, empty on success
  StereoRig rig;
};

// Initialises each camera (fx, fy; principal point at the centre, no distortion) from the
// frame with the most corners (all frames see the same boards, so more frames only average
// noise, which the adjustment does better), then averages right_from_left over the boards
// both cameras see in that frame. Needs at least
// `min_views` boards per camera and one board common to both.
ZhangInitialization initializeWithZhang(const std::vector<BoardView>& views,
                                        const std::vector<VirtualBoard>& boards, int image_width,
                                        int image_height, int min_views = 3);

// Pose of the board in the optical frame of the camera that saw `view` (planar PnP, IPPE).
// Returns false when OpenCV cannot solve it (degenerate corners).
bool estimateCameraFromBoard(const PinholeCamera& camera, const BoardView& view,
                             const VirtualBoard& board, Eigen::Isometry3d* camera_from_board);

// Same, expressed in the rig (left optical) frame using the rig's extrinsics for right views.
bool estimateRigFromBoard(const StereoRig& rig, const BoardView& view, const VirtualBoard& board,
                          Eigen::Isometry3d* rig_from_board);

// Initial rig_from_board per (frame, board index) - frame -1 when `shared` (one pose for all
// frames) - each from its best view: the left camera first, then most corners; or the layout's
// VirtualBoard::rig_from_board when `from_layout`. Keys without a pose go to `failed`.
std::map<std::pair<int, int>, Eigen::Isometry3d> initialBoardPoses(
    const StereoRig& rig, const std::vector<BoardView>& views,
    const std::vector<VirtualBoard>& boards, bool shared, bool from_layout,
    std::set<std::pair<int, int>>* failed);

}  // namespace embedded_calibration_stereo::core
