// rostest: a scenario bag made by render_scenario_bag (20 s, a light window every 5 s) replays
// through launch/replay.launch without errors.
//
// The test node renders the bag at test time (timed and printed), then starts replay.launch on
// the rostest's master as a child roslaunch (ChildLaunch) and follows the replay to the bag's
// end. It checks, from the bag's own calibration_mode (the windows it holds):
//  - the PatternTracker publishes observations in the last window (the window at 0 s has no
//    light-off frame before it, the next one teaches the tracker; on a moving scenario a window
//    can also be lost: the tracker subtracts the light-off frame before the window, a
//    static-world assumption that the scenario is there to measure);
//  - the OnlineCalibrator publishes one calibration/status per tracked window, each a solve of
//    at least min_frames (5) frames;
//  - Disparity produces frames for at least half the bag's images;
//  - /rosout holds no ERROR or FATAL from the nodelet manager of the replay (our nodelets) nor
//    from rosbag play, while it does hold the nodelets' INFO messages (the log pipe works).
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <rosgraph_msgs/Clock.h>
#include <rosgraph_msgs/Log.h>
#include <stereo_msgs/DisparityImage.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>

#include "child_launch.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/test_support/run_command.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::ChildLaunch;
using test_support::Collector;

namespace {

constexpr double kSeconds = 20.0;
constexpr double kPeriodS = 5.0;
constexpr double kFps = 15.0;  // half the driver's default: half the rendering and the bag
constexpr double kStart = 1000.0;  // stamp of the bag's first frame
const std::string kManager = "/stereo/stereo_manager";

std::string launchFile(const std::string& name) { return std::string(ECS_SOURCE_DIR) + "/launch/" + name; }

// Exit status and output (stdout and stderr).
int run(const std::string& command, std::string* output) { return core::runCommand(command + " 2>&1", output); }

// Light windows of the bag: the stamps of their first and last light-on frames.
struct Window {
  ros::Time first, last;
};

// Renders the scenario's bag to `bag_path`.
void renderBag(const std::string& scenario, const std::string& bag_path) {
  const auto render_start = std::chrono::steady_clock::now();
  std::string output;
  const int status = run(std::string(ECS_RENDER_SCENARIO_BAG) + " --config " + scenario + " --out " + bag_path +
                             " --seconds " + std::to_string(kSeconds) + " --fps " + std::to_string(kFps) +
                             " --period " + std::to_string(kPeriodS) + " --start " + std::to_string(kStart),
                         &output);
  const double render_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - render_start).count();
  ASSERT_EQ(status, 0) << output;
  std::printf("%s", output.c_str());
  std::printf("rendered %.0f s of %s in %.1f s wall\n", kSeconds, std::filesystem::path(scenario).filename().c_str(),
              render_s);
}

// The bag's light windows, left images and last calibration_mode stamp.
struct BagWindows {
  std::vector<Window> windows;
  size_t left_images = 0;
  ros::Time end;
};

BagWindows readWindows(const std::string& bag_path) {
  BagWindows out;
  rosbag::Bag bag(bag_path, rosbag::bagmode::Read);
  out.left_images = rosbag::View(bag, rosbag::TopicQuery("/stereo/left/image_raw")).size();
  bool on = false;
  for (const rosbag::MessageInstance& m : rosbag::View(bag, rosbag::TopicQuery("/stereo/calibration_mode"))) {
    const auto mode = m.instantiate<CalibrationMode>();
    EXPECT_TRUE(mode);
    if (!mode) continue;
    if (mode->light_on && !on) out.windows.push_back({mode->header.stamp, mode->header.stamp});
    if (mode->light_on) out.windows.back().last = mode->header.stamp;
    on = mode->light_on;
    out.end = mode->header.stamp;
  }
  return out;
}

