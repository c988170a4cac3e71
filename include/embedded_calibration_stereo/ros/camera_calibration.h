#pragma once
// The calibration pair of the driver: what is in force (published with every frame), how it is
// loaded at start-up, and how set_camera_info changes it.
//
// - Validation: a calibration is refused with the reason when a consumer would drop it
//   (stereo_input_check.h: finite K, R, P, D; positive focal lengths; R a rotation; the
//   images' size; no binning or ROI; principal points, P and distortion plausible; with a
//   nominal rig, focal lengths near its own) or when the OnlineCalibrator cannot model it (plumb_bob).
// - Pairs: a set_camera_info for one camera that changes its R or P (any field: the rectified
//   pair moves), or whose P does not form a rectified pair with the other camera's (a stereo
//   calibration sets left, then right), is staged: answered success with a status message
//   starting "staged:", and committed together with the other camera's set_camera_info when
//   that one matches it. One that changes only K and D is committed at once with the other
//   camera in force. A staged calibration that looks like one of its camera alone
//   (camera_calibration's monocular calibrator: R the identity, Tx 0, where the camera in force
//   has a rectifying R) and finds no match within the pair timeout changes that camera's K and
//   D (applyStagedMonocular()): both cameras are rectified again (alpha 0) with the stereo
//   extrinsics in force and committed together. A staged calibration that finds no match within
//   `pair_timeout_s` is discarded with an error (problem()); so is every staged one when a set
//   is refused. So the pair in force is always a consistent rectified pair.
// - Persistence: every commit writes both cameras' files through CalibrationPairStore (a new
//   generation made current in one rename), then puts the pair in force with one epoch update:
//   the capture thread reads pair and epoch from one snapshot (inForce()).
// - Verified: markVerified() marks the generation in force verified GOOD on disk (the
//   calibration health's verdict), once per epoch.
// - Start-up: the URL files are used when both load and pass the checks as a pair; when either
//   is corrupt, unreadable, missing beside an existing other one, or inconsistent, the newest
//   valid generation of the store that was verified GOOD is used, else the newest valid one (the
//   previous calibration), else the nominal calibration; problem() then says what was rejected
//   and what runs instead.
//
// Threading: set(), load() and applyStagedMonocular() may run on any thread (serialised by
// write_mutex_, which is held across disk writes); expireStaged() only tries that mutex (it skips while a commit runs);
// inForce(), problem(), source() and stagedText() take only state_mutex_. So the capture thread
// never waits for a disk write.
#include <sensor_msgs/CameraInfo.h>

#include <chrono>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"
#include "embedded_calibration_stereo/ros/calibration_file.h"

namespace embedded_calibration_stereo {

class StereoCalibration {
 public:
  struct Camera {
    std::string name;       // camera_info_manager camera name, written into the file
    std::string url;        // camera_info_manager URL
    std::string parameter;  // URL parameter, named in errors (e.g. "left_camera_info_url")
  };

  // Resolves both URLs. Throws core::ConfigError naming the URL parameter when a URL cannot be
  // resolved, or when both resolve to the same file. `width` x `height`: the cameras' images.
  // `nominal`: the device description's cameras, whose focal lengths every calibration must be
  // near (checkNominalFocal); none: no such check.
  StereoCalibration(const Camera& left, const Camera& right, uint32_t width, uint32_t height,
                    double pair_timeout_s, std::optional<core::StereoRig> nominal = std::nullopt);

  // Loads the pair at start-up (see above); the fallbacks (the nominal calibration, or
  // uncalibrated messages carrying the image size) are used when there is no file at all or
  // nothing valid. Never throws for a file's content. Returns what is in force, e.g.
  // "files '/a/left.yaml' and '/a/right.yaml'"; problem() is set when something was rejected.
  std::string load(const sensor_msgs::CameraInfo& left_fallback, const sensor_msgs::CameraInfo& right_fallback);

