#pragma once
// How well tracked corners match the ground truth: found, wrong ids and RMS over the corners
// with the right id. The one score of the tracker tests and bench_tracker.
#include <cstddef>
#include <map>
#include <opencv2/core.hpp>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/observation.h"

namespace embedded_calibration_stereo::core {

struct CornerScore {
  // A reported corner farther than this from the true corner of its id is a wrong id (a slipped
  // square is ~12 px off; a correct corner is within a few tenths of a pixel).
  static constexpr double kWrongIdPx = 1.0;

  size_t truth = 0;     // visible corners in the ground truth
  size_t reported = 0;  // corners the tracker reported
  size_t wrong = 0;     // reported corners with no true corner of that id within kWrongIdPx
  size_t matched = 0;   // reported corners with the right id
  double sum_sq = 0.0;  // over the matched corners

  void add(const std::vector<BoardCorners>& tracked, const std::vector<BoardCorners>& truth_boards);
  void add(const StereoObservation& tracked, const StereoObservation& truth_observation);
  double foundFraction() const;
  double rms() const;
  // "found M/N (P%), wrong ids W, RMS R px"
  std::string str() const;
};

// Corner errors of the frames of one window against the truth: the RMS over every tracked corner,
// and the RMS over the corners of their mean error in the window, the part the window's frames
// share (the device's boards do not move during a window), which more frames do not average
// out. Corners are matched by (board id, corner id); `camera` keeps the two cameras apart.
struct WindowCornerErrors {
  void add(int camera, const std::vector<BoardCorners>& tracked, const std::vector<BoardCorners>& truth);
  double rms() const;
  double sharedRms() const;

 private:
  std::map<std::tuple<int, int, int>, std::pair<cv::Point2d, int>> sums_;  // (camera, board, corner)
  double sum_sq_ = 0.0;
  int count_ = 0;
};

}  // namespace embedded_calibration_stereo::core
