#pragma once
// Helpers of the rostests that look at processes: the pid of a ROS node (asked over its own
// XML-RPC, as rosnode does), whether it still runs, its resident memory, and a command started
// as a child process that the test can kill.
#include <ros/master.h>
#include <ros/this_node.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>
#include <xmlrpcpp/XmlRpcClient.h>

#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

namespace ecs_test {

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
inline long rssKb(int pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  for (std::string line; std::getline(in, line);)
    if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}

// A command run as a child process (stdout and stderr to /dev/null), killed at the end of the
// scope if still running.
class ChildProcess {
 public:
  explicit ChildProcess(std::vector<std::string> argv_strings) {
    std::vector<char*> argv;
    for (std::string& s : argv_strings) argv.push_back(s.data());
    argv.push_back(nullptr);
    pid_ = ::fork();
    if (pid_ == 0) {
      const int null = ::open("/dev/null", O_WRONLY);
      if (null >= 0) {
        ::dup2(null, STDOUT_FILENO);
        ::dup2(null, STDERR_FILENO);
      }
      ::execvp(argv[0], argv.data());
      ::_exit(127);
    }
  }
  ~ChildProcess() { kill(); }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  int pid() const { return pid_; }
  // SIGKILL and reap: the process gets no chance to say goodbye to anyone.
  void kill() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGKILL);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
  }

 private:
  int pid_ = -1;
};

}  // namespace ecs_test
