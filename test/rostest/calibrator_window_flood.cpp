// rostest: a flood of window observations (calibrator_window_flood.test). Each one is a solve of
// a sizeable fraction of a core; solved as fast as they came, a flood took depth from about
// 20 Hz to 10-16 Hz. Now automatic solves start at least min_solve_interval_s (1 s) apart and at
// most solve_queue_size wait (the oldest dropped with a warning): at most one solve starts per
// second of the flood (without the pacing: 39 in 8 s, the worker busy all along). The pacing is
// what this test checks: disparity's rate during the flood is printed, not asserted, since on a
// loaded machine it measures the machine as much as the head (bench/pipeline measures speed).
// The observations are the simulator's ground truth of each frame, republished as they come,
// with 1500 scene correspondences as a whole-burst observation carries (points of the truth's
// rectified images at random disparities, unrectified with the truth's cameras: a solve costs
// what a real window's does): valid, each stamped after the previous one, as a tracker gone
// wild would send them.
#include <gtest/gtest.h>
#include <image_geometry/stereo_camera_model.h>
#include <sensor_msgs/CameraInfo.h>
#include <stereo_msgs/DisparityImage.h>

#include <atomic>
#include <cstdio>
#include <mutex>
#include <random>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/SceneMatch.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;

namespace {

constexpr int kSceneMatches = 1500;

// `observation` with kSceneMatches correspondences of the truth's cameras.
StereoPatternObservation withScene(const StereoPatternObservation& observation,
                                   const image_geometry::StereoCameraModel& truth, std::mt19937* random) {
  StereoPatternObservation out = observation;
  const double width = truth.left().fullResolution().width, height = truth.left().fullResolution().height;
  std::uniform_real_distribution<double> u(0.15 * width, 0.85 * width), v(0.15 * height, 0.85 * height),
      disparity(4.0, 60.0);
  for (int i = 0; i < kSceneMatches; ++i) {
    const cv::Point2d left_rect(u(*random), v(*random));
    const cv::Point2d right_rect(left_rect.x - disparity(*random), left_rect.y);
    const cv::Point2d left = truth.left().unrectifyPoint(left_rect), right = truth.right().unrectifyPoint(right_rect);
    embedded_calibration_stereo::SceneMatch match;
    match.left_u = left.x;
    match.left_v = left.y;
    match.right_u = right.x;
    match.right_v = right.y;
    out.scene.push_back(match);
  }
  return out;
}

struct Fixture {
  ros::NodeHandle nh;
  std::atomic<uint64_t> disparity{0};
  std::atomic<bool> flooding{false};
  std::atomic<uint64_t> sent{0};
  ros::Publisher window_pub = nh.advertise<StereoPatternObservation>("calibration/window_observations", 30);
  ros::Subscriber disparity_sub = nh.subscribe<stereo_msgs::DisparityImage>(
      "disparity", 30, [this](const stereo_msgs::DisparityImageConstPtr&) { ++disparity; });
  std::mutex mutex;  // guards truth_left, truth_right, random
  sensor_msgs::CameraInfoConstPtr truth_left, truth_right;
  std::mt19937 random{3};
  ros::Subscriber truth_left_sub = nh.subscribe<sensor_msgs::CameraInfo>(
      "ground_truth/left/camera_info", 2, [this](const sensor_msgs::CameraInfoConstPtr& info) {
        std::lock_guard<std::mutex> lock(mutex);
        truth_left = info;
      });
  ros::Subscriber truth_right_sub = nh.subscribe<sensor_msgs::CameraInfo>(
      "ground_truth/right/camera_info", 2, [this](const sensor_msgs::CameraInfoConstPtr& info) {
        std::lock_guard<std::mutex> lock(mutex);
        truth_right = info;
      });
  // Every frame's ground truth goes on as a window observation while flooding.
  ros::Subscriber truth_sub = nh.subscribe<StereoPatternObservation>(
      "ground_truth/observations", 30, [this](const StereoPatternObservation::ConstPtr& o) {
        if (!flooding) return;
        std::lock_guard<std::mutex> lock(mutex);
        if (!truth_left || !truth_right) return;
        image_geometry::StereoCameraModel truth;
        truth.fromCameraInfo(truth_left, truth_right);
        window_pub.publish(withScene(*o, truth, &random));
        ++sent;
      });
  Collector<CalibrationStatus> status{nh, "calibration/status", 1000};
  Collector<rosgraph_msgs::Log> log{nh, "/rosout", 2000};
};

Fixture* fixture = nullptr;

double disparityRate(double seconds) {
  const uint64_t before = fixture->disparity.load();
  const ros::WallTime start = ros::WallTime::now();
  ros::WallDuration(seconds).sleep();  // counting messages over a span of time, not synchronising
  return (fixture->disparity.load() - before) / (ros::WallTime::now() - start).toSec();
}

}  // namespace

TEST(CalibratorWindowFlood, DisparityKeepsItsRateAndTheDroppedSolvesAreNamed) {
  ASSERT_TRUE(test_support::waitUntil([] { return fixture->disparity.load() > 15; }, 40.0)) << "no disparity";
  ASSERT_TRUE(test_support::waitUntil([] { return fixture->window_pub.getNumSubscribers() > 0; }, 10.0))
      << "the calibrator does not subscribe to calibration/window_observations";
  const double without = disparityRate(4.0);
  fixture->flooding = true;
  const double with = disparityRate(8.0);
  fixture->flooding = false;
  ros::WallDuration(2.0).sleep();  // the solves started during the flood end
  const size_t solved = fixture->status.snapshot().size();
  std::printf("%llu window observations in 8 s; %zu solved by 2 s after; disparity %.1f Hz during the flood, "
              "%.1f Hz in the 4 s before\n",
              static_cast<unsigned long long>(fixture->sent.load()), solved, with, without);
  // Starts 1 s apart: at 0, 1, ..., 10 s at the most in the flood's 8 s and the 2 s after.
  EXPECT_LE(solved, 11u) << "automatic solves started faster than min_solve_interval_s";
  EXPECT_GT(fixture->sent.load(), 120u) << "control: the flood";
  EXPECT_GT(without, 10.0) << "control: disparity";
  EXPECT_GT(with, 0.0) << "disparity stopped during the flood";
  std::string found;
  EXPECT_TRUE(test_support::waitForLog(fixture->log, {"window observation dropped unsolved", "min_solve_interval_s"}, 5.0,
                                   &found));
  std::printf("logged: %s\n", found.c_str());
  EXPECT_GE(solved, 3u) << "the flood's observations are still solved, paced";
}

int main(int argc, char** argv) {
  return test_support::runTestsWithFixture(argc, argv, "calibrator_window_flood_test", 3, &fixture);
}
