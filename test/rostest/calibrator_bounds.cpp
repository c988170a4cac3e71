// rostest: calibration/recalibrate answers within bounds whatever it is asked, and the
// calibrator counts one frame per stamp (calibrator_bounds.test). The calibrator's set_light
// goes through this test's proxy (test/set_light: forwards to the driver, or never answers) and
// its observations through this test's relay (test/observations: the driver's ground truth, or
// each frame followed by copies under its stamp).
//  - timeout_s inf, -inf or NaN: refused at once, the light untouched;
//  - frames 4e9 and timeout_s 1e9: limited to max_frames and max_request_timeout_s, answered,
//    the answer says so, the light off afterwards;
//  - a set_light that never answers: the request answers within the service timeouts;
//  - five concurrent calls: one runs, four are answered "busy" at once naming who holds it;
//  - a caller killed during its request: the request ends, the light goes off, the window
//    stays within max_frames, and automatic calibration resumes;
//  - observations repeated under one stamp, 2 % off: counted once (the window holds the live
//    frames only);
//  - an automatic window that stops growing (the light held on) ends after window_timeout_s,
//    saying why, and is solved.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <std_srvs/SetBool.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <limits>
#include <memory>
#include <mutex>
#include <thread>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "process_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::Recalibrate;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;
using sensor_msgs::CameraInfo;

namespace {

constexpr int kMaxFrames = 30;             // the launch file's max_frames
constexpr double kMaxTimeoutS = 8.0;       // its max_request_timeout_s
constexpr double kServiceTimeoutS = 2.0;   // the calibrator's default service_timeout_s
constexpr double kPeriodS = 6.0;           // the driver's calibration_period_s

enum class Relay { kForward, kDuplicates };

// The driver's ground truth on the calibrator's input. kDuplicates: after each live message,
// nine copies under its stamp with every corner moved 2 % away from the principal point (a
// frame of a 2 % zoom).
class ObservationRelay {
 public:
  explicit ObservationRelay(ros::NodeHandle& nh)
      : pub_(nh.advertise<StereoPatternObservation>("test/observations", 100)),
        sub_(nh.subscribe("ground_truth/observations", 10, &ObservationRelay::relay, this)) {}
  void set(Relay mode) { mode_ = mode; }
  void setCentre(double cx, double cy) {
    cx_ = cx;
    cy_ = cy;
  }
  size_t copies() const { return copies_; }

 private:
  void relay(const StereoPatternObservation::ConstPtr& msg) {
    pub_.publish(msg);
    if (mode_ != Relay::kDuplicates) return;
    StereoPatternObservation copy = *msg;
    for (auto* side : {&copy.left, &copy.right})
      for (auto& board : *side)
        for (size_t i = 0; i < board.u.size(); ++i) {
          board.u[i] = static_cast<float>(cx_ + 1.02 * (board.u[i] - cx_));
          board.v[i] = static_cast<float>(cy_ + 1.02 * (board.v[i] - cy_));
        }
    for (int i = 0; i < 9; ++i) pub_.publish(copy);
    copies_ += 9;
  }
  ros::Publisher pub_;
  ros::Subscriber sub_;
  std::atomic<Relay> mode_{Relay::kForward};
  std::atomic<double> cx_{376.0}, cy_{240.0};
  std::atomic<size_t> copies_{0};
};

enum class Light { kForward, kHang };

// test/set_light: forwards to the driver's set_light, or holds every call unanswered until
// release() (then answers false without forwarding).
class LightProxy {
 public:
  explicit LightProxy(ros::NodeHandle& nh) : server_(nh.advertiseService("test/set_light", &LightProxy::serve, this)) {}
  void set(Light mode) {
    std::lock_guard<std::mutex> lock(mutex_);
    mode_ = mode;
  }
  void release() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      released_ = true;
      mode_ = Light::kForward;
    }
    cv_.notify_all();
  }
  std::vector<bool> requests() {
    std::lock_guard<std::mutex> lock(mutex_);
    return requests_;
  }
  // Waits for a request `on` after the first `after` requests.
  bool waitForRequest(size_t after, bool on, double timeout_s) {
    std::unique_lock<std::mutex> lock(mutex_);
    return cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] {
      for (size_t i = after; i < requests_.size(); ++i)
        if (requests_[i] == on) return true;
      return false;
    });
  }

 private:
  bool serve(std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
    {
      std::unique_lock<std::mutex> lock(mutex_);
      requests_.push_back(req.data);
      cv_.notify_all();
      if (mode_ == Light::kHang) {
        released_ = false;
        cv_.wait_for(lock, std::chrono::seconds(30), [this] { return released_; });
        res.success = false;
        res.message = "released by the test";
        return true;
      }
    }
    std_srvs::SetBool forward;
    forward.request.data = req.data;
    const bool ok = ros::service::call("set_light", forward);
    res = forward.response;
    if (!ok) {
      res.success = false;
      res.message = "the driver's set_light failed";
    }
    return true;
  }
  std::mutex mutex_;
  std::condition_variable cv_;
  Light mode_ = Light::kForward;
  bool released_ = false;
  std::vector<bool> requests_;
  ros::ServiceServer server_;
};

