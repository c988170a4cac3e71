#pragma once
// Photometric alignment of one whole board (private to the pattern tracker).
//
// Why: without a background of the current scene, a corner refined in a small window is pulled
// by the scene's texture behind it by a few tenths of a pixel. Every pixel near an edge of the
// known pattern carries information about the board's position, and the scene is uncorrelated
// with the pattern, so fitting the whole board at once averages the scene's pull away.
//
// Model: the board as taught (its corners at y_i in the taught image) moved by one image
// homography A (zoom, thermal drift and knocks move a board by a map that is a homography to
// well below the accuracy asked of the tracker over one board), seen as
//   I(A(y)) = a_cell(y) + b * T(y) + scene,
// where T is the checker pattern (with its white margin for the device's boards), blurred like a
// lens blurs it, in the taught image; b is the contrast and a_cell one brightness per cell (an eighth of a square on a
// side): the scene's mean there, exposure and vignetting. A scene brighter on one side of an
// edge than on the other would move that edge; the cell levels take that step out of the fit.
// The taught corners' offsets are smoothed by a cubic over the board first when it fits them (the
// distortion is smooth, each taught corner's own refinement error is not). A is
// found by Gauss-Newton (forward additive, with the fitted pattern's gradient in place of the
// image's, so the scene's texture cannot steer the steps) with Huber weights, so a scene
// edge or a moving object counts as little as a few pixels of noise.
//
// Threading: a template is built once and then only read; alignBoard touches nothing shared (its
// working memory is per thread).
#include <opencv2/core.hpp>
#include <vector>

#include "embedded_calibration_stereo/core/tracker/board_prior.h"

namespace embedded_calibration_stereo::core {
namespace tracker {

struct AlignmentTemplate {
  cv::Point2d centre;                // normalisation of taught coordinates: (y - centre) / scale
  double scale = 1.0;
  std::vector<cv::Point2f> ref;      // samples, normalised taught coordinates
  std::vector<float> value;          // T at each sample, in [-1, 1] (+1 bright)
  std::vector<cv::Point2f> grad;     // dT / d(normalised taught coordinates)
  std::vector<int> cell;             // brightness cell of each sample (an eighth of a square on a side)
  int cells = 0;
  std::vector<int> cell_start;       // the samples are in cell order: cell c's are [cell_start[c], cell_start[c + 1])
  std::vector<cv::Point2f> corners;  // corner id -> normalised taught coordinates
  std::vector<int> corner;           // the corner id nearest to each sample
  bool empty() const { return ref.empty(); }
};

// Samples taught pixels within 2.5 blur widths of an edge of the pattern: the squares and the
// inner half of the margin for the device's boards, the inner corners' lattice and half a square
// beyond it for a printed board (BoardPrior::device_pattern), every other pixel (stride 2, a quincunx) or every
// stride-th pixel of every stride-th row. blur_px: standard deviation of the expected edge blur.
AlignmentTemplate buildAlignmentTemplate(const BoardPrior& board, double blur_px, int stride = 2);

struct AlignmentResult {
  bool ok = false;
  cv::Matx33d a;            // normalised taught coordinates -> pixel
  double contrast = 0.0;    // b: half the bright-dark difference, grey levels
  double huber = 0.0;       // robust residual scale of the last pass, grey levels
  std::vector<double> levels;  // a_c per cell, grey levels
  int samples = 0;
  int passes = 0;
  bool converged = false;  // the last step moved the board's corners by less than 0.05 px
  // Per corner id: the pattern's contrast fitted on the samples nearest that corner alone, as a
  // fraction of `contrast` (what an occluder hides); NaN for corners without samples.
  std::vector<float> corner_contrast;
};

// gray: CV_8UC1 image. start.a: the starting map (within a pixel or so). With warm (the last
// frame's result, the board not moved since) its contrast, cell levels and residual scale are
// taken as they are, which saves the photometric-only first pass. Gauss-Newton steps stop after max_steps or
// when a step moved the board's corners by less than 0.05 px.
AlignmentResult alignBoard(const AlignmentTemplate& t, const cv::Mat& gray, const AlignmentResult& start,
                           bool warm, int max_steps);

// Least-squares homography normalised taught coordinates -> pixel through listed corners.
bool fitAlignmentStart(const AlignmentTemplate& t, const std::vector<int>& ids,
                       const std::vector<cv::Point2f>& pixels, cv::Matx33d* a);

}  // namespace tracker
}  // namespace embedded_calibration_stereo::core