// One calibration/status per window the tracker followed (at least 5 observations), the last
// window among them, each status a solve.
void expectEveryTrackedWindowSolved(const std::vector<Window>& windows,
                                    const std::vector<StereoPatternObservation::ConstPtr>& observed,
                                    const std::vector<CalibrationStatus::ConstPtr>& solved) {
  // Observations per window (by stamp).
  std::vector<size_t> per_window(windows.size(), 0);
  for (const auto& o : observed)
    for (size_t w = 0; w < windows.size(); ++w)
      if (o->header.stamp >= windows[w].first && o->header.stamp <= windows[w].last) ++per_window[w];
  for (size_t w = 0; w < windows.size(); ++w)
    std::printf("window %zu at %.2f s: %zu tracker observations\n", w, (windows[w].first.toSec() - kStart),
                per_window[w]);
  for (const auto& s : solved)
    std::printf("calibration/status: %s, %u frames, rms %.3f/%.3f px: %s\n", s->accepted ? "accepted" : "rejected",
                s->frames_used, s->rms_left_px, s->rms_right_px, s->reason.c_str());

  std::string table;
  size_t tracked = 0;
  for (size_t w = 0; w < windows.size(); ++w) {
    table += "window " + std::to_string(w) + ": " + std::to_string(per_window[w]) + " observations\n";
    tracked += per_window[w] >= 5u;
  }
  for (const auto& s : solved) table += "status: " + std::to_string(s->frames_used) + " frames, " + s->reason + "\n";
  EXPECT_GE(per_window.back(), 5u) << "the last window is not tracked\n" << table;
  EXPECT_EQ(solved.size(), tracked) << "not one calibration/status per tracked window\n" << table;
  for (const auto& s : solved) EXPECT_GE(s->frames_used, 5u) << "a status without a solve: " << s->reason;
}

// No error on /rosout from the manager or the player, and INFO from the manager (else the check
// would be vacuous).
void expectNoErrorsLogged(const std::vector<rosgraph_msgs::Log::ConstPtr>& messages) {
  // ---- /rosout --------------------------------------------------------------------------
  size_t manager_info = 0;
  for (const auto& m : messages) {
    const bool ours = m->name == kManager;
    const bool player = m->name.rfind("/play", 0) == 0;
    if (ours && m->level == rosgraph_msgs::Log::INFO) ++manager_info;
    if ((ours || player) && m->level >= rosgraph_msgs::Log::ERROR)
      ADD_FAILURE() << m->name << " logged an error: " << m->msg;
  }
  EXPECT_GE(manager_info, 1u) << "no INFO from " << kManager << " on /rosout: the error check would be vacuous";
}

}  // namespace

TEST(ScenarioBag, ReplaysThroughTheGraphWithoutErrors) {
  ros::NodeHandle nh;
  std::string scenario;
  ASSERT_TRUE(ros::param::get("~scenario", scenario));
  test_support::TempDir dir("ecs_scenario_bag_test");
  ASSERT_FALSE(dir.path.empty());
  const std::string bag_path = dir.path + "/scenario.bag";

  // ---- The bag --------------------------------------------------------------------------
  renderBag(scenario, bag_path);
  if (HasFatalFailure()) return;
  const BagWindows bag = readWindows(bag_path);
  const std::vector<Window>& windows = bag.windows;
  const size_t left_images = bag.left_images;
  const ros::Time bag_end = bag.end;
  ASSERT_EQ(windows.size(), static_cast<size_t>(kSeconds / kPeriodS)) << "light windows in the bag";
  ASSERT_EQ(left_images, static_cast<size_t>(kSeconds * kFps));

  // ---- The replay -----------------------------------------------------------------------
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 5000);
  Collector<StereoPatternObservation> observations(nh, "calibration/observations", 1000);
  Collector<CalibrationStatus> statuses(nh, "calibration/status");
  Collector<stereo_msgs::DisparityImage> disparity(nh, "disparity", 5);
  Collector<rosgraph_msgs::Clock> clock(nh, "/clock", 5000);
  ChildLaunch replay({launchFile("replay.launch"), "bag:=" + bag_path,
                      "prior_file:=" + dir.path + "/pattern_prior.yaml"},
                     dir.path + "/replay.log");
  ASSERT_TRUE(replay.started());
  const ros::Time nearly_end = bag_end - ros::Duration(0.2);
  ASSERT_TRUE(clock.waitFor([&](const auto& m) { return !m.empty() && m.back()->clock >= nearly_end; },
                            kSeconds + 40.0))
      << "the bag did not play to its end\n" << replay.logTail();
  // The last window ends 5 s before the bag does: its status is out long before.
  const auto observed = observations.snapshot();
  const auto solved = statuses.snapshot();
  const size_t disparity_frames = disparity.snapshot().size();
  EXPECT_TRUE(replay.stop(20.0)) << "replay.launch did not stop in time";

  expectEveryTrackedWindowSolved(windows, observed, solved);
  std::printf("disparity: %zu frames for %zu left images\n", disparity_frames, left_images);
  EXPECT_GE(disparity_frames, left_images / 2) << "disparity did not keep up with the replay";
  expectNoErrorsLogged(log.snapshot());
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "scenario_bag_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
