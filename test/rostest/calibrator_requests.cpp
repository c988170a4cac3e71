// rostest: the OnlineCalibrator's requests when things go wrong around them, in the sim
// driver's manager. The calibrator's set_light goes through this test (remapped to
// test/set_light), which forwards it to the driver's set_light, refuses it, or is absent; its
// observations come from this test too (test/observations), relayed from the driver's
// ground_truth/observations unchanged or with older, shifted copies replayed in between.
//  - set_light absent, refusing to switch on after acting, refusing to switch off: the call
//    answers false naming set_light, nothing is committed, and the light is switched off
//    where the calibrator can;
//  - a second call while one runs is answered "busy" at once, the first one commits;
//  - the epoch of a commit is the one the driver stamps on the first frame carrying it;
//  - observations whose stamps go back are dropped with a warning naming the topic, and the
//    window of live frames calibrates as if they had not come.
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <std_srvs/SetBool.h>
#include <tf2_msgs/TFMessage.h>

#include <atomic>
#include <deque>
#include <mutex>
#include <thread>

#include "calibrator_test_utils.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::Recalibrate;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;
using sensor_msgs::CameraInfo;

namespace {

enum class Relay { kNone, kForward, kReplayShifted };

// Republishes ground truth on the calibrator's input. kReplayShifted: after each live message,
// the one from two messages earlier again, with its own (older) stamp and every corner moved
// by 3 px: in the window, such a copy would pair a frame with corners it does not have.
class ObservationRelay {
 public:
  explicit ObservationRelay(ros::NodeHandle& nh)
      : pub_(nh.advertise<StereoPatternObservation>("test/observations", 10)),
        sub_(nh.subscribe("ground_truth/observations", 10, &ObservationRelay::relay, this)) {}
  void set(Relay mode) { mode_ = mode; }
  size_t replayed() const { return replayed_; }

 private:
  void relay(const StereoPatternObservation::ConstPtr& msg) {
    const Relay mode = mode_;
    if (mode == Relay::kNone) return;
    pub_.publish(msg);
    history_.push_back(msg);
    if (history_.size() > 3) history_.pop_front();
    if (mode != Relay::kReplayShifted || history_.size() < 3) return;
    StereoPatternObservation old = *history_.front();
    for (auto* side : {&old.left, &old.right})
      for (auto& board : *side)
        for (size_t i = 0; i < board.u.size(); ++i) {
          board.u[i] += 3.0f;
          board.v[i] += 3.0f;
        }
    pub_.publish(old);
    ++replayed_;
  }
  ros::Publisher pub_;
  ros::Subscriber sub_;
  std::atomic<Relay> mode_{Relay::kNone};
  std::deque<StereoPatternObservation::ConstPtr> history_;  // subscriber thread only
  std::atomic<size_t> replayed_{0};
};

enum class Light { kForward, kAbsent, kActThenRefuseOn, kRefuseOff };

// test/set_light, the calibrator's set_light (remapped): forwards to the driver's set_light,
// refuses, or is not advertised at all.
class LightProxy {
 public:
  explicit LightProxy(ros::NodeHandle& nh) : nh_(nh) { advertise(); }
  void set(Light mode) {
    std::lock_guard<std::mutex> lock(mutex_);
    mode_ = mode;
    if (mode == Light::kAbsent) {
      server_.shutdown();
    } else if (!server_) {
      advertise();
    }
  }
  // Requests received (true: on), and whether the driver accepted each forwarded one.
  std::vector<bool> requests() {
    std::lock_guard<std::mutex> lock(mutex_);
    return requests_;
  }
  bool lastForwardAccepted() {
    std::lock_guard<std::mutex> lock(mutex_);
    return last_forward_accepted_;
  }

 private:
  void advertise() { server_ = nh_.advertiseService("test/set_light", &LightProxy::serve, this); }
  bool serve(std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
    Light mode;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      mode = mode_;
      requests_.push_back(req.data);
    }
    if (mode == Light::kRefuseOff && !req.data) {
      res.success = false;
      res.message = "light driver fault (test)";
      return true;
    }
    std_srvs::SetBool forward;
    forward.request.data = req.data;
    const bool accepted = ros::service::call("set_light", forward) && forward.response.success;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      last_forward_accepted_ = accepted;
    }
    res = forward.response;
    if (mode == Light::kActThenRefuseOn && req.data) {
      res.success = false;
      res.message = "light fault after switching (test)";
    }
    return true;
  }
  ros::NodeHandle nh_;
  std::mutex mutex_;
  ros::ServiceServer server_;
  Light mode_ = Light::kForward;
  std::vector<bool> requests_;
  bool last_forward_accepted_ = false;
};

