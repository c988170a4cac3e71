#pragma once
// Helpers of the rostests that look at processes: the pid of a ROS node (asked over its own
// XML-RPC, as rosnode does), whether it still runs, its resident memory, and commands started
// as child processes (a roslaunch, a nodelet, a rosservice call) that the test can stop or kill.
#include <ros/master.h>
#include <ros/this_node.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>
#include <xmlrpcpp/XmlRpcClient.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <future>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/test_support/process_memory.h"

namespace embedded_calibration_stereo::test_support {

// The pid of node `name` (absolute), or -1.
inline int nodePid(const std::string& name) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = name;
  if (!ros::master::execute("lookupNode", args, result, payload, false)) return -1;
  std::string uri = payload;
  // http://host:port/
  const size_t scheme = uri.find("://");
  const size_t host_start = scheme == std::string::npos ? 0 : scheme + 3;
  const size_t colon = uri.find(':', host_start);
  const size_t slash = uri.find('/', colon);
  if (colon == std::string::npos) return -1;
  const std::string host = uri.substr(host_start, colon - host_start);
  const int port = std::stoi(uri.substr(colon + 1, slash - colon - 1));
  XmlRpc::XmlRpcClient client(host.c_str(), port, "/");
  XmlRpc::XmlRpcValue call_args, call_result;
  call_args[0] = ros::this_node::getName();
  if (!client.execute("getPid", call_args, call_result) || call_result.getType() != XmlRpc::XmlRpcValue::TypeArray ||
      call_result.size() < 3)
    return -1;
  return static_cast<int>(call_result[2]);
}

inline bool processRuns(int pid) { return pid > 0 && ::kill(pid, 0) == 0; }

// VmRSS of `pid` in kB (-1 when unknown).
inline long rssKb(int pid) { return processStatusKb(pid, "VmRSS"); }

// A command run as a child process of the test, on the test's master: the environment is
// inherited but for ROS_NAMESPACE (rostest sets it for the test node, and launch files put their
// nodes in their own namespace), plus `extra_env` ("NAME=value"). Its stdout and stderr go to
// `log_path` (/dev/null when empty), shown on failure by logTail(). The destructor stops it with
// stop(stop_timeout_s): SIGINT first, so a roslaunch stops its nodes and rosbag closes its bag.
class ChildProcess {
 public:
  explicit ChildProcess(std::vector<std::string> argv_strings, std::vector<std::string> extra_env = {},
                        std::string log_path = "", double stop_timeout_s = 0.0)
      : log_path_(std::move(log_path)), stop_timeout_s_(stop_timeout_s) {
    std::vector<char*> argv;
    for (std::string& s : argv_strings) argv.push_back(s.data());
    argv.push_back(nullptr);
    std::vector<std::string> env_strings;
    for (char** e = environ; *e; ++e)
      if (std::string(*e).rfind("ROS_NAMESPACE=", 0) != 0) env_strings.emplace_back(*e);
    env_strings.insert(env_strings.end(), extra_env.begin(), extra_env.end());
    std::vector<char*> envp;
    for (std::string& s : env_strings) envp.push_back(s.data());
    envp.push_back(nullptr);
    // Everything the child needs is prepared before fork: it only calls async-signal-safe
    // functions before exec (this process has spinner threads).
    const std::string out = log_path_.empty() ? "/dev/null" : log_path_;
    const int log_fd = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    pid_ = ::fork();
    if (pid_ == 0) {
      if (log_fd >= 0) {
        ::dup2(log_fd, STDOUT_FILENO);
        ::dup2(log_fd, STDERR_FILENO);
      }
      ::execvpe(argv[0], argv.data(), envp.data());
      ::_exit(127);
    }
    if (log_fd >= 0) ::close(log_fd);
    if (pid_ > 0) {
      const pid_t pid = pid_;
      exit_ = std::async(std::launch::async, [pid] {
        int status = 0;
        return ::waitpid(pid, &status, 0) == pid ? status : -1;
      });
    }
  }
  ~ChildProcess() { stop(stop_timeout_s_); }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  int pid() const { return pid_; }
  bool started() const { return pid_ > 0; }
  bool running() const { return exit_.valid() && exit_.wait_for(std::chrono::seconds(0)) != std::future_status::ready; }

  // Sends `signal`; SIGKILL (the default) also waits until the process is reaped: it gets no
  // chance to say goodbye to anyone.
  void kill(int signal = SIGKILL) {
    if (!running()) return;
    ::kill(pid_, signal);
    if (signal == SIGKILL) waitForExit(60.0);
  }

  // The wait status once it ended within `timeout_s`, else -1.
  int waitForExit(double timeout_s) {
    if (!exit_.valid()) return exit_status_;
    if (exit_.wait_for(std::chrono::duration<double>(timeout_s)) != std::future_status::ready) return -1;
    exit_status_ = exit_.get();
    return exit_status_;
  }

  // SIGINT, then SIGKILL when it has not exited within `timeout_s`. True when it exited by itself
  // in time (or had already exited).
  bool stop(double timeout_s) {
    if (!exit_.valid()) return true;
    if (running()) ::kill(pid_, SIGINT);
    const bool in_time = exit_.wait_for(std::chrono::duration<double>(timeout_s)) == std::future_status::ready;
    if (!in_time) ::kill(pid_, SIGKILL);
    waitForExit(60.0);
    return in_time;
  }

  // The last `lines` lines of the child's output, for failure messages.
  std::string logTail(size_t lines = 30) const {
    std::ifstream in(log_path_);
    std::vector<std::string> all;
    for (std::string line; std::getline(in, line);) all.push_back(line);
    std::ostringstream out;
    out << "---- " << log_path_ << " (last " << lines << " lines) ----\n";
    for (size_t i = all.size() > lines ? all.size() - lines : 0; i < all.size(); ++i)
      out << all[i].substr(0, 400) << "\n";  // progress lines without newline can be huge
    return out.str();
  }

 private:
  std::string log_path_;
  double stop_timeout_s_;
  pid_t pid_ = -1;
  std::future<int> exit_;
  int exit_status_ = -1;
};

}  // namespace embedded_calibration_stereo::test_support
