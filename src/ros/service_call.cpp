#include "embedded_calibration_stereo/ros/service_call.h"

#include <map>

namespace embedded_calibration_stereo {
namespace service_call_detail {
namespace {

// Never destroyed: a detached call may end while the process exits.
std::mutex& callsMutex() {
  static auto* mutex = new std::mutex;
  return *mutex;
}

// Calls in flight per service (entries at zero are erased).
std::map<std::string, int>& callsInFlight() {
  static auto* calls = new std::map<std::string, int>;
  return *calls;
}

}  // namespace

bool reserve(const std::string& service) {
  std::lock_guard<std::mutex> lock(callsMutex());
  int& calls = callsInFlight()[service];
  if (calls >= kMaxCallsInFlight) return false;
  ++calls;
  return true;
}

void release(const std::string& service) {
  std::lock_guard<std::mutex> lock(callsMutex());
  auto it = callsInFlight().find(service);
  if (it != callsInFlight().end() && --it->second <= 0) callsInFlight().erase(it);
}

}  // namespace service_call_detail
}  // namespace embedded_calibration_stereo
