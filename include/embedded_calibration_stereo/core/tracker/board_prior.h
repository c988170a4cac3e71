#pragma once
// The pattern tracker's prior: where each (virtual) board lies in one camera's image, learned
// by teaching, and how it is stored (YAML through cv::FileStorage).
//
// Grid coordinates: corner id = row * cols + col sits at grid point (col, row), in squares.
// The outer corners are taken in the order of ids 0, cols-1, rows*cols-1, (rows-1)*cols.
//
// Prior file format (YAML, cv::FileStorage; writePatternPrior/readPatternPrior):
//   format: "ecs_pattern_prior"        version: 1
//   cameras:                             one entry per camera, in order (left, right)
//     - name: "left"   width: 752   height: 480   taught_frames: 4
//       boards:
//         - board_id: 3        VirtualBoard::virtual_id (0 for a plain board)
//           cols: 7  rows: 5   inner corners per row / per column
//           outer_mean: [u0, v0, u1, v1, u2, v2, u3, v3]      mean outer corners, px
//           outer_modes: !!opencv-matrix (k x 8)  principal modes (unit rows, cv::PCA)
//           outer_sigma: [s1..sk]  standard deviation (px) along each mode
//           offsets: [du0, dv0, du1, dv1, ...]  per corner: mean taught position minus the
//                    homography through the outer corners (lens distortion), px
//           sign: -1 or 1          +1 when the square at (+col, +row) of corner 0 is bright
//           contrast: 110.5        median saddle contrast when taught, grey levels
//           square_px: 14.2        mean side of one square in the image, px
//           device_pattern: 1      optional (default 1): 1 for the device's boards (exact,
//                    smooth geometry, full outer squares and a white margin), 0 for a printed
//                    chessboard (outer squares may be cut, printing and mounting not exact)
//           edge_blur_px: 0.9      optional (default 0, unknown): edge blur measured when taught
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace embedded_calibration_stereo::core {

struct BoardPrior {
  int board_id = 0;
  int cols = 0, rows = 0;
  cv::Mat outer_mean;                // 1 x 8 CV_64F
  cv::Mat outer_modes;               // k x 8 CV_64F (k may be 0)
  cv::Mat outer_sigma;               // 1 x k CV_64F
  std::vector<cv::Point2f> offsets;  // cols * rows
  int sign = 1;
  double contrast = 0.0;
  double square_px = 0.0;
  // The device's boards: their geometry is smooth and their outer squares are whole, inside a
  // white margin, so the whole-board alignment smooths the taught corners and uses the outer
  // squares' edges. A printed chessboard (taught with --board) gets neither.
  bool device_pattern = true;
  // Edge blur measured when taught (standard deviation of the edge profile, px; 0 = unknown). A
  // printed board's alignment uses it (the device's boards use TrackerOptions::alignment_blur_px,
  // set for the device's optics).
  double edge_blur_px = 0.0;

  int cornerCount() const { return cols * rows; }
  std::vector<cv::Point2f> meanOuterCorners() const;
  // Grid points of the outer corners, in the order of meanOuterCorners().
  std::vector<cv::Point2f> outerGridPoints() const;
  // Empty when usable; otherwise what is wrong ("offsets: expected 35 entries").
  std::string validate() const;
};

struct CameraPrior {
  std::string name;
  int width = 0, height = 0;
  int taught_frames = 0;
  std::vector<BoardPrior> boards;
  std::string validate() const;
};

struct PatternPrior {
  std::vector<CameraPrior> cameras;  // one (mono) or two (left, right)
  std::string validate() const;
};

// Throw ConfigError naming the file and the offending entry. The file is replaced atomically
// (writeFileAtomically).
void writePatternPrior(const std::string& path, const PatternPrior& prior);
PatternPrior readPatternPrior(const std::string& path);

}  // namespace embedded_calibration_stereo::core
