#pragma once
// One job waiting for a busy worker thread, the newest: a job handed over while another still
// waits replaces it (after a change the newest burst is the one that matters), so a worker that
// falls behind never builds a backlog. The PatternTracker's window tracking hands its bursts to
// its worker through it (docs/nodelets.md#patterntracker).
//
// Threading: thread-safe; any number of threads put, one worker takes.
#include <condition_variable>
#include <mutex>
#include <optional>
#include <utility>

namespace embedded_calibration_stereo::core {

template <class Job>
class NewestJobSlot {
 public:
  // Hands `job` over. Returns the job it replaces (handed over before, not taken yet: dropped).
  std::optional<Job> put(Job job) {
    std::optional<Job> replaced;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stopping_) return job;  // nobody will take it
      if (waiting_) replaced = std::move(waiting_);
      waiting_ = std::move(job);
    }
    cv_.notify_all();
    return replaced;
  }

  // Blocks until a job waits, and takes it; nothing once stop() was called.
  std::optional<Job> take() {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait(lock, [this] { return stopping_ || waiting_.has_value(); });
    if (stopping_) return std::nullopt;
    std::optional<Job> job = std::move(waiting_);
    waiting_.reset();
    return job;
  }

  // Wakes the worker for good: take() returns nothing from now on, a job waiting is dropped.
  void stop() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopping_ = true;
      waiting_.reset();
    }
    cv_.notify_all();
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::optional<Job> waiting_;
  bool stopping_ = false;
};

}  // namespace embedded_calibration_stereo::core
