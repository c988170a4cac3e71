#pragma once
// Where the driver's stereo frames come from. One implementation per backend:
//  - sim   (sim_frame_source.cpp): renders core::SimRig, with ground truth;
//  - files (files_frame_source.cpp): replays image pairs or two videos, with an optional CSV
//    of the light state per frame;
//  - v4l2  (v4l2_frame_source.cpp): two V4L2 devices, or one side-by-side device split in halves.
// Construction validates everything it can (paths, devices, sizes) and throws core::ConfigError
// naming the parameter, so that the driver's onInit fails loudly.
//
// Threading: a source is used by one thread at a time (the driver's capture thread).
#include <Eigen/Geometry>
#include <atomic>
#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <string>

#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo {

struct StereoFrame {
  cv::Mat left, right;                 // CV_8UC1 ("mono8") or CV_8UC3 ("bgr8")
  std::string encoding;                // sensor_msgs encoding of left and right
  std::optional<bool> light_on;        // recorded light state (files backend with a CSV)
  std::shared_ptr<const core::SimFrame> truth;  // sim backend only
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // Grabs the next stereo frame taken at `time_s` (seconds since the driver started).
  // Returns false with the reason when no frame can be delivered (end of a non-looping
  // replay, device error).
  virtual bool grab(double time_s, StereoFrame* frame, std::string* error) = 0;
  // True when grab() fills StereoFrame::light_on (a recording): the driver then follows the
  // recorded light state instead of its schedule.
  virtual bool recordsLightState() const { return false; }
  // Image size of each camera, known after construction.
  virtual cv::Size imageSize() const = 0;
};

// Light level in [0, 1] shared between the sim light backend (writer) and the sim source
// (reader); atomic because they may run on different threads.
using SharedLightLevel = std::shared_ptr<std::atomic<double>>;
// The sim light's commanded state, written by the sim light backend and read by the sim source
// so that the simulated rig can model the light's rise and fall (optics.light): 2 * (number of
// switches) + (1 if on), in one atomic so that the pair is always consistent.
using SharedLightCommand = std::shared_ptr<std::atomic<uint64_t>>;

struct FilesSourceParams {
  std::string dir;                         // files_dir: directory of image pairs
  std::string left_glob = "left*";         // files_left_glob
  std::string right_glob = "right*";       // files_right_glob
  std::string left_video, right_video;     // files_left_video / files_right_video (instead of dir)
  std::string light_csv;                   // files_light_csv: "frame,light_on" rows (optional)
  bool loop = true;                        // files_loop
  std::string encoding = "mono8";          // encoding: mono8 or bgr8
};

struct V4l2SourceParams {
  std::string left_device = "/dev/video0";  // v4l2_left_device
  std::string right_device;                 // v4l2_right_device; empty = side-by-side
  int width = 752;                          // v4l2_width: per camera
  int height = 480;                         // v4l2_height
  double fps = 30.0;                        // fps
  std::string encoding = "mono8";           // encoding
};

// Converts a grey or BGR image to "mono8" or "bgr8" (no copy when it already matches).
cv::Mat convertToEncoding(const cv::Mat& image, const std::string& encoding);

// `sim` is shared with the driver, which changes its drift (sim/set_drift) from another
// thread; core::SimRig guards its drift state itself. Frame k (from 0) is rendered at scene time
// k / fps whatever the `time_s` given to grab(): a run is deterministic (core::SimRig::render).
// Throws std::invalid_argument when fps is not > 0.
std::unique_ptr<FrameSource> makeSimFrameSource(std::shared_ptr<core::SimRig> sim,
                                                SharedLightLevel light_level, double fps);
// Same, with the light's command (from makeSimLight with the same object).
std::unique_ptr<FrameSource> makeSimFrameSource(std::shared_ptr<core::SimRig> sim, SharedLightLevel light_level,
                                                SharedLightCommand light_command, double fps);
std::unique_ptr<FrameSource> makeFilesFrameSource(const FilesSourceParams& params);
std::unique_ptr<FrameSource> makeV4l2FrameSource(const V4l2SourceParams& params);

}  // namespace embedded_calibration_stereo
