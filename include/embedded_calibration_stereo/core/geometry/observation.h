#pragma once
// Board corners and scene correspondences seen in images: the core counterpart of
// BoardObservation / SceneMatch / StereoPatternObservation messages.
#include <cstddef>
#include <cstdint>
#include <vector>

namespace embedded_calibration_stereo::core {

struct BoardCorners {
  int board_id = 0;              // VirtualBoard::virtual_id
  std::vector<int> corner_ids;   // row * cols + col of the physical board
  std::vector<float> u, v;       // raw (distorted) pixel coordinates
  size_t size() const { return corner_ids.size(); }
};

// One scene point seen by both cameras at the same instant, raw (distorted) pixel coordinates:
// an epipolar constraint on the calibration whatever the point's depth (found by
// calibration/scene_matches.h, used by calibration/bundle_adjuster.h).
struct SceneMatch {
  float left_u = 0, left_v = 0, right_u = 0, right_v = 0;
};

struct StereoObservation {
  double stamp = 0.0;  // seconds
  std::vector<BoardCorners> left, right;
  // Scene correspondences of light-off frames taken with the boards' images (e.g. around a
  // light window), under the same calibration; often empty.
  std::vector<SceneMatch> scene;
  size_t cornerCount() const {
    size_t n = 0;
    for (const auto& b : left) n += b.size();
    for (const auto& b : right) n += b.size();
    return n;
  }
};

}  // namespace embedded_calibration_stereo::core
