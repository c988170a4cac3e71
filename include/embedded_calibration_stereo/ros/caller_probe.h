#pragma once
// Whether the ROS node that made a service call still runs, so that a long service (the
// calibrator's recalibrate) can stop when its caller went away (killed, Ctrl-C) instead of
// holding the head for the whole request. roscpp does not tell a service callback that its
// client disconnected; every ROS node serves XML-RPC on a port the master knows, and a TCP
// connection to it is refused once the process is gone.
//
// Threads: a probe is used by one thread at a time; probeUri() is thread-safe.
#include <string>

namespace embedded_calibration_stereo {

enum class CallerState {
  kRunning,  // its XML-RPC port accepts connections
  kGone,     // the connection is refused: nothing listens there any more
  kUnknown,  // no way to tell (not a registered node, unreachable host, timeout)
};

// A TCP connection to the host and port of `uri` (http://host:port/), waiting at most
// `timeout_s`.
CallerState probeUri(const std::string& uri, double timeout_s);

class CallerProbe {
 public:
  // Looks the XML-RPC URI of node `caller_id` up on the master (once, without waiting for a
  // master that does not answer).
  explicit CallerProbe(const std::string& caller_id);
  CallerState check(double timeout_s = 0.2) const;
  const std::string& callerId() const { return caller_id_; }

 private:
  std::string caller_id_, uri_;
};

}  // namespace embedded_calibration_stereo
