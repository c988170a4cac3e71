// releaseFreedMemory (ros/freed_memory.h): what a worker thread frees stays resident until it is
// called, then goes back to the system. The process's resident memory (VmRSS) is the measure.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <thread>
#include <vector>

#include "embedded_calibration_stereo/ros/freed_memory.h"
#include "embedded_calibration_stereo/test_support/process_memory.h"

namespace {

double residentMb() { return embedded_calibration_stereo::test_support::processStatusKb(0, "VmRSS") / 1024.0; }

constexpr size_t kBlock = 64 * 1024;  // below glibc's mmap threshold: from the thread's arena
constexpr int kBlocks = 800;          // 50 MB
constexpr int kKeepEvery = 8;         // every 8th block stays, between the freed ones

}  // namespace

TEST(FreedMemory, WhatAWorkerFreedLeavesTheProcess) {
  ASSERT_GT(residentMb(), 0.0) << "no /proc/self/status";
  std::vector<void*> kept;
  double before = 0.0, freed = 0.0;
  // A worker thread, as the head's: it allocates from an arena of its own.
  std::thread worker([&] {
    before = residentMb();
    std::vector<void*> blocks;
    for (int i = 0; i < kBlocks; ++i) {
      void* block = std::malloc(kBlock);
      ASSERT_NE(block, nullptr);
      std::memset(block, i & 0xff, kBlock);  // resident
      blocks.push_back(block);
    }
    // The kept blocks pin the arena: what lies between them is not its end, which free() alone
    // would give back.
    for (int i = 0; i < kBlocks; ++i) {
      if (i % kKeepEvery == kKeepEvery - 1) {
        kept.push_back(blocks[i]);
      } else {
        std::free(blocks[i]);
      }
    }
    freed = (kBlocks - kept.size()) * kBlock / (1024.0 * 1024.0);
  });
  worker.join();
  const double after_free = residentMb();
  const bool released = embedded_calibration_stereo::releaseFreedMemory();
  const double after_release = residentMb();
  std::printf("resident: %.1f MB before, %.1f MB after freeing %.1f MB, %.1f MB after releaseFreedMemory (%s)\n",
              before, after_free, freed, after_release, released ? "released" : "nothing released");
  // Control: the allocator kept what was freed (otherwise there is nothing to test here).
  EXPECT_GT(after_free - before, 0.8 * freed) << "the allocator already returned the freed blocks";
  EXPECT_TRUE(released);
  EXPECT_LT(after_release - before, 0.25 * freed) << "the freed blocks are still resident";
  for (void* block : kept) std::free(block);
}
