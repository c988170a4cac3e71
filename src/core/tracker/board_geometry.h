#pragma once
// Private helpers of the pattern tracker: board grid homographies, box-averaged image samples
// and the saddle test of a chessboard corner.
#include <opencv2/core.hpp>
#include <vector>

#include "embedded_calibration_stereo/core/tracker/board_prior.h"

namespace embedded_calibration_stereo::core {
namespace tracker {

inline cv::Point2f applyHomography(const cv::Matx33d& h, double x, double y) {
  const double w = h(2, 0) * x + h(2, 1) * y + h(2, 2);
  return cv::Point2f(static_cast<float>((h(0, 0) * x + h(0, 1) * y + h(0, 2)) / w),
                     static_cast<float>((h(1, 0) * x + h(1, 1) * y + h(1, 2)) / w));
}

inline cv::Point2f gridPoint(int corner_id, int cols) {
  return cv::Point2f(static_cast<float>(corner_id % cols), static_cast<float>(corner_id / cols));
}

// Homography grid -> pixel through four outer corners (order of BoardPrior::outerGridPoints()).
cv::Matx33d homographyFromOuter(const BoardPrior& board, const std::vector<cv::Point2f>& outer);

// Linear least-squares homography grid -> image (h33 = 1, image coordinates normalised for
// conditioning): the board's corners are near a homography, so the algebraic fit is enough and
// an order of magnitude cheaper than cv::findHomography's LM refinement. False when degenerate.
bool fitHomographyLeastSquares(const std::vector<cv::Point2f>& grid, const std::vector<cv::Point2f>& image,
                               cv::Matx33d* h);

// Local grid directions (pixel displacement of one square along col and row) at a grid point.
void gridAxes(const cv::Matx33d& h, double col, double row, cv::Point2f* along_col, cv::Point2f* along_row);

// Box means of a grey image through the integral image of a region of it.
class BoxSampler {
 public:
  // region is clipped to the image; radius is the box half-size (box side 2 * radius + 1).
  BoxSampler(const cv::Mat& gray, cv::Rect region, int radius);
  // Mean grey of the box centred at the pixel nearest to p; false when it leaves the region.
  bool mean(cv::Point2f p, float* value) const;
  bool contains(cv::Point2f p) const;
  int radius() const { return radius_; }

 private:
  cv::Mat integral_;  // CV_32S, (h+1) x (w+1)
  cv::Rect region_;
  int radius_;
  float inv_area_;
};

// Saddle contrast of a chessboard corner at p: box means at p +- 0.3 (along_col +- along_row);
// `bright` = +1 when the (+col, +row) and (-col, -row) quadrants are expected bright, -1 for
// the other pair. Returns min(bright quadrants) - max(dark quadrants); -inf when a sample leaves
// the sampler's region. Negative means the expected saddle is not there.
float saddleContrast(const BoxSampler& sampler, cv::Point2f p, cv::Point2f along_col, cv::Point2f along_row,
                     int bright);

}  // namespace tracker
}  // namespace embedded_calibration_stereo::core