// The largest "frames in window" the calibrator's diagnostics reported since clear().
class WindowSize {
 public:
  explicit WindowSize(ros::NodeHandle& nh) : sub_(nh.subscribe("/diagnostics", 50, &WindowSize::add, this)) {}
  ~WindowSize() { sub_.shutdown(); }
  void clear() {
    std::lock_guard<std::mutex> lock(mutex_);
    largest_ = -1;
    reports_ = 0;
  }
  long largest() {
    std::lock_guard<std::mutex> lock(mutex_);
    return largest_;
  }
  int reports() {
    std::lock_guard<std::mutex> lock(mutex_);
    return reports_;
  }

 private:
  void add(const diagnostic_msgs::DiagnosticArray::ConstPtr& msg) {
    for (const auto& status : msg->status) {
      if (status.name.find("online_calibrator") == std::string::npos) continue;
      for (const auto& kv : status.values) {
        if (kv.key != "frames in window") continue;
        std::lock_guard<std::mutex> lock(mutex_);
        largest_ = std::max(largest_, std::stol(kv.value));
        ++reports_;
      }
    }
  }
  ros::Subscriber sub_;
  std::mutex mutex_;
  long largest_ = -1;
  int reports_ = 0;
};

struct Fixture {
  ros::NodeHandle nh;
  ObservationRelay relay{nh};
  LightProxy light{nh};
  WindowSize window{nh};
  Collector<CalibrationMode> modes{nh, "calibration_mode", 5000};
  Collector<CameraInfo> truth{nh, "ground_truth/left/camera_info", 10};
  Collector<CalibrationStatus> status{nh, "calibration/status"};
  Collector<rosgraph_msgs::Log> log{nh, "/rosout", 2000};
};

Fixture* fixture = nullptr;

// A recalibrate call on its own thread, which the test may stop waiting for (a call that never
// returns must fail the test, not hang it).
class AsyncCall {
 public:
  AsyncCall(uint32_t frames, double timeout_s) : state_(std::make_shared<State>()) {
    state_->srv.request.frames = frames;
    state_->srv.request.timeout_s = timeout_s;
    state_->start = ros::WallTime::now();
    std::thread([state = state_] {
      Recalibrate srv = state->srv;
      const bool ok = ros::service::call("calibration/recalibrate", srv);
      std::lock_guard<std::mutex> lock(state->mutex);
      state->srv = srv;
      state->ok = ok;
      state->elapsed_s = (ros::WallTime::now() - state->start).toSec();
      state->done = true;
      state->cv.notify_all();
    }).detach();
  }
  // True when answered within `timeout_s`.
  bool wait(double timeout_s) {
    std::unique_lock<std::mutex> lock(state_->mutex);
    const bool done = state_->cv.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] { return state_->done; });
    if (done)
      std::printf("recalibrate(%u, %g): %s in %.2f s: %s\n", state_->srv.request.frames, state_->srv.request.timeout_s,
                  state_->srv.response.success ? "success" : "false", state_->elapsed_s,
                  state_->srv.response.message.c_str());
    return done;
  }
  bool ok() const { return state_->ok; }
  double elapsed() const { return state_->elapsed_s; }
  const Recalibrate::Response& response() const { return state_->srv.response; }

 private:
  struct State {
    std::mutex mutex;
    std::condition_variable cv;
    Recalibrate srv;
    ros::WallTime start;
    bool done = false, ok = false;
    double elapsed_s = 0.0;
  };
  std::shared_ptr<State> state_;
};

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }
bool isBusy(const Recalibrate::Response& r) { return contains(r.message, "busy"); }

