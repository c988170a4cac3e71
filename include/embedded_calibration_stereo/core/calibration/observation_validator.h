#pragma once
// Checks corner observations before calibration: every defect (non-finite coordinates,
// duplicate or out-of-range corner ids, unknown board ids, corners far outside the image,
// boards with too few corners) is dropped with a human-readable reason, never a crash.
//
// Threading: pure function, safe from any thread.
#include <Eigen/Core>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"

namespace embedded_calibration_stereo::core {

enum class CameraSide { kLeft = 0, kRight = 1 };

// The usable corners of one board seen by one camera in one frame.
struct BoardView {
  int frame = 0;  // index into the input frames
  CameraSide camera = CameraSide::kLeft;
  int board = 0;  // index into the virtual board list (not the board_id)
  std::vector<int> corner_ids;
  std::vector<Eigen::Vector2d> pixels;
  size_t size() const { return corner_ids.size(); }
};

struct ObservationValidationOptions {
  int image_width = 0, image_height = 0;
  // Corners further outside the image than this are dropped (a wrong image size or a bad id).
  double max_outside_image_px = 2.0;
  // Boards with fewer valid corners are dropped: too few to constrain their pose.
  int min_corners_per_board = 6;
};

struct ValidatedObservations {
  std::vector<BoardView> views;
  std::vector<std::string> dropped;  // one line per defect found
  int frames_used = 0;               // frames with at least one usable view
};

ValidatedObservations validateObservations(const std::vector<StereoObservation>& frames,
                                           const std::vector<VirtualBoard>& boards,
                                           const ObservationValidationOptions& options);

}  // namespace embedded_calibration_stereo::core
