#pragma once
// Groups corner observations into tracks for the bundle adjuster: all observations of the
// same corner of the same board in the same camera that share one board pose.
//
// With board poses shared across frames (the embedded device is fixed to the left camera),
// every frame predicts the same pixel for a corner, so
//   sum_f |p - o_f|^2 = n |p - mean|^2 + sum_f |o_f - mean|^2 :
// one residual on the track mean, weighted by n, gives exactly the least-squares solution and
// covariance of the per-observation problem at the cost of a single frame. Before averaging,
// observations far from the track's median (a corner mis-detected in one frame) are dropped;
// the robust loss still guards against corners that are wrong in every frame.
//
// Threading: pure function, safe from any thread.
#include <Eigen/Core>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/observation_validator.h"

namespace embedded_calibration_stereo::core {

struct CornerTrack {
  CameraSide camera = CameraSide::kLeft;
  int frame = -1;  // -1: shared across frames
  int board = 0;   // index into the virtual board list
  int corner_id = 0;
  std::vector<Eigen::Vector2d> observations;  // kept observations (after the median test)
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  double scatter_sq = 0.0;  // sum of |o - mean|^2 over the kept observations
};

struct CornerTracks {
  std::vector<CornerTrack> tracks;
  int rejected = 0;  // observations dropped by the median test
};

// `shared_across_frames` false: one track per observation (frame kept), nothing averaged.
// The median test runs on tracks with at least 3 observations.
CornerTracks buildCornerTracks(const std::vector<BoardView>& views, bool shared_across_frames,
                               double max_distance_from_median_px);

}  // namespace embedded_calibration_stereo::core
