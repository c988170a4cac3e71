#pragma once
// Ordinary stereo calibration from images of one flat chessboard (the calibrate_images tool):
// corner detection, OpenCV initialisation and refinement by the BundleAdjuster with a free
// board pose per image pair (Zhang's maximum-likelihood formulation), which also gives a
// standard deviation for every parameter.
//
// Pipeline: cv::findChessboardCornersSB (or findChessboardCorners + cornerSubPix) per image ->
// cv::calibrateCamera per camera -> cv::stereoCalibrate with the intrinsics held (R, T only)
// -> BundleAdjuster (kPerFrame, initialised from that rig, all parameters refined jointly) ->
// per-pair board poses re-fitted on the final rig for per-image residuals -> Bouguet
// rectification (cv::stereoRectify) for the CameraInfo R and P.
//
// Corner order: OpenCV may return a grid with its rows and/or columns reversed. Each order is a
// valid pose of the planar board (an in-plane reflection is a rotation out of the plane), but
// the two images of a pair see one pose, so the right grid is re-ordered to run the way the left
// one does. Square grids (cols == rows) are refused: their order may also be transposed.
//
// Threading: pure functions, safe from any thread.
#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/bundle_adjuster.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"

namespace embedded_calibration_stereo::core {

struct ChessboardSpec {
  int cols = 0, rows = 0;  // inner corners across and down
  double square_m = 0.0;
  // Empty when usable, otherwise what is wrong.
  std::string validate() const;
  // The board as a (non-mirrored) VirtualBoard with id 0; corner id = row * cols + col.
  VirtualBoard virtualBoard() const;
  // OpenCV object points in corner-id order (z = 0).
  std::vector<cv::Point3f> objectPoints() const;
};

// Parses "COLSxROWS" (e.g. "9x6"); on failure returns false and says why in *error.
bool parseBoardSize(const std::string& text, int* cols, int* rows, std::string* error);

enum class CornerDetector {
  // cv::findChessboardCorners (falling back to cv::findChessboardCornersSB when it misses the
  // board), corners placed by cv::cornerSubPix - the default, as ROS camera_calibration:
  // unbiased on the simulated images of test_board_calibration.
  kCornerSubPix,
  // cv::findChessboardCornersSB with its own sub-pixel refinement (CALIB_CB_ACCURACY): several
  // times less accurate and biased on the same images, so a several times worse calibration.
  kSectorBased,
};

// Finds the cols x rows inner corners in an 8-bit image (grey or BGR); corner order as OpenCV
// returns it (row-major). False when the whole board is not found.
bool detectChessboard(const cv::Mat& image, int cols, int rows, CornerDetector detector,
                      std::vector<cv::Point2f>* corners);

// Corners of both images of one pair, each in corner-id order.
struct StereoBoardDetection {
  std::string name;  // for messages and the report (e.g. the left file name)
  std::vector<cv::Point2f> left, right;
};

// Puts the left list first-corner-on-top and re-orders the right grid (rows and/or columns
// reversed) so that it runs the same way as the left one.
void orientConsistently(StereoBoardDetection* detection, int cols, int rows);

struct BoardCalibrationOptions {
  // Distortion terms estimated: k1, k2 always; p1, p2 and k3 by choice (default as ROS
  // camera_calibration: k1, k2, p1, p2).
  bool estimate_tangential = true;
  bool estimate_k3 = false;
  // Least squares by default, the maximum-likelihood estimate under Gaussian corner noise and
  // the objective of cv::stereoCalibrate; a robust loss only matters with bad corners.
  RobustLoss loss = RobustLoss::kNone;
  double loss_scale_px = 1.0;
  int min_pairs = 5;                   // fewer usable pairs: refuse
  RectificationOptions rectification;  // Bouguet, alpha 0 by default (as camera_calibration)
};

// cv::calibrateCamera / stereoCalibrate flags that estimate the same distortion terms.
int openCvDistortionFlags(const BoardCalibrationOptions& options);

struct PairResiduals {
  std::string name;
  // Predicted minus detected pixel per corner (corner-id order), at the final calibration with
  // the pair's board pose re-fitted; `left_pixels` / `right_pixels` are the detections.
  std::vector<Eigen::Vector2d> left, right;
  std::vector<Eigen::Vector2d> left_pixels, right_pixels;
  double rms_left_px = 0, rms_right_px = 0, rms_px = 0;
};

struct BoardCalibrationResult {
  bool ok = false;
  std::string message;  // why it failed
  StereoRig rig;
  BundleAdjustmentSummary summary;   // the adjustment: standard deviations, epipolar RMS...
  double rms_px = 0;                 // over every corner of both cameras (as stereoCalibrate's)
  double opencv_initial_rms_px = 0;  // cv::stereoCalibrate with intrinsics held (the start)
  std::vector<PairResiduals> pairs;
  RectificationGeometry rectification;
};

// Calibrates from the detections (at least options.min_pairs, all of `image_size`).
BoardCalibrationResult calibrateStereoBoard(const ChessboardSpec& board, const cv::Size& image_size,
                                            std::vector<StereoBoardDetection> detections,
                                            const BoardCalibrationOptions& options);

}  // namespace embedded_calibration_stereo::core
