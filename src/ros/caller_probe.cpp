#include "embedded_calibration_stereo/ros/caller_probe.h"

#include <fcntl.h>
#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>

#include <ros/master.h>
#include <ros/this_node.h>

namespace embedded_calibration_stereo {

CallerState probeUri(const std::string& uri, double timeout_s) {
  // http://host:port/
  const size_t scheme = uri.find("://");
  const size_t host_start = scheme == std::string::npos ? 0 : scheme + 3;
  const size_t colon = uri.find(':', host_start);
  if (colon == std::string::npos) return CallerState::kUnknown;
  const size_t port_end = uri.find('/', colon);
  const std::string host = uri.substr(host_start, colon - host_start);
  const std::string port = uri.substr(colon + 1, port_end == std::string::npos ? std::string::npos : port_end - colon - 1);
  if (host.empty() || port.empty()) return CallerState::kUnknown;

  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  if (getaddrinfo(host.c_str(), port.c_str(), &hints, &found) != 0 || !found) return CallerState::kUnknown;
  CallerState state = CallerState::kUnknown;
  for (addrinfo* a = found; a && state != CallerState::kRunning; a = a->ai_next) {
    const int fd = socket(a->ai_family, a->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    int error = 0;
    if (connect(fd, a->ai_addr, a->ai_addrlen) == 0) {
      state = CallerState::kRunning;
    } else if (errno == EINPROGRESS) {
      pollfd p{fd, POLLOUT, 0};
      const int timeout_ms = static_cast<int>(std::lround(std::max(0.0, timeout_s) * 1000.0));
      if (poll(&p, 1, timeout_ms) == 1) {
        socklen_t length = sizeof(error);
        if (getsockopt(fd, SOL_SOCKET, SO_ERROR, &error, &length) == 0) {
          if (error == 0) state = CallerState::kRunning;
          else if (error == ECONNREFUSED) state = CallerState::kGone;
        }
      }
    } else if (errno == ECONNREFUSED) {
      state = CallerState::kGone;
    }
    close(fd);
  }
  freeaddrinfo(found);
  return state;
}

CallerProbe::CallerProbe(const std::string& caller_id) : caller_id_(caller_id) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = caller_id;
  if (ros::master::execute("lookupNode", args, result, payload, /*wait_for_master=*/false) &&
      payload.getType() == XmlRpc::XmlRpcValue::TypeString)
    uri_ = static_cast<std::string>(payload);
}

CallerState CallerProbe::check(double timeout_s) const {
  return uri_.empty() ? CallerState::kUnknown : probeUri(uri_, timeout_s);
}

}  // namespace embedded_calibration_stereo