  struct SetResult {
    bool success = false;
    std::string message;    // for the service response: "stored in ...", "staged: ...", "rejected: ..."
    std::string discarded;  // non-empty when staged calibrations were discarded (log it as an error)
  };
  // set_camera_info of one camera.
  SetResult set(bool left, const sensor_msgs::CameraInfo& info);

  // Discards a staged calibration older than the pair timeout (but one of its camera alone);
  // returns the error text, or "". Does nothing while a set() is writing (the next call catches
  // up).
  std::string expireStaged();
  // Commits each staged calibration of one camera alone older than the pair timeout (see
  // above); returns what happened to each. Waits for a running commit: not for the capture thread.
  std::vector<SetResult> applyStagedMonocular();

  struct InForce {
    sensor_msgs::CameraInfo left, right;
    uint32_t epoch = 0;       // accepted set_camera_info calls committed in this process
    unsigned generation = 0;  // the store's generation of the pair; 0: none (a fallback in memory)
  };
  InForce inForce() const;
  // Marks the generation in force verified GOOD when `epoch` is still in force (a no-op when it
  // is not, when it is no generation of the store, or when it is marked already). Returns "" or
  // why the mark could not be written; *marked (optional) says whether it wrote one.
  std::string markVerified(uint32_t epoch, bool* marked = nullptr);
  struct Verified {
    sensor_msgs::CameraInfo left, right;
    unsigned generation = 0;
  };
  // The newest generation verified GOOD that is a valid pair; none when there is none.
  std::optional<Verified> newestVerified() const;

  // The last calibration problem (start-up fallback, discarded staged calibration); "" after
  // a successful commit.
  std::string problem() const;
  // Which camera's calibration waits for the other one, e.g. "left (2.1 s)"; "" if none.
  std::string stagedText() const;
  // What is in force: the files, a generation, the nominal calibration, or the last commit.
  std::string source() const;
  const CalibrationPairStore& store() const { return store_; }

 private:
  using Clock = std::chrono::steady_clock;
  struct Staged {
    sensor_msgs::CameraInfo info;
    Clock::time_point since;
    bool monocular = false;  // looks like a calibration of its camera alone (isMonocular)
  };

  // "" when `info` can be put in force for the left (`left`) or right camera; `name` names it in
  // the reason.
  std::string checkOne(bool left, const sensor_msgs::CameraInfo& info, const std::string& name) const;
  // "" when the two form a valid pair, as loaded from the named files.
  std::string checkPair(const sensor_msgs::CameraInfo& left, const std::string& left_name,
                        const sensor_msgs::CameraInfo& right, const std::string& right_name) const;
  // Reads a generation; "" when it is a valid pair (then *left and *right are set).
  std::string readGeneration(const CalibrationPairStore::Generation& g, sensor_msgs::CameraInfo* left,
                             sensor_msgs::CameraInfo* right) const;
  // Caller holds write_mutex_. Writes the pair and puts it in force; "" or the reason.
  std::string commitLocked(sensor_msgs::CameraInfo left, sensor_msgs::CameraInfo right, uint32_t calls,
                           std::string* where);
  // Caller holds write_mutex_. A monocular calibration of one camera: see the class comment.
  SetResult setMonocularLocked(bool left, const sensor_msgs::CameraInfo& info, const InForce& in_force);
  static constexpr double kMonocularRectificationAlpha = 0.0;  // the OnlineCalibrator's default
  // Caller holds write_mutex_. Drops staged calibrations; returns the text saying so, or "".
  std::string discardStagedLocked(const std::string& why);
  void setProblem(const std::string& problem);

  const Camera left_camera_, right_camera_;
  const uint32_t width_, height_;
  const std::chrono::duration<double> pair_timeout_;
  const std::optional<core::StereoRig> nominal_;
  CalibrationPairStore store_;

  std::mutex write_mutex_;  // serialises load(), set() and expireStaged()
  std::optional<Staged> staged_left_, staged_right_;  // under write_mutex_ (and state_mutex_ to change)

  mutable std::mutex state_mutex_;  // guards the members below
  InForce in_force_;
  std::string problem_;
  std::string source_;
};

}  // namespace embedded_calibration_stereo