struct Fixture {
  ros::NodeHandle nh;
  ObservationRelay relay{nh};
  LightProxy light{nh};
  Collector<CalibrationMode> modes{nh, "calibration_mode", 5000};
  Collector<CameraInfo> left{nh, "left/camera_info", 5000}, right{nh, "right/camera_info", 5000};
  Collector<CalibrationStatus> status{nh, "calibration/status"};
  Collector<tf2_msgs::TFMessage> tf_static{nh, "/tf_static"};
  Collector<rosgraph_msgs::Log> log{nh, "/rosout", 1000};
};

Fixture* fixture = nullptr;

struct Call {
  Recalibrate srv;
  bool ok = false;
  double elapsed_s = 0.0;
};

Call recalibrate(uint32_t frames, double timeout_s, bool dry_run = false) {
  Call call;
  call.srv.request.frames = frames;
  call.srv.request.timeout_s = timeout_s;
  call.srv.request.dry_run = dry_run;
  const ros::WallTime start = ros::WallTime::now();
  call.ok = ros::service::call("calibration/recalibrate", call.srv);
  call.elapsed_s = (ros::WallTime::now() - start).toSec();
  std::printf("recalibrate: %s in %.2f s: %s\n", call.srv.response.success ? "success" : "false", call.elapsed_s,
              call.srv.response.message.c_str());
  return call;
}

void waitFrames(size_t n) {
  ASSERT_TRUE(fixture->modes.waitForCount(fixture->modes.snapshot().size() + n, 10.0));
}

void setDrift(double focal_scale, double right_rotation_y_deg) {
  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = focal_scale;
  drift.request.right_rotation_deg = {0.0, right_rotation_y_deg, 0.0};
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  waitFrames(2);  // the drifted rig is rendered from here on
}

// The driver's own light switch (the calibrator's goes through the proxy).
void driverLight(bool on) {
  std_srvs::SetBool srv;
  srv.request.data = on;
  ASSERT_TRUE(ros::service::call("set_light", srv));
  ASSERT_TRUE(srv.response.success) << srv.response.message;
}

// What a commit would change: the epoch and calibration the driver publishes, /tf_static, and
// the calibrator's status.
struct InForce {
  uint32_t epoch;
  boost::array<double, 9> left_K, right_K;
  size_t tf_count, status_count;
};

InForce inForce() {
  return {fixture->modes.snapshot().back()->calibration_epoch, fixture->left.snapshot().back()->K,
          fixture->right.snapshot().back()->K, fixture->tf_static.snapshot().size(),
          fixture->status.snapshot().size()};
}

void expectNothingCommitted(const InForce& before) {
  waitFrames(4);  // a commit at the end of the call would be published by now
  const InForce after = inForce();
  EXPECT_EQ(after.epoch, before.epoch);
  EXPECT_EQ(after.left_K, before.left_K);
  EXPECT_EQ(after.right_K, before.right_K);
  EXPECT_EQ(after.tf_count, before.tf_count) << "a transform went on /tf_static";
  const auto statuses = fixture->status.snapshot();
  for (size_t i = before.status_count; i < statuses.size(); ++i)
    EXPECT_FALSE(statuses[i]->accepted) << "an accepted status was published";
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

}  // namespace

TEST(CalibratorRequests, Setup) {
  ASSERT_TRUE(ros::service::waitForService("calibration/recalibrate", 20000));
  ASSERT_TRUE(ros::service::waitForService("set_light", 5000));
  ASSERT_TRUE(fixture->modes.waitForCount(2, 20.0)) << "no calibration_mode from the driver";
  ASSERT_TRUE(fixture->left.waitForCount(1, 5.0));
  ASSERT_TRUE(fixture->right.waitForCount(1, 5.0));
  // The calibration in force at start goes on /tf_static once the calibrator has its pair: before
  // any "nothing went on /tf_static" below counts (it came late once, under load).
  ASSERT_TRUE(fixture->tf_static.waitForCount(1, 10.0)) << "no /tf_static of the calibration in force";
  // A drifted rig: every window solved from here on would be accepted and committed (the
  // busy test below commits one), so that "nothing committed" is not vacuous.
  setDrift(1.05, 0.3);
  fixture->relay.set(Relay::kForward);
}

