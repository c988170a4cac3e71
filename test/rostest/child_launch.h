#pragma once
// A `roslaunch` started by a rostest node as a child process, on the rostest's master, so that
// one test can run several launch phases one after the other (record, then replay). Its output
// goes to a log file, shown on failure; stop() is Ctrl-C (roslaunch then stops its nodes with
// SIGINT: rosbag record closes its bag).
#include <string>
#include <vector>

#include "process_test_utils.h"

namespace embedded_calibration_stereo::test_support {

class ChildLaunch : public ChildProcess {
 public:
  // `args`: what follows `roslaunch` (launch files, arg:=value ...).
  ChildLaunch(const std::vector<std::string>& args, std::string log_path)
      : ChildProcess(withProgram("roslaunch", args), {}, std::move(log_path), 20.0) {}

 private:
  static std::vector<std::string> withProgram(const std::string& program, const std::vector<std::string>& args) {
    std::vector<std::string> argv{program};
    argv.insert(argv.end(), args.begin(), args.end());
    return argv;
  }
};

}  // namespace embedded_calibration_stereo::test_support
