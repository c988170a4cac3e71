#include "embedded_calibration_stereo/ros/tracker_teaching.h"

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <future>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "embedded_calibration_stereo/core/io/atomic_file.h"
#include "embedded_calibration_stereo/ros/freed_memory.h"

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
TeachOutcome teachBoth(const TeachOne& teach, const core::SimRigConfig& device, const std::string& path) {
  TeachOutcome out;
  const auto t0 = std::chrono::steady_clock::now();
  try {
    const std::vector<core::VirtualBoard> boards = device.device.virtualBoards();
    auto right_result = std::async(std::launch::async, [&] {
      return teach(1, core::BoardLayout::device(boards, device.rig.right, device.rig.right_from_left), "right");
    });
    core::TeachResult left_result;
    try {
      left_result = teach(0, core::BoardLayout::device(boards, device.rig.left, Eigen::Isometry3d::Identity()), "left");
    } catch (...) {
      right_result.wait();  // it references `boards`
      throw;
    }
    const core::TeachResult right_taught = right_result.get();
    out.prior.cameras = {left_result.prior, right_taught.prior};
    for (const core::TeachResult* r : {static_cast<const core::TeachResult*>(&left_result), &right_taught})
      for (const std::string& note : r->notes) out.notes += (out.notes.empty() ? "" : "; ") + note;
  } catch (const std::exception& e) {
    out.error = e.what();
  }
  if (out.error.empty()) out.write_error = writeStereoPrior(path, out.prior);
  out.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace

TeachOutcome teachStereoPrior(const core::TeachFrame& left, const core::TeachFrame& right, core::ColorOrder order,
                              const core::SimRigConfig& device, const std::string& path) {
  const core::TeachFrame* frames[2] = {&left, &right};
  return teachBoth(
      [&](int c, const core::BoardLayout& layout, const std::string& name) {
        return core::teachCamera({*frames[c]}, layout, name, order);
      },
      device, path);
}

TeachOutcome teachStereoPriorFromBurst(const core::WindowFrames& left, const core::WindowFrames& right,
                                       const core::SimRigConfig& device, const std::string& path) {
  const core::WindowFrames* frames[2] = {&left, &right};
  return teachBoth(
      [&](int c, const core::BoardLayout& layout, const std::string& name) {
        cv::Mat taught_on;
        core::TeachResult result =
            core::teachCameraFromWindow(*frames[c], layout, name, core::windowLearnerOptions(), &taught_on);
        // Beside the prior, for whoever brings a head up: what the boards were found on.
        const std::string image_path = taughtOnImagePath(path, name);
        std::vector<uchar> png;
        try {
          createParentDirectories(image_path);
          cv::imencode(".png", taught_on, png);
          core::writeFileAtomically(image_path, std::string(png.begin(), png.end()));
        } catch (const std::exception& e) {
          result.notes.push_back(name + ": " + image_path + " not written (" + e.what() + ")");
        }
        return result;
      },
      device, path);
}

TeachOutcome teachStereoPriorFromBurst(const LightBurst& burst, const core::SimRigConfig& device,
                                       const std::string& path) {
  TeachOutcome out;
  try {
    const core::WindowFrames left = windowFrames(burst, 0), right = windowFrames(burst, 1);
    return teachStereoPriorFromBurst(left, right, device, path);
  } catch (const std::exception& e) {
    out.error = e.what();
  }
  return out;
}

std::string writeStereoPrior(const std::string& path, const core::PatternPrior& prior) {
  try {
    createParentDirectories(path);
    core::writePatternPrior(path, prior);  // atomic
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

TeachingRun::~TeachingRun() {
  if (result_.valid()) result_.wait();
}

void TeachingRun::start(const core::TeachFrame& left, const core::TeachFrame& right, core::ColorOrder order,
                        const core::SimRigConfig& device, const std::string& path) {
  const auto copy = [](const core::TeachFrame& frame) {
    core::TeachFrame out;
    out.light_on = frame.light_on.clone();
    out.light_off = frame.light_off.clone();
    return out;
  };
  result_ = std::async(std::launch::async, [left = copy(left), right = copy(right), order, device, path] {
    TeachOutcome outcome = teachStereoPrior(left, right, order, device, path);
    releaseFreedMemory();  // teaching freed tens of MB
    return outcome;
  });
}

void TeachingRun::start(LightBurst burst, const core::SimRigConfig& device, const std::string& path) {
  result_ = std::async(std::launch::async, [burst = std::move(burst), device, path] {
    TeachOutcome outcome = teachStereoPriorFromBurst(burst, device, path);
    releaseFreedMemory();  // teaching freed tens of MB
    return outcome;
  });
}

std::optional<TeachOutcome> TeachingRun::finished() {
  if (!result_.valid() || result_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return std::nullopt;
  return result_.get();
}

void PriorWriteRetry::taught(const TeachOutcome& outcome, const ros::NodeHandle& nh) {
  const size_t left_boards = outcome.prior.cameras[0].boards.size();
  const size_t right_boards = outcome.prior.cameras[1].boards.size();
  if (outcome.write_error.empty()) {
    prior_.reset();
    ROS_INFO_NAMED(logger_, "PatternTracker: taught %zu + %zu boards in %.0f ms, prior written to %s (%s)", left_boards,
                   right_boards, outcome.ms, path_.c_str(), outcome.notes.c_str());
    return;
  }
  // Tracking needs no file: keep the prior in memory and write it when the disk allows.
  prior_ = outcome.prior;
  error_ = outcome.write_error;
  ROS_ERROR_NAMED(logger_, "PatternTracker: taught %zu + %zu boards in %.0f ms and tracking, but the prior file '%s' "
                  "could not be written (%s); trying again every %.0f s", left_boards, right_boards, outcome.ms,
                  path_.c_str(), error_.c_str(), kRetryS);
  timer_ = nh.createWallTimer(ros::WallDuration(kRetryS), [this](const ros::WallTimerEvent&) { retry(); });
}

void PriorWriteRetry::retry() {
  const std::string error = prior_ ? writeStereoPrior(path_, *prior_) : "";
  if (error.empty()) {
    if (prior_) ROS_INFO_NAMED(logger_, "PatternTracker: prior written to %s (it could not be written when taught)",
                               path_.c_str());
    prior_.reset();
    error_.clear();
    timer_.stop();
    return;
  }
  error_ = error;
  ROS_WARN_THROTTLE_NAMED(60.0, logger_, "PatternTracker: the prior file '%s' still cannot be written (%s); trying "
                          "again every %.0f s", path_.c_str(), error.c_str(), kRetryS);
}

void GroundTruthPairing::subscribe(ros::NodeHandle& nh, std::function<void()> on_scene) {
  for (int c = 0; c < 2; ++c)
    subscribers_[c] = nh.subscribe<sensor_msgs::Image>(
        c == 0 ? "ground_truth/left/image_scene" : "ground_truth/right/image_scene", 5,
        [this, c, on_scene](const sensor_msgs::ImageConstPtr& msg) {
          addScene(c, msg);
          on_scene();
        });
}

void GroundTruthPairing::unsubscribe() {
  if (!subscribed()) return;
  for (ros::Subscriber& sub : subscribers_) sub.shutdown();
  clear();
}

void GroundTruthPairing::addLightOn(const StereoImages& frame) {
  light_on_.push_back(frame);
  while (light_on_.size() > kKept) light_on_.pop_front();
}

void GroundTruthPairing::addScene(int camera, const sensor_msgs::ImageConstPtr& scene) {
  std::deque<sensor_msgs::ImageConstPtr>& q = scenes_[camera];
  q.push_back(scene);
  while (q.size() > kKept) q.pop_front();
}

std::optional<GroundTruthPairing::Match> GroundTruthPairing::newest() const {
  const auto by_stamp = [](const std::deque<sensor_msgs::ImageConstPtr>& q, const ros::Time& stamp) {
    for (const sensor_msgs::ImageConstPtr& m : q)
      if (m->header.stamp == stamp) return m;
    return sensor_msgs::ImageConstPtr();
  };
  for (auto it = light_on_.rbegin(); it != light_on_.rend(); ++it) {
    const ros::Time& stamp = it->first->header.stamp;
    Match match{*it, {by_stamp(scenes_[0], stamp), by_stamp(scenes_[1], stamp)}};
    if (match.scene.first && match.scene.second) return match;
  }
  return std::nullopt;
}

void GroundTruthPairing::clear() {
  light_on_.clear();
  for (auto& q : scenes_) q.clear();
}

std::string defaultPatternPriorFile() {
  const char* ros_home = std::getenv("ROS_HOME");
  const char* home = std::getenv("HOME");
  const std::string dir = ros_home ? ros_home : std::string(home ? home : ".") + "/.ros";
  return dir + "/ecs_pattern_prior.yaml";
}

}  // namespace embedded_calibration_stereo
