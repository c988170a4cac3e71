#pragma once
// Buffers kept between calls of a matcher (fresh pages would cost page faults on every frame),
// shared by the threads that call it or run its pieces: the pool holds as many as were ever in
// use at once, not one per thread that ever ran the code, as thread_local buffers would (a
// nodelet manager's worker threads take turns at a nodelet's callbacks).
//
// Threading: take() and the lease's return are guarded by the pool's mutex; a leased buffer
// belongs to its lease's thread until the lease ends.
#include <cstddef>
#include <memory>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

namespace embedded_calibration_stereo::core {

template <typename Buffer>
class ReusableBuffers {
 public:
  class Lease {
   public:
    Lease(ReusableBuffers* pool, std::unique_ptr<Buffer> buffer) : pool_(pool), buffer_(std::move(buffer)) {}
    Lease(Lease&& other) noexcept : pool_(other.pool_), buffer_(std::move(other.buffer_)) {}
    Lease(const Lease&) = delete;
    Lease& operator=(const Lease&) = delete;
    Lease& operator=(Lease&&) = delete;
    ~Lease() {
      if (buffer_) pool_->giveBack(std::move(buffer_));
    }
    Buffer& operator*() const { return *buffer_; }
    Buffer* operator->() const { return buffer_.get(); }

   private:
    ReusableBuffers* pool_;
    std::unique_ptr<Buffer> buffer_;
  };

  // A buffer no other lease holds: one given back earlier (by this thread if it gave one back:
  // its pages are still in this core's caches), else a new (value-initialised) one.
  Lease take() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (free_.empty()) return Lease(this, std::make_unique<Buffer>());
    size_t pick = free_.size() - 1;
    for (size_t i = 0; i < free_.size(); ++i)
      if (free_[i].last_user == std::this_thread::get_id()) pick = i;
    std::unique_ptr<Buffer> buffer = std::move(free_[pick].buffer);
    free_.erase(free_.begin() + static_cast<std::ptrdiff_t>(pick));
    return Lease(this, std::move(buffer));
  }

 private:
  struct Free {
    std::unique_ptr<Buffer> buffer;
    std::thread::id last_user;
  };
  void giveBack(std::unique_ptr<Buffer> buffer) {
    std::lock_guard<std::mutex> lock(mutex_);
    free_.push_back(Free{std::move(buffer), std::this_thread::get_id()});
  }
  std::mutex mutex_;
  std::vector<Free> free_;
};

}  // namespace embedded_calibration_stereo::core
