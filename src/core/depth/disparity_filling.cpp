#include "embedded_calibration_stereo/core/depth/disparity_filling.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <vector>
#include "parallel_pieces.h"

namespace embedded_calibration_stereo::core {

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
  thread_local cv::Mat thread_row_filled, thread_filled_mask;
  cv::Mat& row_filled = thread_row_filled;
  cv::Mat& filled_mask = thread_filled_mask;
  row_filled.create(disp.size(), CV_32F);
  filled_mask.create(disp.size(), CV_8U);
  cv::parallel_for_(cv::Range(0, disp.rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      float* f = row_filled.ptr<float>(y);
      uint8_t* mask = filled_mask.ptr<uint8_t>(y);
      std::copy(disp.ptr<float>(y), disp.ptr<float>(y) + disp.cols, f);
      std::fill(mask, mask + disp.cols, 0);
      fillRow(f, mask, disp.cols);
    }
  });
  // Rows filled independently disagree at run ends; a 3x3 median over the filled pixels evens
  // them. It runs in stripes of rows, each with one row of context either side (as
  // cv::medianBlur of the whole map would see them), reading row_filled and writing disp, so
  // that the stripes need no ordering. Next to a row left all invalid the median may be NaN:
  // the row fill stays there.
  const int stripes = parallelPieces(disp.rows, 16);
  cv::parallel_for_(cv::Range(0, stripes), [&](const cv::Range& range) {
    thread_local cv::Mat median;
    for (int s = range.start; s < range.end; ++s) {
      const int y0 = disp.rows * s / stripes, y1 = disp.rows * (s + 1) / stripes;
      const int context0 = std::max(y0 - 1, 0), context1 = std::min(y1 + 1, disp.rows);
      cv::medianBlur(row_filled.rowRange(context0, context1), median, 3);
      for (int y = y0; y < y1; ++y) {
        const uint8_t* filled = filled_mask.ptr<uint8_t>(y);
        const float* m = median.ptr<float>(y - context0);
        const float* f = row_filled.ptr<float>(y);
        float* d = disp.ptr<float>(y);
        for (int x = 0; x < disp.cols; ++x) d[x] = filled[x] && m[x] == m[x] ? m[x] : f[x];
      }
    }
  }, stripes);
}

}  // namespace embedded_calibration_stereo::core
