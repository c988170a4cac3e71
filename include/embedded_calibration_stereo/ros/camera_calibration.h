#pragma once
// The calibration of one camera of the driver: a camera_info_manager::CameraInfoManager holds
// the CameraInfo in force (loaded from its URL), and set() persists a new one atomically to
// the URL's file before making it current.
//
// Why not camera_info_manager's own set_camera_info service: it writes the file in place
// (a crash mid-write leaves a broken file) and answers true even when the file cannot be
// written. The driver serves left|right/set_camera_info itself with set(); the manager is
// constructed on a private namespace (`~camera_info_manager/<side>`) so that its own service
// does not collide with the driver's.
//
// Threading: set() and current() may be called from any thread (the manager locks its state;
// set() is serialised by an internal mutex so that two writers cannot interleave).
#include <camera_info_manager/camera_info_manager.h>
#include <ros/node_handle.h>
#include <sensor_msgs/CameraInfo.h>

#include <memory>
#include <mutex>
#include <string>

namespace embedded_calibration_stereo {

class CameraCalibration {
 public:
  // `manager_nh`: namespace for camera_info_manager's internal service; `parameter` names the
  // URL parameter in error messages (e.g. "left_camera_info_url").
  CameraCalibration(const ros::NodeHandle& manager_nh, const std::string& camera_name,
                    const std::string& url, const std::string& parameter);

  // Loads the calibration at start-up. A missing file is not an error: `fallback` (a nominal
  // calibration, or an uncalibrated message with the image size) is used in memory until the
  // first set(). Throws ecs::ConfigError naming the URL parameter when the URL cannot be
  // resolved, or the file exists but is unreadable, unparsable or has a non-positive focal
  // length. Returns true when a file was loaded.
  bool load(const sensor_msgs::CameraInfo& fallback);

  // Validates `info` (plumb_bob, positive focal length, image size), writes it atomically to
  // the URL's file and only then makes it current. On failure returns false with the reason;
  // the calibration in force and the file on disk are unchanged.
  bool set(const sensor_msgs::CameraInfo& info, std::string* reason);

  sensor_msgs::CameraInfo current() const;
  const std::string& path() const { return path_; }
  const std::string& cameraName() const { return camera_name_; }

 private:
  std::string camera_name_;
  std::string url_;
  std::string parameter_;
  std::string path_;
  std::unique_ptr<camera_info_manager::CameraInfoManager> manager_;
  std::mutex write_mutex_;
};

}  // namespace embedded_calibration_stereo
