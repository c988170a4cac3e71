#pragma once
// Helpers shared by the driver's rostest nodes: collect messages of a topic and wait on a
// condition over them with a deadline (never a fixed sleep as synchronisation), load the
// driver nodelet in-process, and call services (calibration/recalibrate among them).
#include <gtest/gtest.h>
#include <nodelet/loader.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>

#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/Recalibrate.h"

namespace embedded_calibration_stereo::test_support {

template <class M>
class Collector {
 public:
  using Ptr = typename M::ConstPtr;
  Collector(ros::NodeHandle& nh, const std::string& topic, uint32_t queue = 100) {
    sub_ = nh.subscribe<M>(topic, queue, [this](const Ptr& msg) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        messages_.push_back(msg);
      }
      cv_.notify_all();
    });
  }
  // The subscription ends before the members its callback touches are destroyed: the spinner
  // threads may be delivering a message right now (shutdown waits for that callback).
  ~Collector() { sub_.shutdown(); }
  Collector(const Collector&) = delete;
  Collector& operator=(const Collector&) = delete;
  // Waits until `done(messages)` holds; false on timeout.
  bool waitFor(const std::function<bool(const std::vector<Ptr>&)>& done, double timeout_s) {
    std::unique_lock<std::mutex> lock(mutex_);
    return cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] { return done(messages_); });
  }
  bool waitForCount(size_t n, double timeout_s) {
    return waitFor([n](const std::vector<Ptr>& m) { return m.size() >= n; }, timeout_s);
  }
  std::vector<Ptr> snapshot() {
    std::lock_guard<std::mutex> lock(mutex_);
    return messages_;
  }
  void clear() {
    std::lock_guard<std::mutex> lock(mutex_);
    messages_.clear();
  }

 private:
  ros::Subscriber sub_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<Ptr> messages_;
};

// Waits for a /rosout message containing every string of `needles`.
inline bool waitForLog(Collector<rosgraph_msgs::Log>& log, const std::vector<std::string>& needles,
                       double timeout_s, std::string* found = nullptr) {
  return log.waitFor(
      [&](const std::vector<rosgraph_msgs::Log::ConstPtr>& messages) {
        for (const auto& m : messages) {
          bool all = true;
          for (const auto& n : needles) all = all && m->msg.find(n) != std::string::npos;
          if (all) {
            if (found) *found = m->msg;
            return true;
          }
        }
        return false;
      },
      timeout_s);
}

inline std::string makeTempDir(const std::string& prefix) {
  std::string pattern = "/tmp/" + prefix + "_XXXXXX";
  std::vector<char> name(pattern.begin(), pattern.end());
  name.push_back('\0');
  return mkdtemp(name.data()) ? std::string(name.data()) : std::string();
}

// A temporary directory removed with everything in it at the end of the scope.
struct TempDir {
  explicit TempDir(const std::string& prefix) : path(makeTempDir(prefix)) {}
  ~TempDir() {
    if (!path.empty()) std::filesystem::remove_all(path);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string path;
};

constexpr const char* kDriverType = "embedded_calibration_stereo/CameraDriver";

// Loads driver nodelets (or others: `type`) into this process (the test's own nodelet manager).
class InProcessManager {
 public:
  using Params = std::map<std::string, XmlRpc::XmlRpcValue>;
  // Sets the private parameters of `name` and loads the nodelet; false when onInit failed.
  bool load(const std::string& name, const Params& params, const std::string& type = kDriverType,
            const ros::M_string& remappings = {}) {
    ros::param::del(name);
    for (const auto& p : params) ros::param::set(name + "/" + p.first, p.second);
    return loader_.load(name, type, remappings, std::vector<std::string>());
  }
  bool unload(const std::string& name) { return loader_.unload(name); }

 private:
  nodelet::Loader loader_{false};
};

// Polls `done` every 10 ms until it holds; false after timeout_s. For states no message
// announces: publisher connections, the master's lists.
inline bool waitUntil(const std::function<bool()>& done, double timeout_s) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(timeout_s);
  while (!done()) {
    if (ros::WallTime::now() > deadline) return false;
    ros::WallDuration(0.01).sleep();
  }
  return true;
}

// The main() of a rostest node whose tests share one Fixture: its subscriptions and clients are
// made once, after ros::init, and `*fixture` points to it while the tests run; spinner_threads
// serve its callbacks.
template <class Fixture>
int runTestsWithFixture(int argc, char** argv, const char* node_name, int spinner_threads, Fixture** fixture) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, node_name);
  ros::AsyncSpinner spinner(spinner_threads);
  spinner.start();
  Fixture f;
  *fixture = &f;
  const int result = RUN_ALL_TESTS();
  *fixture = nullptr;
  return result;
}

// The camera_info pair of one stamp (the newest one both sides have).
inline bool latestPair(Collector<sensor_msgs::CameraInfo>& left, Collector<sensor_msgs::CameraInfo>& right,
                       sensor_msgs::CameraInfo* l, sensor_msgs::CameraInfo* r) {
  const auto lefts = left.snapshot(), rights = right.snapshot();
  for (auto it = lefts.rbegin(); it != lefts.rend(); ++it)
    for (const auto& candidate : rights)
      if (candidate->header.stamp == (*it)->header.stamp) {
        *l = **it;
        *r = *candidate;
        return true;
      }
  return false;
}

// Calls `name` once it is advertised (waiting at most wait_s); false when it never is or the call fails.
template <class Srv>
bool callService(const std::string& name, Srv* srv, double wait_s = 10.0) {
  return ros::service::waitForService(name, ros::Duration(wait_s)) && ros::service::call(name, *srv);
}

// Forces a recalibration of `frames` frames through /stereo/calibration/recalibrate (timeout_s
// for the calibrator) and prints its answer after `what`. False when the service was not reached.
inline bool recalibrate(int frames, double timeout_s, const std::string& what, Recalibrate* call,
                        double wait_s = 10.0) {
  call->request.frames = frames;
  call->request.timeout_s = timeout_s;
  if (!callService("/stereo/calibration/recalibrate", call, wait_s)) return false;
  std::printf("recalibrate %s: success %d, '%s'\n", what.c_str(), call->response.success,
              call->response.message.c_str());
  return true;
}

}  // namespace embedded_calibration_stereo::test_support
