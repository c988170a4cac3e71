#include "embedded_calibration_stereo/core/disparity_filling.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <vector>

namespace ecs {

namespace {

// Fills every run of invalid pixels of one row; marks the filled pixels in mask.
void fillRow(float* d, uint8_t* mask, int W) {
  int x = 0;
  while (x < W) {
    if (std::isfinite(d[x])) {
      ++x;
      continue;
    }
    const int start = x;
    while (x < W && !std::isfinite(d[x])) ++x;
    const bool has_left = start > 0, has_right = x < W;
    if (!has_left && !has_right) return;  // no valid pixel on this row
    const float value =
        has_left && has_right ? std::min(d[start - 1], d[x]) : (has_left ? d[start - 1] : d[x]);
    for (int i = start; i < x; ++i) {
      d[i] = value;
      mask[i] = 255;
    }
  }
}

}  // namespace

void fillDisparityHoles(cv::Mat* disparity) {
  cv::Mat& disp = *disparity;
  if (disp.type() != CV_32FC1) throw std::invalid_argument("fillDisparityHoles: need CV_32FC1");
  // Work images kept per calling thread between calls (fresh pages cost page faults every
  // frame); named by reference so that the parallel workers use the caller's.
  thread_local cv::Mat thread_filled_mask, thread_median;
  cv::Mat& filled_mask = thread_filled_mask;
  cv::Mat& median = thread_median;
  filled_mask.create(disp.size(), CV_8U);
  filled_mask.setTo(0);
  cv::parallel_for_(cv::Range(0, disp.rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y)
      fillRow(disp.ptr<float>(y), filled_mask.ptr<uint8_t>(y), disp.cols);
  });
  // Rows filled independently disagree at run ends; a median over the filled pixels evens them.
  cv::medianBlur(disp, median, 3);
  // (Next to a row left all invalid the median may be NaN: keep the row fill there.)
  cv::parallel_for_(cv::Range(0, disp.rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      const uint8_t* filled = filled_mask.ptr<uint8_t>(y);
      const float* m = median.ptr<float>(y);
      float* d = disp.ptr<float>(y);
      for (int x = 0; x < disp.cols; ++x)
        if (filled[x] && m[x] == m[x]) d[x] = m[x];
    }
  });
}

}  // namespace ecs