// Waits until the driver's last `n` frames all have the light off.
bool lightOffFor(size_t n, double timeout_s) {
  return fixture->modes.waitFor(
      [n](const auto& m) {
        if (m.size() < n) return false;
        for (size_t i = m.size() - n; i < m.size(); ++i)
          if (m[i]->light_on) return false;
        return true;
      },
      timeout_s);
}

}  // namespace

TEST(CalibratorBounds, Setup) {
  ASSERT_TRUE(ros::service::waitForService("calibration/recalibrate", 20000));
  ASSERT_TRUE(ros::service::waitForService("set_light", 5000));
  ASSERT_TRUE(fixture->modes.waitForCount(2, 20.0)) << "no calibration_mode from the driver";
  ASSERT_TRUE(fixture->truth.waitForCount(1, 5.0));
  const auto truth = fixture->truth.snapshot().back();
  fixture->relay.setCentre(truth->K[2], truth->K[5]);
}

TEST(CalibratorBounds, NonFiniteTimeoutsAreRefusedAtOnceWithoutTouchingTheLight) {
  const size_t requests_before = fixture->light.requests().size();
  for (double timeout_s : {std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                           std::numeric_limits<double>::quiet_NaN()}) {
    AsyncCall call(10, timeout_s);
    ASSERT_TRUE(call.wait(10.0)) << "no answer to timeout_s " << timeout_s;
    ASSERT_TRUE(call.ok());
    EXPECT_FALSE(call.response().success);
    EXPECT_TRUE(contains(call.response().message, "timeout_s must be a finite number")) << call.response().message;
    EXPECT_LT(call.elapsed(), 1.0);
  }
  EXPECT_EQ(fixture->light.requests().size(), requests_before) << "set_light was called";
}

TEST(CalibratorBounds, HugeFramesAndTimeoutAreLimitedAnsweredAndTheLightIsOffAfterwards) {
  const size_t requests_before = fixture->light.requests().size();
  fixture->window.clear();
  AsyncCall call(4000000000u, 1e9);
  // Within max_request_timeout_s, the solve and the service calls, with a margin.
  ASSERT_TRUE(call.wait(kMaxTimeoutS + 4 * kServiceTimeoutS + 5.0)) << "recalibrate(4e9, 1e9) never answered";
  ASSERT_TRUE(call.ok());
  const Recalibrate::Response& r = call.response();
  EXPECT_TRUE(contains(r.message, "limited to 30 (max_frames)")) << r.message;
  EXPECT_TRUE(contains(r.message, "limited to 8 s (max_request_timeout_s)")) << r.message;
  // The window was solved with max_frames frames (the gate may reject it: nothing to correct).
  EXPECT_EQ(r.status.frames_used, static_cast<uint32_t>(kMaxFrames)) << r.message;
  EXPECT_LE(fixture->window.largest(), kMaxFrames);
  const std::vector<bool> requests = fixture->light.requests();
  EXPECT_EQ(std::vector<bool>(requests.begin() + static_cast<long>(requests_before), requests.end()),
            (std::vector<bool>{true, false}));
  EXPECT_TRUE(lightOffFor(5, 5.0)) << "the light stayed on";
}

TEST(CalibratorBounds, ASetLightThatNeverAnswersCostsTheServiceTimeoutsOnly) {
  const size_t statuses_before = fixture->status.snapshot().size();
  fixture->light.set(Light::kHang);
  AsyncCall call(10, 3.0);
  // On: service_timeout_s; off (tried all the same): service_timeout_s; plus a margin.
  const bool answered = call.wait(2 * kServiceTimeoutS + 3.0);
  fixture->light.release();
  ASSERT_TRUE(answered) << "recalibrate waited for a set_light that never answers";
  ASSERT_TRUE(call.ok());
  EXPECT_FALSE(call.response().success);
  EXPECT_TRUE(contains(call.response().message, "did not answer within 2.0 s")) << call.response().message;
  EXPECT_TRUE(contains(call.response().message, "nothing solved or committed")) << call.response().message;
  const auto statuses = fixture->status.snapshot();
  for (size_t i = statuses_before; i < statuses.size(); ++i) EXPECT_FALSE(statuses[i]->accepted);
}