TEST(CalibratorRequests, AnswersFalseNamingSetLightWhenItIsAbsent) {
  fixture->light.set(Light::kAbsent);
  const InForce before = inForce();
  const Call call = recalibrate(10, 3.0);
  fixture->light.set(Light::kForward);
  ASSERT_TRUE(call.ok);
  EXPECT_FALSE(call.srv.response.success);
  EXPECT_TRUE(contains(call.srv.response.message, "set_light")) << call.srv.response.message;
  EXPECT_TRUE(contains(call.srv.response.message, "not available")) << call.srv.response.message;
  EXPECT_FALSE(call.srv.response.status.accepted);
  // service_timeout_s (2 s) of waiting for the service, once, plus a margin.
  EXPECT_LT(call.elapsed_s, 2.0 + 1.5);
  expectNothingCommitted(before);
}

TEST(CalibratorRequests, SwitchesTheLightOffWhenSetLightRefusesAfterActing) {
  fixture->light.set(Light::kActThenRefuseOn);
  const size_t requests_before = fixture->light.requests().size();
  const InForce before = inForce();
  const Call call = recalibrate(10, 3.0);
  fixture->light.set(Light::kForward);
  ASSERT_TRUE(call.ok);
  EXPECT_FALSE(call.srv.response.success);
  EXPECT_TRUE(contains(call.srv.response.message, "set_light")) << call.srv.response.message;
  EXPECT_TRUE(contains(call.srv.response.message, "light fault after switching (test)")) << call.srv.response.message;
  const std::vector<bool> requests = fixture->light.requests();
  ASSERT_GT(requests.size(), requests_before);
  EXPECT_TRUE(requests[requests_before]) << "the first request was not 'on'";
  // The light is off again: the driver's frames say so (the proxy forwarded both switches).
  const size_t frames_now = fixture->modes.snapshot().size();
  EXPECT_TRUE(fixture->modes.waitFor(
      [&](const auto& m) { return m.size() >= frames_now + 2 && !m.back()->light_on && !m[m.size() - 2]->light_on; },
      3.0))
      << "the light was left on";
  EXPECT_TRUE(fixture->light.lastForwardAccepted());
  expectNothingCommitted(before);
  driverLight(false);  // whatever happened above, the next test starts in the dark
}

TEST(CalibratorRequests, AnswersFalseAndCommitsNothingWhenTheLightCannotBeSwitchedOff) {
  fixture->light.set(Light::kRefuseOff);
  const InForce before = inForce();
  const Call call = recalibrate(10, 3.0);
  fixture->light.set(Light::kForward);
  ASSERT_TRUE(call.ok);
  EXPECT_FALSE(call.srv.response.success);
  EXPECT_TRUE(contains(call.srv.response.message, "set_light")) << call.srv.response.message;
  EXPECT_TRUE(contains(call.srv.response.message, "off")) << call.srv.response.message;
  EXPECT_TRUE(contains(call.srv.response.message, "light driver fault (test)")) << call.srv.response.message;
  EXPECT_FALSE(call.srv.response.status.accepted);
  // Control: the window was collected (the light went on), so a solve would have been possible.
  const auto modes = fixture->modes.snapshot();
  EXPECT_TRUE(std::any_of(modes.begin(), modes.end(), [](const auto& m) { return m->light_on && m->settled; }));
  expectNothingCommitted(before);
  driverLight(false);  // the calibrator could not
  ASSERT_TRUE(fixture->modes.waitFor([](const auto& m) { return !m.back()->light_on; }, 3.0));
}

