#pragma once
// Teaching the pattern tracker from one light burst, on a moving head (ROS-free).
//
// Teaching needs the boards without the scene. Covering the scene (or a still scene and a
// light-off frame) is a factory step; a head that moves has neither. One burst is enough: the
// device image I_C learned from its light pairs (learnWindowDevice, as the window tracker learns
// it) is what stays put while the scene moves, the boards, in the light-on frames' grey levels.
// It is searched as a light-on frame with no scene (teachCamera), so the taught contrast is the
// one the tracker later meets in light-on frames.
//
// Threading: stateless functions.
#include <opencv2/core.hpp>
#include <string>

#include "embedded_calibration_stereo/core/tracker/board_teacher.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"

namespace embedded_calibration_stereo::core {

// The device image (CV_32FC1 or CV_32FC3, grey levels) as a teaching frame: grey, 8-bit,
// rounded, negative values 0, no light-off frame. Throws std::invalid_argument on another type.
TeachFrame teachFrameFromDevice(const cv::Mat& device);

// Learns one camera's I_C from `frames` and teaches on it; `taught_on`, when given, receives the
// 8-bit image it taught on. Throws as learnWindowDevice and teachCamera do.
TeachResult teachCameraFromWindow(const WindowFrames& frames, const BoardLayout& layout,
                                  const std::string& camera_name,
                                  const DeviceLearnerOptions& learner = windowLearnerOptions(),
                                  cv::Mat* taught_on = nullptr);

}  // namespace embedded_calibration_stereo::core
