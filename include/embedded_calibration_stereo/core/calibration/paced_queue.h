#pragma once
// The automatic solves waiting for a calibrator's worker, paced: one starts at the earliest
// `min_interval_s` after the previous one started, and at most `capacity` wait; a newer one
// pushes the oldest out. A solve costs a sizeable fraction of a core; windows arrive every few
// seconds, but a flood from outside (window observations published in a loop) would otherwise
// keep a core busy and take it from depth. With the pacing, solves take at most one per
// min_interval_s of the machine, whatever arrives, and the newest observations are the ones kept.
//
// Threading: not thread-safe; the owner guards it with its own mutex.
#include <deque>
#include <optional>
#include <string>
#include <utility>

namespace embedded_calibration_stereo::core {

struct PacedQueueOptions {
  double min_interval_s = 1.0;  // s between the starts of two solves (>= 0)
  size_t capacity = 2;          // waiting solves (>= 1)
  // Empty when usable; otherwise a message naming the bad field.
  std::string validate() const {
    if (!(min_interval_s >= 0.0)) return "min_interval_s must be >= 0";
    if (capacity < 1) return "capacity must be >= 1";
    return "";
  }
};

template <class T>
class PacedQueue {
 public:
  explicit PacedQueue(PacedQueueOptions options) : options_(options) {}

  // Adds `item`; returns the oldest waiting item when it had to make room (the caller reports it).
  std::optional<T> push(T item) {
    items_.push_back(std::move(item));
    if (items_.size() <= options_.capacity) return std::nullopt;
    std::optional<T> dropped(std::move(items_.front()));
    items_.pop_front();
    return dropped;
  }
  // Seconds from `now` until the next item may start (0: now); negative when none waits.
  double readyIn(double now) const {
    if (items_.empty()) return -1.0;
    if (!last_start_) return 0.0;
    const double ready_at = *last_start_ + options_.min_interval_s;
    return now >= ready_at ? 0.0 : ready_at - now;
  }
  // The next item when one may start at `now` (its start counts from then); nothing otherwise.
  std::optional<T> pop(double now) {
    if (readyIn(now) != 0.0) return std::nullopt;
    std::optional<T> item(std::move(items_.front()));
    items_.pop_front();
    last_start_ = now;
    return item;
  }
  size_t size() const { return items_.size(); }
  void clear() { items_.clear(); }
  const PacedQueueOptions& options() const { return options_; }

 private:
  PacedQueueOptions options_;
  std::deque<T> items_;
  std::optional<double> last_start_;
};

}  // namespace embedded_calibration_stereo::core
