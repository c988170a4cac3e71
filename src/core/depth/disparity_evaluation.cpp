#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"

#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace embedded_calibration_stereo::core {

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
      const double e = static_cast<double>(d[x]) - g[x];
      if (!std::isfinite(d[x])) {
        ++stats.invalid;
        ++stats.bad;
      } else if (std::abs(e) > threshold_px) {
        ++stats.bad;
      } else {
        ++stats.inliers;
        stats.inlier_square_sum += e * e;
      }
    }
  }
  return stats;
}

double BadPixelStats::inlierRmsPx() const {
  return inliers > 0 ? std::sqrt(inlier_square_sum / inliers) : 0.0;
}

cv::Mat loadScaledGroundTruth(const std::string& path, double scale) {
  if (!(scale > 0)) throw std::invalid_argument("ground-truth scale must be > 0");
  const cv::Mat raw = cv::imread(path, cv::IMREAD_ANYDEPTH | cv::IMREAD_GRAYSCALE);
  if (raw.empty()) throw std::runtime_error("cannot read ground truth '" + path + "'");
  cv::Mat gt;
  raw.convertTo(gt, CV_32F, 1.0 / scale);
  return gt;
}

cv::Mat rectifiedDisparityFromDepth(const cv::Mat& left_depth, const RectificationMaps& maps) {
  const RectificationGeometry& g = maps.geometry();
  if (left_depth.type() != CV_32FC1 || left_depth.size() != g.size)
    throw std::invalid_argument("rectifiedDisparityFromDepth: depth must be CV_32FC1 of the rectified size");
  cv::Mat depth = left_depth.clone();
  cv::patchNaNs(depth, 0.0);
  depth.setTo(0.0f, depth > 1e6);
  cv::Mat rect_depth;
  cv::remap(depth, rect_depth, maps.leftMap1(), maps.leftMap2(), cv::INTER_NEAREST,
            cv::BORDER_CONSTANT, 0);
  const double f = g.P1(0, 0), fy = g.P1(1, 1), cx = g.P1(0, 2), cy = g.P1(1, 2);
  const double baseline = g.baseline();
  const cv::Matx33d raw_from_rect = g.R1.t();
  cv::Mat disparity(rect_depth.size(), CV_32F, cv::Scalar(0));
  for (int v = 0; v < rect_depth.rows; ++v) {
    for (int u = 0; u < rect_depth.cols; ++u) {
      const float z_raw = rect_depth.at<float>(v, u);
      if (!(z_raw > 0)) continue;
      // The raw z of a point on the rectified ray (x, y, 1) * z_rect is z_rect * (R1^T ray).z.
      const cv::Vec3d ray = raw_from_rect * cv::Vec3d((u - cx) / f, (v - cy) / fy, 1.0);
      disparity.at<float>(v, u) = static_cast<float>(f * baseline * ray[2] / z_raw);
    }
  }
  return disparity;
}

}  // namespace embedded_calibration_stereo::core
