#pragma once
// Teaching the pattern tracker: bootstraps every board of one camera with
// cv::findChessboardCornersSB and learns the prior of board_prior.h.
//
// Detection: with a light-off frame the light-on minus light-off difference isolates the device
// (the scene cancels); otherwise the light-on frame itself is searched. Boards are searched one
// at a time in regions of interest: around each board's predicted position when an approximate
// camera is known, else in the connected bright regions of the difference image, else in the
// whole image. A found board is painted over and the region searched again, so neighbouring
// boards of the same size are found too.
// Identification: with an approximate camera every detection is matched to the virtual board
// whose predicted corners it fits best (optimal assignment), and the detected grid is re-ordered
// by whichever grid symmetry (reversal, mirroring) matches the predicted corner ids - so ids are
// consistent in both cameras and mirrored copies get their mirrored order. Without a camera (a
// plain single chessboard) the documented rule is: corner 0 is the outer corner nearest the image
// origin (top-left), and corner 1 lies more to the right than corner cols (below it).
// Boards that are not completely inside the image in a teaching frame cannot be detected there.
//
// Threading: stateless functions.
#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/tracker/board_prior.h"
#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/camera_model.h"
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"

namespace embedded_calibration_stereo::core {

// The boards one camera should see, and optionally how they project (for identification).
struct BoardLayout {
  std::vector<VirtualBoard> boards;
  bool has_camera = false;
  PinholeCamera camera;
  Eigen::Isometry3d camera_from_rig = Eigen::Isometry3d::Identity();

  // One plain chessboard (board id 0) with cols x rows inner corners.
  static BoardLayout plainChessboard(int cols, int rows);
  // The device's virtual boards seen by an approximately known camera.
  static BoardLayout device(const std::vector<VirtualBoard>& boards, const PinholeCamera& camera,
                            const Eigen::Isometry3d& camera_from_rig);
  // Predicted raw pixels of every corner of boards[index] (requires has_camera); false when a
  // corner is behind the camera.
  bool predictCorners(size_t index, std::vector<cv::Point2f>* pixels) const;
};

struct TeachFrame {
  cv::Mat light_on;   // CV_8UC1 or CV_8UC3
  cv::Mat light_off;  // optional, same size and type
};

struct TeachResult {
  CameraPrior prior;
  // Per taught frame: the detected corners of each identified board (all corners, by id).
  std::vector<std::vector<BoardCorners>> detections;
  std::vector<std::string> notes;  // human-readable: what was found / missed, and why
};

// Teaches one camera from one or more frames. Boards found in no frame are left out of the
// prior (and named in notes). Throws std::invalid_argument for bad input images and
// std::runtime_error when no board at all was found.
TeachResult teachCamera(const std::vector<TeachFrame>& frames, const BoardLayout& layout,
                        const std::string& camera_name, ColorOrder order = ColorOrder::kBgr);

}  // namespace embedded_calibration_stereo::core
