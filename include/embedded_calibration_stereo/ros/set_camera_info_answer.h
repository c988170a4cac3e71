#pragma once
// Our drivers' set_camera_info protocol (the CameraDriver's, and the LightController's with
// calibration_store file; docs/nodelets.md#calibrations-sent-to-set_camera_info). A stock
// sensor_msgs/SetCameraInfo answer carries only success and status_message, so the one thing our
// drivers add rides in the message: a calibration of one camera held back until the other
// camera's arrives (StereoCalibration::set) is answered success with a status message starting
// kStagedAnswerPrefix, and nothing is in force or written yet. A stock driver never answers so: a
// caller that sees no such answer takes the calibration as stored, as with any driver.
//
// Threads: pure functions.
#include <sensor_msgs/SetCameraInfo.h>

#include <string>

namespace embedded_calibration_stereo {

// The first characters of a staged answer's status_message.
constexpr char kStagedAnswerPrefix[] = "staged:";

// The status_message of a staged answer: the prefix, a space and `reason`.
std::string stagedAnswer(const std::string& reason);

// Whether `status_message` (of a successful answer) says the calibration was only staged.
bool isStagedAnswer(const std::string& status_message);
// Whether `response` is a successful answer saying the calibration was only staged.
bool isStagedAnswer(const sensor_msgs::SetCameraInfo::Response& response);

}  // namespace embedded_calibration_stereo
