// ReusableBuffers (the census matcher's buffers kept between calls): a buffer is never held by
// two leases at once, a returned one is reused rather than a new one made, a thread gets back the
// one it returned when that one is free, and the pool never holds more buffers than were leased
// at once (which is the point: thread_local buffers grow with every thread that ever ran).
#include <gtest/gtest.h>

#include <future>
#include <optional>
#include <set>
#include <thread>
#include <vector>

#include "../../src/core/depth/reusable_buffers.h"

namespace embedded_calibration_stereo::core {
namespace {

using Pool = ReusableBuffers<std::vector<int>>;

TEST(ReusableBuffers, LeasesHoldDistinctBuffersAndReturnedOnesAreReused) {
  Pool pool;
  std::set<std::vector<int>*> seen;
  {
    const Pool::Lease a = pool.take(), b = pool.take();
    EXPECT_NE(&*a, &*b);
    a->assign(100, 1);
    seen = {&*a, &*b};
  }
  for (int round = 0; round < 5; ++round) {
    const Pool::Lease a = pool.take(), b = pool.take();
    EXPECT_NE(&*a, &*b);
    EXPECT_TRUE(seen.count(&*a) && seen.count(&*b)) << "round " << round << ": a new buffer was made";
  }
}

TEST(ReusableBuffers, AThreadGetsBackTheBufferItReturned) {
  Pool pool;
  std::vector<int>*first = nullptr, *second = nullptr;
  std::promise<void> returned, go;
  std::optional<Pool::Lease> held(pool.take());  // this thread's buffer
  std::thread other([&] {
    {
      const Pool::Lease lease = pool.take();  // a second buffer: the first is held
      first = &*lease;
    }
    returned.set_value();
    go.get_future().wait();
    const Pool::Lease lease = pool.take();
    second = &*lease;
  });
  returned.get_future().wait();
  held.reset();  // given back last: without the preference, the next take would get it
  go.set_value();
  other.join();
  EXPECT_EQ(second, first) << "the other thread got this thread's buffer rather than its own";
}

TEST(ReusableBuffers, ThreadsTakingTurnsShareOneBuffer) {
  Pool pool;
  std::set<std::vector<int>*> used;
  for (int t = 0; t < 8; ++t)
    std::thread([&] {
      const Pool::Lease lease = pool.take();
      used.insert(&*lease);
    }).join();
  EXPECT_EQ(used.size(), 1u) << "eight threads in turn, one at a time, need one buffer";
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
