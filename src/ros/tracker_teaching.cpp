#include "embedded_calibration_stereo/ros/tracker_teaching.h"

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <future>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "embedded_calibration_stereo/core/geometry/atomic_file.h"

namespace embedded_calibration_stereo {

namespace {

// Creates the directories a file at `path` needs. Throws std::filesystem::filesystem_error.
void createParentDirectories(const std::string& path) {
  const std::filesystem::path target(path);
  if (target.has_parent_path()) std::filesystem::create_directories(target.parent_path());
}

// Teaches both cameras concurrently with `teach(camera, layout, name)` (0 left, 1 right) and
// writes the prior.
template <typename TeachOne>
TeachOutcome teachBoth(const TeachOne& teach, const ecs::SimRigConfig& device, const std::string& path) {
  TeachOutcome out;
  const auto t0 = std::chrono::steady_clock::now();
  try {
    const std::vector<ecs::VirtualBoard> boards = device.device.virtualBoards();
    auto right_result = std::async(std::launch::async, [&] {
      return teach(1, ecs::BoardLayout::device(boards, device.rig.right, device.rig.right_from_left), "right");
    });
    ecs::TeachResult left_result;
    try {
      left_result = teach(0, ecs::BoardLayout::device(boards, device.rig.left, Eigen::Isometry3d::Identity()), "left");
    } catch (...) {
      right_result.wait();  // it references `boards`
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

}  // namespace

TeachOutcome teachStereoPrior(const ecs::TeachFrame& left, const ecs::TeachFrame& right, ecs::ColorOrder order,
                              const ecs::SimRigConfig& device, const std::string& path) {
  const ecs::TeachFrame* frames[2] = {&left, &right};
  return teachBoth(
      [&](int c, const ecs::BoardLayout& layout, const std::string& name) {
        return ecs::teachCamera({*frames[c]}, layout, name, order);
      },
      device, path);
}

TeachOutcome teachStereoPriorFromBurst(const ecs::WindowFrames& left, const ecs::WindowFrames& right,
                                       const ecs::SimRigConfig& device, const std::string& path) {
  const ecs::WindowFrames* frames[2] = {&left, &right};
  return teachBoth(
      [&](int c, const ecs::BoardLayout& layout, const std::string& name) {
        cv::Mat taught_on;
        ecs::TeachResult result =
            ecs::teachCameraFromWindow(*frames[c], layout, name, ecs::windowLearnerOptions(), &taught_on);
        // Beside the prior, for whoever brings a head up: what the boards were found on.
        const std::string image_path = taughtOnImagePath(path, name);
        std::vector<uchar> png;
        try {
          createParentDirectories(image_path);
          cv::imencode(".png", taught_on, png);
          ecs::writeFileAtomically(image_path, std::string(png.begin(), png.end()));
        } catch (const std::exception& e) {
          result.notes.push_back(name + ": " + image_path + " not written (" + e.what() + ")");
        }
        return result;
      },
      device, path);
}

std::string writeStereoPrior(const std::string& path, const ecs::PatternPrior& prior) {
  try {
    createParentDirectories(path);
    ecs::writePatternPrior(path, prior);  // atomic
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

std::string taughtOnImagePath(const std::string& prior_path, const std::string& camera_name) {
  std::filesystem::path p(prior_path);
  p.replace_extension();
  return p.string() + "_" + camera_name + "_device.png";
}

std::string defaultPatternPriorFile() {
  const char* ros_home = std::getenv("ROS_HOME");
  const char* home = std::getenv("HOME");
  const std::string dir = ros_home ? ros_home : std::string(home ? home : ".") + "/.ros";
  return dir + "/ecs_pattern_prior.yaml";
}

}  // namespace embedded_calibration_stereo
