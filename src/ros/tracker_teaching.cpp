#include "embedded_calibration_stereo/ros/tracker_teaching.h"

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <future>

namespace embedded_calibration_stereo {

TeachOutcome teachStereoPrior(const ecs::TeachFrame& left, const ecs::TeachFrame& right, ecs::ColorOrder order,
                              const ecs::SimRigConfig& device, const std::string& path) {
  TeachOutcome out;
  const auto t0 = std::chrono::steady_clock::now();
  try {
    const std::vector<ecs::VirtualBoard> boards = device.device.virtualBoards();
    auto right_result = std::async(std::launch::async, [&] {
      return ecs::teachCamera({right}, ecs::BoardLayout::device(boards, device.rig.right, device.rig.right_from_left),
                              "right", order);
    });
    ecs::TeachResult left_result;
    try {
      left_result = ecs::teachCamera(
          {left}, ecs::BoardLayout::device(boards, device.rig.left, Eigen::Isometry3d::Identity()), "left", order);
    } catch (...) {
      right_result.wait();  // it references `boards` and `right`
      throw;
    }
    const ecs::TeachResult right_taught = right_result.get();
    out.prior.cameras = {left_result.prior, right_taught.prior};
    for (const ecs::TeachResult* r : {static_cast<const ecs::TeachResult*>(&left_result), &right_taught})
      for (const std::string& note : r->notes) out.notes += (out.notes.empty() ? "" : "; ") + note;
  } catch (const std::exception& e) {
    out.error = e.what();
  }
  if (out.error.empty()) out.write_error = writeStereoPrior(path, out.prior);
  out.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

std::string writeStereoPrior(const std::string& path, const ecs::PatternPrior& prior) {
  try {
    const std::filesystem::path target(path);
    if (target.has_parent_path()) std::filesystem::create_directories(target.parent_path());
    ecs::writePatternPrior(path, prior);  // atomic
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

std::string defaultPatternPriorFile() {
  const char* ros_home = std::getenv("ROS_HOME");
  const char* home = std::getenv("HOME");
  const std::string dir = ros_home ? ros_home : std::string(home ? home : ".") + "/.ros";
  return dir + "/ecs_pattern_prior.yaml";
}

}  // namespace embedded_calibration_stereo