TEST(CalibratorRequests, ASecondCallIsAnsweredBusyAtOnceAndTheFirstCommitsWithTheDriversEpoch) {
  fixture->light.set(Light::kForward);
  fixture->relay.set(Relay::kForward);
  const InForce before = inForce();
  const size_t requests_before = fixture->light.requests().size();
  std::atomic<bool> first_done{false};
  Call first;
  std::thread runner([&] {
    first = recalibrate(20, 6.0);
    first_done = true;
  });
  // The first call is running: it has switched the light on and frames come in.
  const bool started = fixture->modes.waitFor(
      [&](const auto&) { return fixture->light.requests().size() > requests_before; }, 5.0);
  waitFrames(3);
  const Call second = recalibrate(10, 1.0);
  const bool first_was_running = !first_done;
  runner.join();
  ASSERT_TRUE(started) << "the first call never switched the light on";
  ASSERT_TRUE(second.ok);
  EXPECT_FALSE(second.srv.response.success);
  EXPECT_TRUE(contains(second.srv.response.message, "busy")) << second.srv.response.message;
  EXPECT_LT(second.elapsed_s, 1.0) << "the second call was not answered at once";
  EXPECT_TRUE(first_was_running) << "the second call was answered only after the first one";

  ASSERT_TRUE(first.ok);
  ASSERT_TRUE(first.srv.response.success) << first.srv.response.message;
  EXPECT_EQ(first.srv.response.message, "committed");
  EXPECT_EQ(first.srv.response.status.frames_used, 20u);
  // Only the first call switched the light: on, then off.
  const std::vector<bool> requests = fixture->light.requests();
  EXPECT_EQ(std::vector<bool>(requests.begin() + static_cast<long>(requests_before), requests.end()),
            (std::vector<bool>{true, false}));

  // The epoch reported is the one the driver stamps on the first frame carrying the new
  // calibration (observed here on calibration_mode and camera_info), whatever the driver's
  // rule for counting set_camera_info calls.
  const std::optional<uint32_t> published = test_support::epochPublishedWith(
      first.srv.response.status, fixture->modes, fixture->left, fixture->right);
  ASSERT_TRUE(published) << "the driver never published the committed calibration";
  std::printf("epoch before %u, reported %u, published with the new calibration %u\n", before.epoch,
              first.srv.response.status.epoch, *published);
  EXPECT_NE(*published, before.epoch);
  EXPECT_EQ(first.srv.response.status.epoch, *published);
  ASSERT_TRUE(fixture->status.waitFor([](const auto& m) { return !m.empty() && m.back()->accepted; }, 2.0));
  EXPECT_EQ(fixture->status.snapshot().back()->epoch, *published);
}

TEST(CalibratorRequests, ObservationsWhoseStampsGoBackAreDroppedAndTheWindowStillCalibrates) {
  setDrift(1.02, -0.2);  // another rig than the one just committed: a solve must commit again
  const size_t replayed_before = fixture->relay.replayed();
  fixture->relay.set(Relay::kReplayShifted);
  const Call call = recalibrate(10, 4.0);
  fixture->relay.set(Relay::kForward);
  ASSERT_TRUE(call.ok);
  EXPECT_GT(fixture->relay.replayed(), replayed_before + 5) << "control: nothing was replayed";
  std::string found;
  EXPECT_TRUE(test_support::waitForLog(fixture->log, {"test/observations", "not after the previous one"}, 5.0, &found));
  std::printf("logged: %s\n", found.c_str());
  // The replayed copies, 3 px off, stayed out of the window: the noise-free live frames fit to
  // the solver's tolerance (a copy inside would leave an RMS near a pixel).
  ASSERT_TRUE(call.srv.response.success) << call.srv.response.message;
  const CalibrationStatus& status = call.srv.response.status;
  std::printf("rms %.6f / %.6f px, %u frames\n", status.rms_left_px, status.rms_right_px, status.frames_used);
  EXPECT_EQ(status.frames_used, 10u);
  EXPECT_LT(status.rms_left_px, 0.01);
  EXPECT_LT(status.rms_right_px, 0.01);
  const std::optional<uint32_t> published =
      test_support::epochPublishedWith(status, fixture->modes, fixture->left, fixture->right);
  ASSERT_TRUE(published);
  EXPECT_EQ(status.epoch, *published);

  // A later window of ordinary observations calibrates as usual.
  setDrift(1.04, 0.1);
  const Call later = recalibrate(10, 4.0);
  ASSERT_TRUE(later.ok);
  EXPECT_TRUE(later.srv.response.success) << later.srv.response.message;
  EXPECT_LT(later.srv.response.status.rms_left_px, 0.01);
}

int main(int argc, char** argv) {
  // 3 spinner threads: the light proxy calls the driver from inside its callback
  return test_support::runTestsWithFixture(argc, argv, "calibrator_requests_test", 3, &fixture);
}
