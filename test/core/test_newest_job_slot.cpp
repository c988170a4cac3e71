// NewestJobSlot (newest_job_slot.h): one job waits for a busy worker, the newest; the worker
// takes it, blocks while none waits, and stops.
#include <gtest/gtest.h>

#include <chrono>
#include <future>

#include "embedded_calibration_stereo/core/tracker/newest_job_slot.h"

namespace embedded_calibration_stereo::core {
namespace {

TEST(NewestJobSlot, ANewerJobReplacesTheOneWaitingWhichIsHandedBack) {
  NewestJobSlot<int> slot;
  EXPECT_FALSE(slot.put(1).has_value());
  const std::optional<int> replaced = slot.put(2);
  ASSERT_TRUE(replaced.has_value());
  EXPECT_EQ(*replaced, 1);
  EXPECT_EQ(slot.take(), std::optional<int>(2));
  EXPECT_FALSE(slot.put(3).has_value());  // taken jobs are not replaced
  EXPECT_EQ(slot.take(), std::optional<int>(3));
}

TEST(NewestJobSlot, TheWorkerWaitsForAJobAndStopsWhenTold) {
  NewestJobSlot<int> slot;
  auto first = std::async(std::launch::async, [&] { return slot.take(); });
  EXPECT_EQ(first.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  slot.put(7);
  EXPECT_EQ(first.get(), std::optional<int>(7));
  auto second = std::async(std::launch::async, [&] { return slot.take(); });
  EXPECT_EQ(second.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  slot.stop();
  EXPECT_EQ(second.get(), std::nullopt);
  EXPECT_EQ(slot.put(8), std::optional<int>(8));  // nobody takes it any more
  EXPECT_EQ(slot.take(), std::nullopt);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
