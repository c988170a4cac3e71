// rostest: a PatternTracker that cannot write its prior file (tracker_prior_retry.test). The
// prior file's directory is blocked by a regular file of that name (as a full disk, the write
// fails; unlike a full disk, this works for root and in any file system). The tracker teaches
// at the second light burst:
//  - it says that the prior could not be written, naming the file, and tracks all the same
//    (observations with boards), where it used to stay idle;
//  - once the blocking file is gone (space freed), the prior is written within the retry
//    period, and it is a stereo prior (two cameras with boards, read with OpenCV's YAML
//    reader), and the tracker keeps tracking.
#include <gtest/gtest.h>
#include <opencv2/core/persistence.hpp>

#include <filesystem>
#include <fstream>

#include "child_launch.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;

namespace {

bool withBoards(const std::vector<StereoPatternObservation::ConstPtr>& m, size_t from) {
  for (size_t i = from; i < m.size(); ++i)
    if (!m[i]->left.empty() && !m[i]->right.empty()) return true;
  return false;
}

}  // namespace

TEST(TrackerPriorRetry, APriorThatCouldNotBeWrittenIsUsedAndWrittenOnceItCanBe) {
  ros::NodeHandle nh;
  Collector<CalibrationMode> modes(nh, "calibration_mode", 2000);
  Collector<StereoPatternObservation> observations(nh, "calibration/observations", 2000);
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 2000);
  ASSERT_TRUE(modes.waitForCount(2, 20.0)) << "no frames from the driver";

  test_support::TempDir dir("ecs_tracker_prior_retry");
  ASSERT_FALSE(dir.path.empty());
  const std::string blocker = dir.path + "/blocked";
  std::ofstream(blocker) << "a file where the prior's directory should be\n";
  const std::string prior = blocker + "/pattern_prior.yaml";
  test_support::ChildLaunch tracker({"embedded_calibration_stereo", "tracker.launch", "prior_file:=" + prior},
                                dir.path + "/tracker_launch.log");
  ASSERT_TRUE(tracker.started());

  // Teaching happens at the second burst (the first has no light-off frame before it).
  std::string found;
  ASSERT_TRUE(test_support::waitForLog(log, {"could not be written", prior}, 30.0, &found)) << tracker.logTail();
  std::printf("logged: %s\n", found.c_str());
  EXPECT_TRUE(observations.waitFor([](const auto& m) { return withBoards(m, 0); }, 10.0))
      << "the tracker does not track with the prior it could not write";
  EXPECT_FALSE(std::filesystem::exists(prior));

  // Space freed: the prior is written within the retry period (3 s) and a margin.
  std::filesystem::remove(blocker);
  const ros::WallTime freed = ros::WallTime::now();
  ASSERT_TRUE(test_support::waitForLog(log, {"prior written to", prior}, 10.0, &found)) << tracker.logTail();
  std::printf("written %.1f s after the space was freed; logged: %s\n", (ros::WallTime::now() - freed).toSec(),
              found.c_str());
  ASSERT_TRUE(std::filesystem::exists(prior));
  cv::FileStorage fs(prior, cv::FileStorage::READ);
  ASSERT_TRUE(fs.isOpened());
  const cv::FileNode cameras = fs["cameras"];
  ASSERT_EQ(cameras.size(), 2u);
  for (const cv::FileNode& camera : cameras) EXPECT_GT(camera["boards"].size(), 0u);
  // Still tracking.
  const size_t seen = observations.snapshot().size();
  EXPECT_TRUE(observations.waitFor([seen](const auto& m) { return withBoards(m, seen); }, 10.0));
  tracker.stop(10.0);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "tracker_prior_retry_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
