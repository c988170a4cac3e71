#include "embedded_calibration_stereo/test_support/corner_score.h"

#include <cmath>
#include <cstdio>
#include <map>
#include <opencv2/core.hpp>
#include <utility>

namespace embedded_calibration_stereo::core {

void CornerScore::add(const std::vector<BoardCorners>& tracked, const std::vector<BoardCorners>& truth_boards) {
  std::map<std::pair<int, int>, cv::Point2f> gt;
  for (const BoardCorners& b : truth_boards)
    for (size_t i = 0; i < b.size(); ++i) gt[{b.board_id, b.corner_ids[i]}] = cv::Point2f(b.u[i], b.v[i]);
  truth += gt.size();
  for (const BoardCorners& b : tracked)
    for (size_t i = 0; i < b.size(); ++i) {
      ++reported;
      const auto it = gt.find({b.board_id, b.corner_ids[i]});
      const double err = it == gt.end() ? 1e9 : cv::norm(it->second - cv::Point2f(b.u[i], b.v[i]));
      if (err > kWrongIdPx) {
        ++wrong;
      } else {
        sum_sq += err * err;
        ++matched;
      }
    }
}

void CornerScore::add(const StereoObservation& tracked, const StereoObservation& truth_observation) {
  add(tracked.left, truth_observation.left);
  add(tracked.right, truth_observation.right);
}

double CornerScore::foundFraction() const { return truth ? static_cast<double>(matched) / truth : 0.0; }

double CornerScore::rms() const { return matched ? std::sqrt(sum_sq / matched) : 0.0; }

std::string CornerScore::str() const {
  char buf[200];
  std::snprintf(buf, sizeof(buf), "found %zu/%zu (%.2f%%), wrong ids %zu, RMS %.4f px", matched, truth,
                100.0 * foundFraction(), wrong, rms());
  return buf;
}

void WindowCornerErrors::add(int camera, const std::vector<BoardCorners>& tracked,
                             const std::vector<BoardCorners>& truth) {
  for (const BoardCorners& b : tracked)
    for (const BoardCorners& t : truth) {
      if (t.board_id != b.board_id) continue;
      for (size_t i = 0; i < b.size(); ++i)
        for (size_t j = 0; j < t.size(); ++j)
          if (t.corner_ids[j] == b.corner_ids[i]) {
            const cv::Point2d e(b.u[i] - t.u[j], b.v[i] - t.v[j]);
            sum_sq_ += e.dot(e);
            ++count_;
            auto& s = sums_[{camera, b.board_id, b.corner_ids[i]}];
            s.first += e;
            ++s.second;
          }
    }
}

double WindowCornerErrors::rms() const { return count_ ? std::sqrt(sum_sq_ / count_) : 0.0; }

double WindowCornerErrors::sharedRms() const {
  double q = 0;
  for (const auto& kv : sums_) {
    const cv::Point2d m = kv.second.first / kv.second.second;
    q += m.dot(m);
  }
  return sums_.empty() ? 0.0 : std::sqrt(q / sums_.size());
}

}  // namespace embedded_calibration_stereo::core
