#pragma once
// Board corners seen in images: the core counterpart of BoardObservation /
// StereoPatternObservation messages.
#include <cstdint>
#include <vector>

namespace ecs {

struct BoardCorners {
  int board_id = 0;              // VirtualBoard::virtual_id
  std::vector<int> corner_ids;   // row * cols + col of the physical board
  std::vector<float> u, v;       // raw (distorted) pixel coordinates
  size_t size() const { return corner_ids.size(); }
};

struct StereoObservation {
  double stamp = 0.0;  // seconds
  std::vector<BoardCorners> left, right;
  size_t cornerCount() const {
    size_t n = 0;
    for (const auto& b : left) n += b.size();
    for (const auto& b : right) n += b.size();
    return n;
  }
};

}  // namespace ecs