TEST(CalibratorBounds, OfFiveConcurrentCallsOneRunsAndFourAreToldAtOnceWhoHoldsIt) {
  ASSERT_TRUE(lightOffFor(2, 5.0));
  const size_t requests_before = fixture->light.requests().size();
  std::vector<std::unique_ptr<AsyncCall>> calls;
  for (int i = 0; i < 5; ++i) calls.push_back(std::make_unique<AsyncCall>(10, 6.0));
  int busy = 0, ran = 0;
  for (auto& call : calls) {
    ASSERT_TRUE(call->wait(6.0 + 4 * kServiceTimeoutS + 5.0)) << "a call never answered";
    ASSERT_TRUE(call->ok());
    if (isBusy(call->response())) {
      ++busy;
      EXPECT_LT(call->elapsed(), 1.0) << "a busy answer was not given at once";
      EXPECT_TRUE(contains(call->response().message, "requested by " + ros::this_node::getName()))
          << call->response().message;
    } else {
      ++ran;
      EXPECT_EQ(call->response().status.frames_used, 10u) << call->response().message;
    }
  }
  EXPECT_EQ(ran, 1);
  EXPECT_EQ(busy, 4);
  const std::vector<bool> requests = fixture->light.requests();
  EXPECT_EQ(std::vector<bool>(requests.begin() + static_cast<long>(requests_before), requests.end()),
            (std::vector<bool>{true, false}));
  EXPECT_TRUE(lightOffFor(5, 5.0)) << "the light stayed on";
  // The next call is served.
  AsyncCall next(5, 4.0);
  ASSERT_TRUE(next.wait(4.0 + 4 * kServiceTimeoutS + 5.0));
  EXPECT_FALSE(isBusy(next.response())) << next.response().message;
}

TEST(CalibratorBounds, AKilledCallerEndsItsRequestTheLightGoesOffAndAutomaticCalibrationResumes) {
  ASSERT_TRUE(lightOffFor(2, 5.0));
  const int manager = test_support::nodePid("/stereo/stereo_manager");
  ASSERT_GT(manager, 0) << "cannot find the manager's pid";
  const size_t requests_before = fixture->light.requests().size();
  const test_support::TempDir temp("ecs_calibrator_bounds_client");
  test_support::ChildProcess client({"rosservice", "call", "--wait", "/stereo/calibration/recalibrate",
                                 "{frames: 4000000000, timeout_s: 1000000000.0, dry_run: false}"},
                                {}, temp.path + "/rosservice.log");
  ASSERT_TRUE(fixture->light.waitForRequest(requests_before, true, 20.0))
      << "the client's request never started (rosservice " << (client.running() ? "still runs" : "ended")
      << "), it printed:\n" << client.logTail();
  // Who holds the calibrator: the rosservice client's node.
  AsyncCall second(5, 2.0);
  ASSERT_TRUE(second.wait(3.0));
  EXPECT_TRUE(isBusy(second.response())) << second.response().message;
  EXPECT_TRUE(contains(second.response().message, "rosservice")) << second.response().message;

  const long rss_before = test_support::rssKb(manager);
  const size_t statuses_before = fixture->status.snapshot().size();
  const size_t requests_at_kill = fixture->light.requests().size();
  fixture->window.clear();
  client.kill();
  const ros::WallTime killed = ros::WallTime::now();
  // The calibrator notices (it probes its caller every 0.5 s) and switches the light off.
  ASSERT_TRUE(fixture->light.waitForRequest(requests_at_kill, false, 3.0 + kServiceTimeoutS))
      << "the light was not switched off after the caller was killed";
  std::printf("light switched off %.2f s after the kill\n", (ros::WallTime::now() - killed).toSec());
  EXPECT_TRUE(lightOffFor(5, 5.0)) << "the light stayed on";
  std::string found;
  EXPECT_TRUE(test_support::waitForLog(fixture->log, {"went away", "rosservice"}, 5.0, &found));
  std::printf("logged: %s\n", found.c_str());
  // Automatic calibration resumes: the next burst of the driver's schedule is solved.
  EXPECT_TRUE(fixture->status.waitForCount(statuses_before + 1, 2 * kPeriodS + 5.0))
      << "no automatic calibration after the killed request";
  const long rss_after = test_support::rssKb(manager);
  std::printf("manager RSS %ld kB at the kill, %ld kB %.1f s later; largest window %ld frames (%d reports)\n",
              rss_before, rss_after, (ros::WallTime::now() - killed).toSec(), fixture->window.largest(),
              fixture->window.reports());
  EXPECT_GT(fixture->window.reports(), 0) << "control: no diagnostics from the calibrator";
  EXPECT_LE(fixture->window.largest(), kMaxFrames);
  EXPECT_TRUE(test_support::processRuns(manager));
  // And the calibrator serves the next request.
  AsyncCall next(5, 4.0);
  ASSERT_TRUE(next.wait(4.0 + 4 * kServiceTimeoutS + 5.0));
  EXPECT_FALSE(isBusy(next.response())) << next.response().message;
}

