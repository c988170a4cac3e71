#include "embedded_calibration_stereo/core/tracker/scene_background.h"

#include <cmath>
#include <opencv2/imgproc.hpp>

namespace embedded_calibration_stereo::core {

namespace {

// Cubic monomials of normalised coordinates (x, y in about [-1, 1]).
constexpr int kTerms = 10;
inline void monomials(double x, double y, double* m) {
  m[0] = 1, m[1] = x, m[2] = y, m[3] = x * x, m[4] = x * y, m[5] = y * y;
  m[6] = x * x * x, m[7] = x * x * y, m[8] = x * y * y, m[9] = y * y * y;
}

}  // namespace

void SceneBackground::set(const cv::Mat& gray_light_off) {
  CV_Assert(gray_light_off.type() == CV_8UC1);
  image_ = gray_light_off.clone();
  anchor_.clear();
  last_motion_px_ = 0.0;
}

void SceneBackground::clear() {
  image_.release();
  anchor_.clear();
  last_motion_px_ = 0.0;
}

cv::Mat SceneBackground::difference(const cv::Mat& gray, double smoothing_sigma) const {
  CV_Assert(gray.size() == image_.size() && gray.type() == CV_8UC1);
  cv::Mat diff;
  // Saturating u8 arithmetic: gray + offset - background.
  cv::addWeighted(gray, 1.0, image_, -1.0, kDifferenceOffset, diff, CV_8U);
  if (smoothing_sigma > 0) {
    // Kernel truncated at 2 sigma (7 taps for 1.5): symmetric, so corners do not move, and
    // cheaper than OpenCV's default 3-sigma kernel.
    const int k = 2 * static_cast<int>(std::ceil(2.0 * smoothing_sigma)) + 1;
    cv::GaussianBlur(diff, diff, cv::Size(k, k), smoothing_sigma);
  }
  return diff;
}

bool SceneBackground::follow(const std::vector<BoardCorners>& tracked, double motion_threshold_px) {
  if (image_.empty()) return false;
  std::vector<cv::Point2f> now, then;
  for (const BoardCorners& b : tracked) {
    for (size_t i = 0; i < b.size(); ++i) {
      const auto it = anchor_.find({b.board_id, b.corner_ids[i]});
      if (it == anchor_.end()) continue;
      now.emplace_back(b.u[i], b.v[i]);
      then.push_back(it->second);
    }
  }
  auto setAnchor = [&]() {
    anchor_.clear();
    for (const BoardCorners& b : tracked)
      for (size_t i = 0; i < b.size(); ++i)
        anchor_[{b.board_id, b.corner_ids[i]}] = cv::Point2f(b.u[i], b.v[i]);
  };
  if (anchor_.empty()) {
    setAnchor();
    last_motion_px_ = 0.0;
    return false;
  }
  if (now.size() < 2 * kTerms) {
    last_motion_px_ = 0.0;
    return false;  // too few common corners to tell (light off, or the boards lost)
  }
  double sq = 0;
  for (size_t k = 0; k < now.size(); ++k) sq += std::pow(cv::norm(now[k] - then[k]), 2);
  last_motion_px_ = std::sqrt(sq / now.size());
  if (last_motion_px_ < motion_threshold_px) return false;

  // Fit the map current pixel -> background pixel, so that remap() pulls the background over.
  const double sx = 2.0 / image_.cols, sy = 2.0 / image_.rows;
  cv::Mat a(static_cast<int>(now.size()), kTerms, CV_64F), bx(a.rows, 1, CV_64F), by(a.rows, 1, CV_64F);
  for (int k = 0; k < a.rows; ++k) {
    monomials(now[k].x * sx - 1.0, now[k].y * sy - 1.0, a.ptr<double>(k));
    bx.at<double>(k) = then[k].x - now[k].x;
    by.at<double>(k) = then[k].y - now[k].y;
  }
  cv::Mat cx, cy;
  if (!cv::solve(a, bx, cx, cv::DECOMP_SVD) || !cv::solve(a, by, cy, cv::DECOMP_SVD)) return false;
  cv::Mat map_x(image_.size(), CV_32F), map_y(image_.size(), CV_32F);
  const double* px = cx.ptr<double>();
  const double* py = cy.ptr<double>();
  cv::parallel_for_(cv::Range(0, image_.rows), [&](const cv::Range& range) {
    double m[kTerms];
    for (int v = range.start; v < range.end; ++v) {
      float* mx = map_x.ptr<float>(v);
      float* my = map_y.ptr<float>(v);
      for (int u = 0; u < image_.cols; ++u) {
        monomials(u * sx - 1.0, v * sy - 1.0, m);
        double dx = 0, dy = 0;
        for (int t = 0; t < kTerms; ++t) dx += px[t] * m[t], dy += py[t] * m[t];
        mx[u] = static_cast<float>(u + dx);
        my[u] = static_cast<float>(v + dy);
      }
    }
  });
  cv::Mat warped;
  cv::remap(image_, warped, map_x, map_y, cv::INTER_CUBIC, cv::BORDER_REPLICATE);
  image_ = warped;
  setAnchor();
  return true;
}

}  // namespace embedded_calibration_stereo::core
