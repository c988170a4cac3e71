// PacedQueue (the calibrator's automatic solves): the times at which items start, and which are
// dropped, written out by hand from the options for each scenario.
#include <gtest/gtest.h>

#include <vector>

#include "embedded_calibration_stereo/core/calibration/paced_queue.h"

namespace core = embedded_calibration_stereo::core;

namespace {

// A worker that takes every item as soon as one may start, `solve_s` each, while items
// arrive at `arrivals` (s): the start time of each item taken, and the items dropped.
struct Outcome {
  std::vector<std::pair<int, double>> started;  // item, start time
  std::vector<int> dropped;
};

Outcome simulate(core::PacedQueueOptions options, const std::vector<double>& arrivals, double solve_s, double until) {
  core::PacedQueue<int> queue(options);
  Outcome run;
  size_t next = 0;
  double busy_until = 0.0;
  for (double t = 0.0; t <= until + 1e-9; t += 0.01) {
    while (next < arrivals.size() && arrivals[next] <= t + 1e-9) {
      if (auto dropped = queue.push(static_cast<int>(next))) run.dropped.push_back(*dropped);
      ++next;
    }
    if (t + 1e-9 < busy_until) continue;
    if (auto item = queue.pop(t)) {
      run.started.push_back({*item, t});
      busy_until = t + solve_s;
    }
  }
  return run;
}

}  // namespace

TEST(PacedQueue, WindowsFarApartStartAsTheyCome) {
  // A window every 4 s, solved in 0.3 s: nothing waits, nothing is dropped.
  const Outcome run = simulate({1.0, 2}, {0.5, 4.5, 8.5}, 0.3, 10.0);
  ASSERT_EQ(run.started.size(), 3u);
  EXPECT_NEAR(run.started[0].second, 0.5, 0.011);
  EXPECT_NEAR(run.started[1].second, 4.5, 0.011);
  EXPECT_NEAR(run.started[2].second, 8.5, 0.011);
  EXPECT_TRUE(run.dropped.empty());
}

TEST(PacedQueue, AFloodIsSolvedAtMostOncePerIntervalKeepingTheNewest) {
  // 100 observations in 1 s (a flood), then nothing: solves start 1 s apart; while the flood
  // lasts only the two newest wait.
  std::vector<double> arrivals;
  for (int i = 0; i < 100; ++i) arrivals.push_back(0.01 * i);
  const Outcome run = simulate({1.0, 2}, arrivals, 0.26, 5.0);
  // Item 0 starts at once (0.0 s); at 1.0 s the two newest of those that came are waiting (98, 99).
  ASSERT_EQ(run.started.size(), 3u);
  EXPECT_EQ(run.started[0].first, 0);
  EXPECT_NEAR(run.started[0].second, 0.0, 0.011);
  EXPECT_EQ(run.started[1].first, 98);
  EXPECT_NEAR(run.started[1].second, 1.0, 0.011);
  EXPECT_EQ(run.started[2].first, 99);
  EXPECT_NEAR(run.started[2].second, 2.0, 0.011);
  EXPECT_EQ(run.dropped.size(), 97u);
  EXPECT_EQ(run.dropped.front(), 1) << "the oldest is dropped first";
}

TEST(PacedQueue, ReadyInSaysHowLongTheNextWaits) {
  core::PacedQueue<int> queue({2.0, 3});
  EXPECT_LT(queue.readyIn(0.0), 0.0) << "nothing waits";
  queue.push(1);
  EXPECT_EQ(queue.readyIn(10.0), 0.0) << "the first starts at once";
  ASSERT_TRUE(queue.pop(10.0).has_value());
  queue.push(2);
  EXPECT_NEAR(queue.readyIn(10.5), 1.5, 1e-12);
  EXPECT_FALSE(queue.pop(11.9).has_value());
  EXPECT_EQ(queue.pop(12.0).value_or(-1), 2);
}

TEST(PacedQueue, OptionsAreChecked) {
  EXPECT_EQ(core::PacedQueueOptions{}.validate(), "");
  EXPECT_NE(core::PacedQueueOptions({-1.0, 2}).validate(), "");
  EXPECT_NE(core::PacedQueueOptions({1.0, 0}).validate(), "");
}
