#include "embedded_calibration_stereo/core/calibration/depth_coverage_watch.h"

#include <algorithm>
#include <cstdio>
#include <stdexcept>
#include <vector>

namespace embedded_calibration_stereo::core {

std::string DepthCoverageWatchOptions::validate() const {
  if (!(recent_s > 0.0)) return "recent_s must be > 0";
  if (!(history_s > recent_s)) return "history_s must be > recent_s";
  if (!(min_history_s >= 0.0 && min_history_s <= history_s)) return "min_history_s must be in [0, history_s]";
  if (!(collapse_ratio > 0.0 && collapse_ratio < 1.0)) return "collapse_ratio must be in (0, 1)";
  if (!(min_reference >= 0.0 && min_reference < 1.0)) return "min_reference must be in [0, 1)";
  return "";
}

std::string CoverageCollapse::text() const {
  char text[160];
  std::snprintf(text, sizeof(text), "valid disparity on %.0f %% of the image against %.0f %% before", 100.0 * recent,
                100.0 * reference);
  return text;
}

DepthCoverageWatch::DepthCoverageWatch(DepthCoverageWatchOptions options) : options_(options) {
  const std::string problem = options_.validate();
  if (!problem.empty()) throw std::invalid_argument("DepthCoverageWatchOptions: " + problem);
}

void DepthCoverageWatch::add(double t, double valid_fraction) {
  if (!recent_.empty() && t < recent_.back().t) rebase();
  recent_.push_back({t, valid_fraction});
  while (recent_.front().t < t - options_.recent_s) recent_.pop_front();
  if (collapse()) return;  // not learned: the history keeps the level before the collapse
  history_.push_back({t, valid_fraction});
  while (history_.front().t < t - options_.history_s) history_.pop_front();
}

double DepthCoverageWatch::median(const std::deque<Sample>& samples) {
  std::vector<double> values;
  for (const Sample& s : samples) values.push_back(s.fraction);
  const auto middle = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

std::optional<CoverageCollapse> DepthCoverageWatch::collapse() const {
  if (recent_.empty() || history_.empty()) return std::nullopt;
  if (history_.back().t - history_.front().t < options_.min_history_s) return std::nullopt;
  const double reference = median(history_), recent = median(recent_);
  if (reference < options_.min_reference || !(recent < options_.collapse_ratio * reference)) return std::nullopt;
  return CoverageCollapse{recent, reference};
}

void DepthCoverageWatch::rebase() {
  history_.clear();
  recent_.clear();
}

}  // namespace embedded_calibration_stereo::core
