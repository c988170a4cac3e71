#pragma once
// A ROS service call bounded in time. roscpp's ServiceClient::call() waits for the answer
// without limit: a server that accepts the call and never answers (a hung driver, a proxy in
// between) would hold the caller forever. callService() waits at most `timeout_s` for the
// service to appear and at most `timeout_s` more for its answer.
//
// Threads: the call runs on a thread of its own, detached when the caller stops waiting; it
// ends when the server answers or its connection drops (ros::shutdown() drops them all) and
// touches nothing but its own shared state. At most kMaxCallsInFlight such threads run per
// service: beyond that a call is refused at once (a server that never answers costs a bounded
// number of threads). Any thread may call callService().
#include <ros/node_handle.h>
#include <ros/service_client.h>

#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

namespace embedded_calibration_stereo {

namespace service_call_detail {
constexpr int kMaxCallsInFlight = 4;
// Counts the calls of `service` that have not ended; false (nothing counted) when
// kMaxCallsInFlight already run.
bool reserve(const std::string& service);
void release(const std::string& service);
}  // namespace service_call_detail

// Calls `name` (resolved in `nh`) with `*srv`. True when the server answered in time (its
// answer in `*srv`); otherwise false with `*error` naming the service and saying why: "is not
// available", "did not answer within ... s", "call failed" (the server refused the types or
// dropped the connection), or "has not answered N earlier calls".
template <class S>
bool callService(const ros::NodeHandle& nh, const std::string& name, S* srv, double timeout_s, std::string* error) {
  ros::NodeHandle handle(nh);
  ros::ServiceClient client = handle.serviceClient<S>(name);
  const std::string service = client.getService();
  if (!client.waitForExistence(ros::Duration(timeout_s))) {
    *error = service + " is not available";
    return false;
  }
  struct State {
    std::mutex mutex;
    std::condition_variable done_cv;
    bool done = false, ok = false;
    S srv;
  };
  auto state = std::make_shared<State>();
  state->srv = *srv;
  if (!service_call_detail::reserve(service)) {
    *error = service + " has not answered " + std::to_string(service_call_detail::kMaxCallsInFlight) +
             " earlier calls";
    return false;
  }
  std::thread([state, client, service]() mutable {
    const bool ok = client.call(state->srv);
    {
      std::lock_guard<std::mutex> lock(state->mutex);
      state->done = true;
      state->ok = ok;
    }
    state->done_cv.notify_all();
    service_call_detail::release(service);
  }).detach();
  std::unique_lock<std::mutex> lock(state->mutex);
  if (!state->done_cv.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] { return state->done; })) {
    char text[64];
    std::snprintf(text, sizeof(text), " did not answer within %.1f s", timeout_s);
    *error = service + text;
    return false;
  }
  if (!state->ok) {
    *error = service + " call failed";
    return false;
  }
  *srv = state->srv;
  return true;
}

}  // namespace embedded_calibration_stereo
