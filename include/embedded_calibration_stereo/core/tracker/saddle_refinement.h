#pragma once
// Sub-pixel position of one chessboard corner by fitting a blurred-saddle model to the pixels
// around it (ROS-free).
//
// Why not cv::cornerSubPix: its gradient-orthogonality estimate has a bias that depends on the
// corner's sub-pixel phase and on the edges' blur. It is the same in every frame of a window
// (the device's boards do not move), so averaging frames does not remove it, and the calibrator
// turns it into calibration error. The model here is the image a blurred X-junction makes:
//   m(p) = a + g . (p - c) + b * erf(n1 . (p - c) / (sqrt(2) s)) * erf(n2 . (p - c) / (sqrt(2) s))
// with c the corner, n1, n2 the normals of its two edges, s the edge blur (lens PSF and pixel
// area), a + g . d a smooth background (vignetting, what is left of the scene), b the contrast.
// It is point-symmetric about c like a real corner, so its fitted c is not pulled by the pixel
// grid. Solved by Ceres (Levenberg-Marquardt, analytic derivatives), one small problem per corner.
//
// Threading: a pure function; safe to call concurrently.
#include <memory>
#include <opencv2/core.hpp>
#include <vector>

namespace ceres {
class CostFunction;
}

namespace embedded_calibration_stereo::core {

struct SaddleFitOptions {
  int radius_px = 5;            // half-size of the fitted square window (>= 2)
  double initial_blur_px = 1.2; // starting edge blur (standard deviation, px)
  int max_iterations = 25;
  // The fit fails when the corner moves further than this from its start (px) ...
  double max_shift_px = 2.0;
  // ... or when its contrast |b| is below this (grey levels).
  double min_contrast = 2.0;
};

struct SaddleFit {
  cv::Point2d corner;         // fitted corner (OpenCV pixel convention: pixel centres at integers)
  double contrast = 0.0;      // b: signed, half the grey-level swing between the quadrants
  double blur_px = 0.0;       // s
  double rms_residual = 0.0;  // grey levels
};

// Fits the model to `gray` (CV_8UC1 or CV_32FC1) around `start`. along_col and along_row are the
// directions of the board's two lines through the corner (any length, e.g. one square). Returns
// false (and leaves *fit unspecified) when the window leaves the image, the fit does not
// converge, or it fails the checks of SaddleFitOptions.
bool fitSaddle(const cv::Mat& gray, cv::Point2f start, cv::Point2f along_col, cv::Point2f along_row,
               const SaddleFitOptions& options, SaddleFit* fit);

// fitSaddle's cost over one window: residual i = m(offsets[i]) - values[i] (offsets: pixel minus
// the window's centre), one parameter block of 9: cx, cy (the corner, from the window's centre),
// the two edge normals' angles, a, gx, gy, b, log(s). Its derivatives are written out (automatic
// ones cost 3 times as much); exposed so that a test can check them. Both vectors must outlive it.
std::unique_ptr<ceres::CostFunction> makeSaddleCost(const std::vector<float>* values,
                                                    const std::vector<cv::Point2f>* offsets);

}  // namespace embedded_calibration_stereo::core
