#pragma once
// Watches what depth users see: the fraction of pixels with a valid disparity, against its own
// recent history. A calibration can keep rows aligned and disparity unbiased and still leave
// depth empty (a principal point shifted in both cameras alike moves the rectified images out
// of view), which neither the scene rows nor the boards reveal. A collapse of the valid fraction
// does.
//
// The reference is the median of the fractions of the last `history_s` before any collapse;
// the recent level is the median over the last `recent_s`. A collapse: the recent level below
// `collapse_ratio` x the reference, once the reference spans `min_history_s` and is at least
// `min_reference`. Fractions taken during a collapse are not learned, so a collapse lasts until
// depth recovers or the owner rebases (the scene really changed: a calibrator confirmed the
// calibration in force).
//
// Threading: not thread-safe; one owner thread calls every method.
#include <deque>
#include <optional>
#include <string>

namespace embedded_calibration_stereo::core {

struct DepthCoverageWatchOptions {
  double recent_s = 2.0;        // the recent level: median over this span (s)
  double history_s = 60.0;      // the reference: median over this span (s)
  double min_history_s = 10.0;  // no verdict until the reference spans this (s)
  double collapse_ratio = 0.5;  // recent < ratio x reference: a collapse
  double min_reference = 0.05;  // a reference below this (a view with little depth): no verdict
  // Empty when usable; otherwise a message naming the bad field.
  std::string validate() const;
};

struct CoverageCollapse {
  double recent = 0.0;     // valid fraction now (median over recent_s)
  double reference = 0.0;  // valid fraction before (median over history_s)
  std::string text() const;  // e.g. "valid disparity on 3 % of the image against 61 % before"
};

class DepthCoverageWatch {
 public:
  // Throws std::invalid_argument when options.validate() fails.
  explicit DepthCoverageWatch(DepthCoverageWatchOptions options);

  // The valid fraction (0..1) of the disparity image of time t (s). Times go forward; a time
  // before the latest one (a replayed bag starting again) starts the history again.
  void add(double t, double valid_fraction);
  // A collapse as of the latest time given, or none.
  std::optional<CoverageCollapse> collapse() const;
  // Accepts the current level: the history starts again from now.
  void rebase();
  const DepthCoverageWatchOptions& options() const { return options_; }

 private:
  struct Sample {
    double t, fraction;
  };
  static double median(const std::deque<Sample>& samples);  // of a non-empty deque

  DepthCoverageWatchOptions options_;
  std::deque<Sample> recent_;   // every sample of the last recent_s
  std::deque<Sample> history_;  // samples not taken during a collapse, history_s up to the newest
};

}  // namespace embedded_calibration_stereo::core
