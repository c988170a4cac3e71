#pragma once
// Checks of the stereo inputs shared by every consumer of CameraInfo (Rectifier, Disparity,
// OnlineCalibrator) and by the driver's set_camera_info and calibration loader, so that the
// driver refuses exactly what the consumers would drop. Every function returns an empty string
// when the input is usable, otherwise "<topic>: <field>: <problem>", so that the nodelet can log
// it (see ErrorThrottle) and skip the frame instead of crashing.
//
// Why: image_geometry::StereoCameraModel::fromCameraInfo asserts that both cameras share the
// frame id and the rectified fx', fy' and cy' (after binning), and Debian's build keeps
// assertions: one inconsistent pair aborts the whole nodelet manager. NaN or zero fields do not
// abort but silently stop depth. So a pair passes only when it is a rectified stereo pair that
// this pipeline (full-resolution images, plumb_bob or rational_polynomial distortion) can use.
// All functions are pure and thread-safe; ErrorThrottle is thread-safe.
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"
#include "embedded_calibration_stereo/ros/set_camera_info_answer.h"  // the answers of the driver's set_camera_info

#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

namespace embedded_calibration_stereo {

// Largest difference of fx', fy' or cy' (pixels) between the two P of a rectified pair: far
// below anything the matcher resolves, above the round-off of a calibration file.
constexpr double kRectifiedPairTolerancePx = 1e-3;

// How far past the image's edges a principal point (K's cx, cy and P's cx', cy') may lie, as a
// fraction of the image's size: real lenses and rectifications stay well within it.
constexpr double kPrincipalPointMargin = 0.25;

// Both images have an encoding of `accepted`, the same encoding and the same size.
std::string checkImagePair(const sensor_msgs::Image& left, const std::string& left_topic,
                           const sensor_msgs::Image& right, const std::string& right_topic,
                           const std::vector<std::string>& accepted);

// A rectified camera's focal lengths (P) lie within this factor of the raw camera's (K): the
// rectification's scaling (alpha) changes them by far less.
constexpr double kRectifiedScaleLimit = 2.0;

// The undistorted radius of the image's farthest corner lies within this factor of its distorted
// radius (strong barrel lenses reach about 1.5).
constexpr double kDistortionFieldLimit = 4.0;

// One CameraInfo of a camera whose images are `width` x `height`: a positive size equal to the
// images'; a distortion model this pipeline rectifies (plumb_bob with 0, 4 or 5 coefficients,
// rational_polynomial with 8; an empty model counts as plumb_bob) and finite coefficients;
// K, R, P finite, K and P calibrated (not all zero) with positive focal lengths and last rows
// [0 0 1] and [0 0 1 0]; R a rotation; principal points within kPrincipalPointMargin of the
// image; P fitting K and R (focal lengths within kRectifiedScaleLimit of K's, the raw image's
// centre rectified within the principal points' margin); a radial distortion that does not fold
// over before the image's corners (kDistortionFieldLimit); binning 0 or 1 and the ROI empty or the full image (this pipeline works on
// full-resolution images).
std::string checkCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& info_topic, uint32_t width,
                            uint32_t height);
// The same for the camera of `image`.

std::string checkCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& info_topic,
                            const sensor_msgs::Image& image);

// A calibrated camera's focal lengths (K's fx, fy) lie within this factor of the device
// description's nominal ones (device_config's cameras): lenses of one model differ by a few
// percent, and a calibration a quarter away is another lens or a corrupt file.
constexpr double kNominalFocalFactor = 1.25;

// K's fx and fy of `info` within kNominalFocalFactor of `nominal_fx`, `nominal_fy` (a device
// description's camera); "" when they are, or "<topic>: K: fx ...: <problem>".
std::string checkNominalFocal(const sensor_msgs::CameraInfo& info, const std::string& info_topic, double nominal_fx,
                              double nominal_fy);

// A calibration pair as a whole: each CameraInfo passes checkCameraInfo (with its own size), the
// two form a rectified pair (checkRectifiedPair) and, with a `nominal` rig (a device
// description's cameras), each camera's focal lengths lie near its nominal ones
// (checkNominalFocal). "" or the first problem.
std::string checkCalibrationPair(const sensor_msgs::CameraInfo& left, const std::string& left_topic,
                                 const sensor_msgs::CameraInfo& right, const std::string& right_topic,
                                 const std::optional<core::StereoRig>& nominal);

// Two CameraInfos, each passing checkCameraInfo, form a rectified stereo pair: same size, the
// same fx', fy' and cy' in both P (within kRectifiedPairTolerancePx), the left P's Tx (P[3])
// zero and the right one's (-fx' * baseline) non-zero. The frame ids are not compared (see
// checkSameFrame): the driver stamps them itself.
std::string checkRectifiedPair(const sensor_msgs::CameraInfo& left, const std::string& left_topic,
                               const sensor_msgs::CameraInfo& right, const std::string& right_topic);

// The two CameraInfos share one frame id (image_geometry::StereoCameraModel asserts it).
std::string checkSameFrame(const sensor_msgs::CameraInfo& left, const std::string& left_topic,
                           const sensor_msgs::CameraInfo& right, const std::string& right_topic);

// Gives the right P exactly the left P's fx', fy' and cy'. checkRectifiedPair allows round-off
// between them; image_geometry compares them with ==. Call it on a pair that passed the checks,
// before any image_geometry call or before publishing the pair.
void alignRectifiedPair(const sensor_msgs::CameraInfo& left, sensor_msgs::CameraInfo* right);

// Throttles error reports per message text: a new problem is reported at once even while
// another one repeats (one NODELET_ERROR_THROTTLE call site would hide it).
class ErrorThrottle {
 public:
  explicit ErrorThrottle(double period_s) : period_s_(period_s) {}
  // True when `message` was not reported within the last period (wall time).
  bool shouldReport(const std::string& message);

 private:
  const double period_s_;
  std::mutex mutex_;
  std::map<std::string, double> last_report_s_;
};

}  // namespace embedded_calibration_stereo
