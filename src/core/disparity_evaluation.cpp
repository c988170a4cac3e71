#include "embedded_calibration_stereo/core/disparity_evaluation.h"

#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>

namespace ecs {

BadPixelStats evaluateBadPixels(const cv::Mat& disparity, const cv::Mat& ground_truth,
                                double threshold_px) {
  if (disparity.type() != CV_32FC1 || ground_truth.type() != CV_32FC1)
    throw std::invalid_argument("evaluateBadPixels: disparity and ground truth must be CV_32FC1");
  if (disparity.size() != ground_truth.size())
    throw std::invalid_argument("evaluateBadPixels: disparity and ground truth sizes differ");
  BadPixelStats stats;
  for (int y = 0; y < disparity.rows; ++y) {
    const float* d = disparity.ptr<float>(y);
    const float* g = ground_truth.ptr<float>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      if (!(g[x] > 0) || !std::isfinite(g[x])) continue;
      ++stats.evaluated;
      if (!std::isfinite(d[x])) {
        ++stats.invalid;
        ++stats.bad;
      } else if (std::abs(d[x] - g[x]) > threshold_px) {
        ++stats.bad;
      }
    }
  }
  return stats;
}

cv::Mat loadScaledGroundTruth(const std::string& path, double scale) {
  if (!(scale > 0)) throw std::invalid_argument("ground-truth scale must be > 0");
  const cv::Mat raw = cv::imread(path, cv::IMREAD_ANYDEPTH | cv::IMREAD_GRAYSCALE);
  if (raw.empty()) throw std::runtime_error("cannot read ground truth '" + path + "'");
  cv::Mat gt;
  raw.convertTo(gt, CV_32F, 1.0 / scale);
  return gt;
}

}  // namespace ecs
