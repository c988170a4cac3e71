#include "embedded_calibration_stereo/test_support/symmetric_corner.h"

#include <algorithm>
#include <cmath>

namespace embedded_calibration_stereo::core {

namespace {

double cubicWeight(double t) {  // Keys, a = -0.5
  t = std::abs(t);
  if (t < 1) return (1.5 * t - 2.5) * t * t + 1;
  if (t < 2) return ((-0.5 * t + 2.5) * t - 4) * t + 2;
  return 0;
}

}  // namespace

double bicubicSample(const cv::Mat& img, double x, double y) {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  double sum = 0;
  for (int j = -1; j <= 2; ++j) {
    const float* row = img.ptr<float>(std::min(std::max(y0 + j, 0), img.rows - 1));
    const double wy = cubicWeight(y - (y0 + j));
    for (int i = -1; i <= 2; ++i)
      sum += wy * cubicWeight(x - (x0 + i)) * row[std::min(std::max(x0 + i, 0), img.cols - 1)];
  }
  return sum;
}

cv::Point2d symmetricCorner(const cv::Mat& img, cv::Point2d c, int radius) {
  const double h = 1e-3;
  for (int it = 0; it < 20; ++it) {
    double a = 0, b = 0, d = 0, gx = 0, gy = 0;
    for (int dy = 0; dy <= radius; ++dy)
      for (int dx = -radius; dx <= radius; ++dx) {
        if (dy == 0 && dx <= 0) continue;  // each symmetric pair once
        auto r = [&](double x, double y) { return bicubicSample(img, x + dx, y + dy) - bicubicSample(img, x - dx, y - dy); };
        const double r0 = r(c.x, c.y);
        const double jx = (r(c.x + h, c.y) - r(c.x - h, c.y)) / (2 * h);
        const double jy = (r(c.x, c.y + h) - r(c.x, c.y - h)) / (2 * h);
        a += jx * jx, b += jx * jy, d += jy * jy, gx += jx * r0, gy += jy * r0;
      }
    const double det = a * d - b * b;
    if (!(std::abs(det) > 1e-12)) break;
    const double sx = (d * gx - b * gy) / det, sy = (a * gy - b * gx) / det;
    c.x -= sx, c.y -= sy;
    if (sx * sx + sy * sy < 1e-12) break;
  }
  return c;
}

}  // namespace embedded_calibration_stereo::core
