#pragma once
// A `roslaunch` started by a rostest node as a child process, on the rostest's master (the
// environment is inherited, but for ROS_NAMESPACE), so that one test can run several launch phases one after the
// other (record, then replay). Its output goes to a log file, shown on failure.
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <future>
#include <sstream>
#include <string>
#include <vector>

namespace ecs_test {

class ChildLaunch {
 public:
  // `args`: what follows `roslaunch` (launch files, arg:=value ...).
  ChildLaunch(const std::vector<std::string>& args, std::string log_path) : log_path_(std::move(log_path)) {
    std::vector<std::string> argv_strings{"roslaunch"};
    argv_strings.insert(argv_strings.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (std::string& s : argv_strings) argv.push_back(s.data());
    argv.push_back(nullptr);
    // The environment without ROS_NAMESPACE: rostest sets it for the test node (ns="..."), and
    // the launch files put their nodes in their own namespace.
    std::vector<std::string> env_strings;
    for (char** e = environ; *e; ++e)
      if (std::string(*e).rfind("ROS_NAMESPACE=", 0) != 0) env_strings.emplace_back(*e);
    std::vector<char*> envp;
    for (std::string& s : env_strings) envp.push_back(s.data());
    envp.push_back(nullptr);
    // Everything the child needs is prepared before fork: it only calls async-signal-safe
    // functions before exec (this process has spinner threads).
    const int log_fd = ::open(log_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
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
  ~ChildLaunch() { stop(20.0); }
  ChildLaunch(const ChildLaunch&) = delete;
  ChildLaunch& operator=(const ChildLaunch&) = delete;

  bool started() const { return pid_ > 0; }
  bool running() const { return exit_.valid() && exit_.wait_for(std::chrono::seconds(0)) != std::future_status::ready; }

  // Ctrl-C (roslaunch then stops its nodes with SIGINT: rosbag record closes its bag), and waits
  // for the exit up to `timeout_s`; SIGKILL after that. True when it exited by itself in time.
  bool stop(double timeout_s) {
    if (!exit_.valid()) return false;
    if (running()) ::kill(pid_, SIGINT);
    const bool in_time = exit_.wait_for(std::chrono::duration<double>(timeout_s)) == std::future_status::ready;
    if (!in_time) ::kill(pid_, SIGKILL);
    exit_.wait();
    exit_ = std::future<int>();
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
  pid_t pid_ = -1;
  std::future<int> exit_;
};

}  // namespace ecs_test
