#pragma once
// The simulated embedded-calibration stereo head (ROS-free): two distorted pinhole cameras
// behind a half-mirror, the calibration device's boards reflected by the mirror copies,
// a textured 3D scene with known depth, sensor noise and run-time drift. It renders
//   I = PSF * (transmittance * I_scene + light_level * reflectance * I_device) + noise
// with anti-aliased boards (analytic pixel-area averaging) and a symmetric Gaussian lens PSF, so
// that rendered corners agree with the ground-truth corner positions to 0.02 px.
// Per-camera layers (scene, device, depth) are cached and re-rendered only when that camera's
// truth changes (zoom, drift; every frame while a thermal rate is set).
//
// Threading: render() may run on one thread while setDrift()/truthAt() run on another;
// the drift state is guarded by a mutex and render() works on a snapshot of it. render() itself
// is meant for one thread at a time (its layer caches are serialised by a second mutex).
#include <Eigen/Geometry>
#include <cstdint>
#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace ecs {

// A textured planar rectangle of the scene, in the rig (left optical) frame.
struct ScenePlane {
  Eigen::Vector3d origin = Eigen::Vector3d(0, 0, 5);  // one corner of the rectangle
  Eigen::Vector3d u_axis = Eigen::Vector3d::UnitX();  // unit, along the width
  Eigen::Vector3d v_axis = Eigen::Vector3d::UnitY();  // unit, along the height
  double width_m = 1.0, height_m = 1.0;
  int texture_seed = 1;
  double texel_m = 0.005;  // size of one texture cell on the plane
};

struct SimSceneConfig {
  bool enabled = true;      // false: an empty (black) scene, e.g. for corner accuracy tests
  std::vector<ScenePlane> planes;  // nearest hit wins; the first is usually a background wall
};

struct SimOpticsConfig {
  double transmittance = 0.5;  // t: scene -> camera through the half-mirror
  double reflectance = 0.5;    // r: lit device -> camera
  double device_white = 0.95;  // radiance of lit white squares, fraction of full scale
  double device_black = 0.05;  // radiance of lit black squares and of the device housing
  double psf_sigma_px = 1.0;   // Gaussian lens blur of scene and device, pixels (0 = none)
};

struct SimRigConfig {
  StereoRig rig;               // nominal calibration (no drift)
  CalibrationDevice device;
  SimSceneConfig scene;
  SimOpticsConfig optics;
  double noise_sigma = 1.0;    // Gaussian sensor noise, grey levels (0..255)
  double fps = 30.0;
  std::string encoding = "mono8";  // "mono8" or "bgr8"
  std::string validate() const;
};

// Loads and validates config/sim_rig.yaml; throws ConfigError naming the parameter.
SimRigConfig loadSimRigConfig(const std::string& path);

// Mirrors SetRigDrift.srv.
struct DriftRequest {
  double focal_scale = 1.0;
  Eigen::Vector3d right_rotation_deg = Eigen::Vector3d::Zero();
  double thermal_rate_deg_per_s = 0.0;
  Eigen::Vector3d knock_rotation_deg = Eigen::Vector3d::Zero();
  Eigen::Vector3d knock_translation_m = Eigen::Vector3d::Zero();
  bool reset = false;
};

struct SimFrame {
  cv::Mat left, right;              // CV_8UC1 (mono8) or CV_8UC3 (bgr8)
  cv::Mat left_scene, right_scene;  // transmittance * scene, no device, no noise; same type
  cv::Mat left_depth;               // CV_32FC1, z in metres per raw left pixel; +inf = no hit
  StereoObservation observations;   // every visible corner, true raw pixel positions
  StereoRig truth;                  // the calibration in force for this frame
  // Head pose: the left optical frame in the world frame (identity for a static head).
  Eigen::Isometry3d world_from_left = Eigen::Isometry3d::Identity();
};

class SimRig {
 public:
  explicit SimRig(SimRigConfig config);
  ~SimRig();

  const SimRigConfig& config() const { return config_; }
  // Returns an empty string on success, otherwise why the request was refused (state unchanged).
  // The thermal rotation starts at the time of the request: the latest time_s given to render().
  std::string setDrift(const DriftRequest& request);
  // Same, with an explicit request time on the render() clock (tests, replay).
  std::string setDrift(const DriftRequest& request, double time_s);
  // Current truth at time t (seconds since construction of the clock used by render()).
  StereoRig truthAt(double time_s) const;
  // Virtual boards in the rig frame (fixed to the left camera).
  const std::vector<VirtualBoard>& virtualBoards() const { return boards_; }
  // Renders one stereo frame. light_level in [0, 1] (intermediate while switching).
  SimFrame render(double time_s, double light_level, uint64_t noise_seed) const;

 private:
  struct Impl;
  SimRigConfig config_;
  std::vector<VirtualBoard> boards_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace ecs
