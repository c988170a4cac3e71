#pragma once
// Teaching step of the PatternTracker nodelet: teaches both cameras of the device from one
// light-on stereo frame (with a light-off frame when available), or from one light burst, and
// stores the prior file atomically, so a reader never sees a half-written prior. Also the glue
// around it: the worker that runs it (TeachingRun), the retries of a prior not written
// (PriorWriteRetry) and the pairing of frames with the simulator's scenes (GroundTruthPairing).
// When to teach and on what is the core TeachingPlan's decision (core/tracker/teaching_plan.h).
//
// Threading: the functions are pure functions of their arguments (called on the nodelet's worker
// thread); the two cameras are taught concurrently. The classes are not thread-safe: each says
// who uses it.
#include <ros/ros.h>
#include <sensor_msgs/Image.h>

#include <cstddef>
#include <deque>
#include <functional>
#include <future>
#include <optional>
#include <string>
#include <utility>

#include "embedded_calibration_stereo/core/tracker/board_teacher.h"
#include "embedded_calibration_stereo/core/tracker/window_teacher.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/ros/light_burst.h"

namespace embedded_calibration_stereo {

// What teaching hands back: a stereo prior (left, right), written to the file unless
// write_error says why not, or an error.
struct TeachOutcome {
  core::PatternPrior prior;
  std::string error;        // empty when taught
  std::string write_error;  // taught, but the file could not be written (a full disk): empty when written
  std::string notes;  // the teacher's notes of both cameras
  double ms = 0.0;    // wall time of teaching and writing
};

// Teaches left and right with the device's virtual boards seen by the nominal cameras of
// `device` (as track_pattern teach --device does), then writes `path` (writeStereoPrior). Never
// throws.
TeachOutcome teachStereoPrior(const core::TeachFrame& left, const core::TeachFrame& right, core::ColorOrder order,
                              const core::SimRigConfig& device, const std::string& path);

// The same from one light burst of each camera (frames in BGR order when in colour): each taught
// on the device image learned from the burst's light pairs (core/tracker/window_teacher.h), no
// covered or still scene needed. The images taught on are written beside the prior
// (taughtOnImagePath; a failure is only noted).
TeachOutcome teachStereoPriorFromBurst(const core::WindowFrames& left, const core::WindowFrames& right,
                                       const core::SimRigConfig& device, const std::string& path);

// The same from a burst's messages (a burst under way has no light-off frame after it); an image
// cv_bridge cannot read is an error. Never throws.
TeachOutcome teachStereoPriorFromBurst(const LightBurst& burst, const core::SimRigConfig& device,
                                       const std::string& path);

// Writes `prior` to `path` through a temporary file in the same directory and a rename
// (creating missing directories). Returns "" on success, otherwise why not. Never throws.
std::string writeStereoPrior(const std::string& path, const core::PatternPrior& prior);

// PRIOR_left_device.png for PRIOR.yaml and camera "left".
std::string taughtOnImagePath(const std::string& prior_path, const std::string& camera_name);

// One teaching at a time on a std::async worker (teaching takes many frame periods), polled by
// its owner's thread, which alone calls it; the destructor waits for a teaching under way.
class TeachingRun {
 public:
  ~TeachingRun();
  // Teaches with teachStereoPrior on copies of the frames' images (the worker outlives the
  // caller's messages).
  void start(const core::TeachFrame& left, const core::TeachFrame& right, core::ColorOrder order,
             const core::SimRigConfig& device, const std::string& path);
  // Teaches with teachStereoPriorFromBurst on the burst's messages (never written).
  void start(LightBurst burst, const core::SimRigConfig& device, const std::string& path);
  // The outcome of the teaching started last, once it finished; nothing while it runs, or
  // when it was already taken.
  std::optional<TeachOutcome> finished();

 private:
  std::future<TeachOutcome> result_;
};

// A prior taught and in use but not written to its file (a full disk, a directory that cannot be
// created): written again every kRetryS on a wall timer of the owner's queue until it is, or
// until a new teaching replaces it. Logs under `logger` (the nodelet's name). The owner's
// callback queue only (its timer runs there); not movable (the timer calls it).
class PriorWriteRetry {
 public:
  static constexpr double kRetryS = 3.0;
  PriorWriteRetry(std::string path, std::string logger) : path_(std::move(path)), logger_(std::move(logger)) {}
  PriorWriteRetry(const PriorWriteRetry&) = delete;
  PriorWriteRetry& operator=(const PriorWriteRetry&) = delete;
  // A prior taught and in use: says so; when it was not written, keeps it and starts the timer
  // on `nh`.
  void taught(const TeachOutcome& outcome, const ros::NodeHandle& nh);
  // A new teaching started: its prior replaces the one waiting.
  void replaced() { prior_.reset(); }
  bool pending() const { return prior_.has_value(); }
  const std::string& error() const { return error_; }  // why it is not written yet

 private:
  void retry();
  const std::string path_, logger_;
  std::optional<core::PatternPrior> prior_;
  std::string error_;
  ros::WallTimer timer_;
};

// Teaching from the simulator's truth (teach_from_ground_truth, tests only): pairs the latest
// settled light-on frames with the ground-truth scenes of the same stamp, which arrive on their
// own topics, before or after them. Not thread-safe (the nodelet's callback queue, where the
// scenes' subscribers run).
class GroundTruthPairing {
 public:
  static constexpr size_t kKept = 5;  // frames kept of each kind while they wait for their match
  struct Match {
    StereoImages light_on, scene;
  };
  // Subscribes ground_truth/left|right/image_scene on `nh`; `on_scene` runs after each scene kept.
  void subscribe(ros::NodeHandle& nh, std::function<void()> on_scene);
  bool subscribed() const { return static_cast<bool>(subscribers_[0]); }
  // Unsubscribes and forgets every frame kept.
  void unsubscribe();
  void addLightOn(const StereoImages& frame);
  // `camera`: 0 left, 1 right.
  void addScene(int camera, const sensor_msgs::ImageConstPtr& scene);
  // The newest light-on frame kept whose two scenes (left and right, of its stamp) came.
  std::optional<Match> newest() const;
  void clear();

 private:
  ros::Subscriber subscribers_[2];
  std::deque<StereoImages> light_on_;
  std::deque<sensor_msgs::ImageConstPtr> scenes_[2];
};

// $ROS_HOME/ecs_pattern_prior.yaml, or ~/.ros/ecs_pattern_prior.yaml without ROS_HOME.
std::string defaultPatternPriorFile();

}  // namespace embedded_calibration_stereo
