#pragma once
// Simulated images of one flat chessboard held in front of a stereo rig, as a user collects
// them for an ordinary offline calibration (calibrate_images): the board is a VirtualBoard
// without mirrors (one white square of margin around the grid, dark background), rendered by
// the simulator's analytic anti-aliased board renderer (sim/device_renderer.h), blurred by a
// symmetric Gaussian lens PSF (moves no corner) and given Gaussian sensor noise.
//
// Threading: pure functions (the renderer uses cv::parallel_for_ internally).
#include <Eigen/Geometry>
#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

struct FlatBoardImageOptions {
  double white = 0.85;        // radiance of white squares and margin, fraction of full scale
  double black = 0.10;        // black squares and background
  double psf_sigma_px = 0.8;  // Gaussian lens blur (0 = none)
  double noise_sigma = 1.5;   // Gaussian sensor noise, grey levels (0..255)
};

struct FlatBoardImagePair {
  cv::Mat left, right;      // CV_8UC1
  StereoObservation truth;  // every inner corner visible in each image, exact positions
};

// Renders `board` (its rig_from_board in the left optical frame) as both cameras see it.
FlatBoardImagePair renderFlatBoardPair(const StereoRig& rig, const VirtualBoard& board,
                                       const FlatBoardImageOptions& options, uint64_t noise_seed);

struct FlatBoardPoseOptions {
  int count = 30;                // poses to return
  double min_distance_m = 0.45;  // distance of the board centre from the left camera
  double max_distance_m = 0.80;
  double min_tilt_deg = 15.0;  // angle between board normal and the viewing direction
  double max_tilt_deg = 40.0;
  double image_margin_px = 8.0;  // the whole board, margin included, stays this far inside
};

// Poses of a cols x rows inner-corner board (square metres) the way a careful user moves it
// for a calibration: centres spread over a grid of image positions (centre, edges, corners),
// tilted 15-40 deg about varying axes and rolled, at varying distance, each with the whole
// board (margin included) inside both images. Deterministic for a given seed. Returns fewer
// than options.count poses only if the rig cannot see the board whole often enough.
std::vector<Eigen::Isometry3d> flatBoardCalibrationPoses(const StereoRig& rig, int cols, int rows,
                                                         double square,
                                                         const FlatBoardPoseOptions& options,
                                                         uint64_t seed);

}  // namespace embedded_calibration_stereo::core