TEST(CalibratorBounds, ObservationsRepeatedUnderOneStampAreCountedOnce) {
  ASSERT_TRUE(lightOffFor(2, 5.0));
  const auto truth = fixture->truth.snapshot().back();
  const size_t copies_before = fixture->relay.copies();
  fixture->relay.set(Relay::kDuplicates);
  AsyncCall call(10, 6.0);
  const bool answered = call.wait(6.0 + 4 * kServiceTimeoutS + 5.0);
  fixture->relay.set(Relay::kForward);
  ASSERT_TRUE(answered);
  ASSERT_TRUE(call.ok());
  EXPECT_GE(fixture->relay.copies(), copies_before + 9 * 5) << "control: no copies were sent";
  std::string found;
  EXPECT_TRUE(test_support::waitForLog(fixture->log, {"test/observations", "not after the previous one"}, 5.0, &found));
  std::printf("logged: %s\n", found.c_str());
  // Ten live frames, none of the copies: the noise-free truth fits to the solver's tolerance and
  // the focal length is the truth's (copies inside would leave pixels of RMS or pull it 2 %).
  const CalibrationStatus& status = call.response().status;
  ASSERT_EQ(status.left_intrinsics.size() >= 4 && status.right_intrinsics.size() >= 4, true)
      << call.response().message;
  std::printf("frames %u, rms %.6f / %.6f px, fx %.4f (truth %.4f)\n", status.frames_used, status.rms_left_px,
              status.rms_right_px, status.left_intrinsics[0], truth->K[0]);
  EXPECT_EQ(status.frames_used, 10u);
  EXPECT_LT(status.rms_left_px, 0.01);
  EXPECT_LT(status.rms_right_px, 0.01);
  EXPECT_NEAR(status.left_intrinsics[0], truth->K[0], 1e-4 * truth->K[0]);
}

TEST(CalibratorBounds, AnAutomaticWindowThatStopsGrowingEndsWithAReason) {
  // The light held on by the driver's own set_light: the window fills to max_frames and then
  // receives nothing more; it never closes by the light going off.
  ASSERT_TRUE(lightOffFor(2, 5.0));
  // The window's status is the first whose newest frame came after the light went on (a solve
  // of an earlier test may still publish its status meanwhile).
  const ros::Time light_on = ros::Time::now();
  const auto window_status = [&light_on](const auto& statuses) {
    return std::find_if(statuses.begin(), statuses.end(), [&](const auto& s) { return s->newest_frame > light_on; });
  };
  std_srvs::SetBool on;
  on.request.data = true;
  ASSERT_TRUE(ros::service::call("set_light", on) && on.response.success);
  std::string found;
  // max_frames at 15 fps, then window_timeout_s (5 s), with a margin.
  const bool ended = test_support::waitForLog(fixture->log, {"calibration window ended", "window_timeout_s", "solving"},
                                          kMaxFrames / 15.0 + 5.0 + 5.0, &found);
  const bool solved = fixture->status.waitFor(
      [&](const auto& statuses) { return window_status(statuses) != statuses.end(); }, 5.0);
  std_srvs::SetBool off;
  off.request.data = false;
  ASSERT_TRUE(ros::service::call("set_light", off) && off.response.success);
  ASSERT_TRUE(ended) << "the window never ended with the light held on";
  std::printf("logged: %s\n", found.c_str());
  ASSERT_TRUE(solved);
  const auto statuses = fixture->status.snapshot();
  EXPECT_EQ((*window_status(statuses))->frames_used, static_cast<uint32_t>(kMaxFrames));
  EXPECT_TRUE(lightOffFor(5, 5.0));
}

int main(int argc, char** argv) {
  // 6 spinner threads: the proxy holds threads while it hangs or forwards
  return test_support::runTestsWithFixture(argc, argv, "calibrator_bounds_test", 6, &fixture);
}
