// rostest: a commit of a calibration pair survives SIGKILL at every step
// (calibration_commit_kill.test).
#include <gtest/gtest.h>
#include <sensor_msgs/SetCameraInfo.h>

#include "calibration_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using embedded_calibration_stereo::CalibrationMode;
using sensor_msgs::CameraInfo;

namespace {

const std::string kNs = "/killed";
constexpr int kHookSteps = 9;  // calibration_file.h: durable steps of a commit

double rectifiedFocal(double fx) { return test_support::pairWithFocal(fx).first.P[0]; }

std::vector<std::string> driverParams(const std::string& dir) {
  return {"_backend:=sim", "_fps:=10.0", "_left_camera_info_url:=file://" + dir + "/left.yaml",
          "_right_camera_info_url:=file://" + dir + "/right.yaml"};
}

// The pair the driver publishes (one stamp), waiting up to `timeout_s`.
bool publishedPair(Collector<CameraInfo>& left, Collector<CameraInfo>& right, CameraInfo* l, CameraInfo* r,
                   double timeout_s) {
  return right.waitFor(
      [&](const auto& rights) {
        for (auto ri = rights.rbegin(); ri != rights.rend(); ++ri)
          for (const auto& li : left.snapshot())
            if (li->header.stamp == (*ri)->header.stamp) {
              *l = *li;
              *r = **ri;
              return true;
            }
        return false;
      },
      timeout_s);
}

bool callSet(const std::string& side, const CameraInfo& info, sensor_msgs::SetCameraInfo* srv) {
  srv->request.camera_info = info;
  return ros::service::call(kNs + "/" + side + "/set_camera_info", *srv);
}

// `kill_at`: 0 = the test kills the driver between the left and the right call; k >= 1 = the
// store's hook kills it after step k of the commit (beyond the last step: no kill).
// `old_fx`, `new_fx`: the pair on disk before, the pair sent. Returns what the files show.
// Files in `base`/cal, driver logs in `base`.
std::pair<double, double> commitAndKill(const std::string& base, int kill_at, double old_fx, double new_fx) {
  const std::string dir = base + "/cal";
  ros::NodeHandle nh(kNs);
  Collector<CameraInfo> left(nh, "left/camera_info", 20), right(nh, "right/camera_info", 20);
  std::vector<std::string> env;
  if (kill_at > 0) env.push_back("ECS_TEST_CRASH_COMMIT_AT=" + std::to_string(kill_at));
  test_support::DriverProcess driver(kNs, driverParams(dir), env, base + "/driver_" + std::to_string(kill_at) + ".log");
  CameraInfo l, r;
  EXPECT_TRUE(publishedPair(left, right, &l, &r, 30.0)) << "the driver did not start\n" << driver.logTail();
  if (old_fx > 0) {
    EXPECT_NEAR(l.P[0], rectifiedFocal(old_fx), 1e-3);
  }
  EXPECT_TRUE(ros::service::waitForService(kNs + "/right/set_camera_info", 10000));

  const auto next = test_support::pairWithFocal(new_fx);
  sensor_msgs::SetCameraInfo srv;
  EXPECT_TRUE(callSet("left", next.first, &srv));
  EXPECT_TRUE(srv.response.success) << srv.response.status_message;
  if (kill_at == 0) {
    driver.kill(SIGKILL);
  } else {
    const bool answered = callSet("right", next.second, &srv);
    if (kill_at > kHookSteps) {
      EXPECT_TRUE(answered && srv.response.success) << srv.response.status_message;
    }
  }
  if (kill_at <= kHookSteps) {
    const int status = driver.waitForExit(20.0);
    EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL)
        << "the driver was not killed at step " << kill_at << " (status " << status << ")\n"
        << driver.logTail();
  }
  return test_support::shownFocals(dir + "/left.yaml", dir + "/right.yaml");
}

// A relaunched driver runs and publishes a consistent pair: the one the files show (`fx` > 0).
void expectRelaunchPublishes(const std::string& base, double fx) {
  const std::string dir = base + "/cal";
  ros::NodeHandle nh(kNs);
  Collector<CameraInfo> left(nh, "left/camera_info", 20), right(nh, "right/camera_info", 20);
  Collector<CalibrationMode> modes(nh, "calibration_mode", 20);
  test_support::DriverProcess driver(kNs, driverParams(dir), {}, base + "/relaunch.log");
  CameraInfo l, r;
  ASSERT_TRUE(publishedPair(left, right, &l, &r, 30.0)) << "the relaunched driver does not run\n" << driver.logTail();
  EXPECT_EQ(test_support::pairProblem(l, r), "");
  if (fx > 0) {
    EXPECT_NEAR(l.P[0], rectifiedFocal(fx), 1e-3);
    EXPECT_NEAR(r.P[0], rectifiedFocal(fx), 1e-3);
  }
  EXPECT_TRUE(modes.waitForCount(3, 10.0)) << "the relaunched driver stopped";
  driver.kill(SIGINT);
  EXPECT_GE(driver.waitForExit(20.0), 0) << "the relaunched driver did not stop";
}

void killAtEveryStep(bool from_regular_files) {
  const double old_fx = 560.0, new_fx = 600.0;
  for (int kill_at = 0; kill_at <= kHookSteps + 1; ++kill_at) {
    SCOPED_TRACE("kill at step " + std::to_string(kill_at));
    const test_support::TempDir temp("ecs_calibration_commit_kill");
    const std::string dir = temp.path + "/cal";
    if (from_regular_files) {
      // What a driver without calibration generations left: two regular files.
      std::string error;
      const auto pair = test_support::pairWithFocal(old_fx);
      ASSERT_TRUE(embedded_calibration_stereo::writeCalibrationFileAtomic(dir + "/left.yaml", "l", pair.first, &error));
      ASSERT_TRUE(
          embedded_calibration_stereo::writeCalibrationFileAtomic(dir + "/right.yaml", "r", pair.second, &error));
    } else {
      // A pair stored by the driver itself.
      ASSERT_NO_FATAL_FAILURE(commitAndKill(temp.path, kHookSteps + 1, 0.0, old_fx));
    }
    const auto shown = commitAndKill(temp.path, kill_at, old_fx, new_fx);
    const bool old_both =
        std::abs(shown.first - rectifiedFocal(old_fx)) < 1e-3 && std::abs(shown.second - rectifiedFocal(old_fx)) < 1e-3;
    const bool new_both =
        std::abs(shown.first - rectifiedFocal(new_fx)) < 1e-3 && std::abs(shown.second - rectifiedFocal(new_fx)) < 1e-3;
    std::printf("  kill at step %d: the files show fx' %.3f / %.3f (%s)\n", kill_at, shown.first, shown.second,
                old_both   ? "old pair"
                : new_both ? "new pair"
                           : "MIXED");
    EXPECT_TRUE(old_both || new_both) << "the files show fx' " << shown.first << " and " << shown.second;
    // The new pair is on disk exactly from the rename of `current` (hook step 8) on.
    if (kill_at > 0) {
      EXPECT_EQ(new_both, kill_at >= 8);
    }
    expectRelaunchPublishes(temp.path, old_both ? old_fx : new_both ? new_fx : -1.0);  // -1: mixed, no pair
  }
}

}  // namespace

TEST(CalibrationCommitKill, FromRegularFiles) { killAtEveryStep(true); }
TEST(CalibrationCommitKill, FromStoredGenerations) { killAtEveryStep(false); }

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "calibration_commit_kill_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
