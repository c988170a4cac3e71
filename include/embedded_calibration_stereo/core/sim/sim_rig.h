#pragma once
// The simulated embedded-calibration stereo head (ROS-free): two distorted pinhole cameras
// behind a half-mirror, the calibration device's boards reflected by the mirror copies,
// a textured 3D scene with known depth, sensor noise and run-time drift. It renders
//   I = PSF * (transmittance * I_scene + light_level * reflectance * I_device) + noise
// with anti-aliased boards (analytic pixel-area averaging) and a symmetric Gaussian lens PSF, so
// that rendered corners agree with the ground-truth corner positions to 0.02 px.
// The head (cameras and device, one rigid body) may move through the world along a trajectory
// and panels may move in it; the scene is rendered with world_from_camera = world_from_left(t) *
// left_from_camera, the device stays fixed to the rig.
// Per-camera layers are cached: the device layer is re-rendered only when that camera's truth
// changes (zoom, drift; every frame while a thermal rate is set), the scene layer also when the
// head or a mover moves.
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
#include "embedded_calibration_stereo/core/sim/trajectory.h"

namespace ecs {

// A textured planar rectangle of the scene, in the world frame (a mover's: in its own frame).
// The texture is multi-scale noise from texture_seed, or a photograph (texture_image).
struct ScenePlane {
  Eigen::Vector3d origin = Eigen::Vector3d(0, 0, 5);  // one corner of the rectangle
  Eigen::Vector3d u_axis = Eigen::Vector3d::UnitX();  // unit, along the width
  Eigen::Vector3d v_axis = Eigen::Vector3d::UnitY();  // unit, along the height
  double width_m = 1.0, height_m = 1.0;
  int texture_seed = 1;
  double texel_m = 0.005;  // size of one texture cell on the plane
  // A photograph instead of the noise: path of an image file (read as grey at run time), and
  // the metric size of one copy of it on the plane: (0, 0) = stretched over the whole plane,
  // otherwise tiled from the origin.
  std::string texture_image;
  Eigen::Vector2d texture_tile_m = Eigen::Vector2d::Zero();
};

// A textured panel moving through the world (a person crossing, a door swinging): `panel` is
// given in the mover's own frame, placed in the world by world_from_mover = trajectory(t).
struct SimMover {
  ScenePlane panel;
  SimTrajectory trajectory;
};

struct SimSceneConfig {
  bool enabled = true;      // false: an empty (black) scene, e.g. for corner accuracy tests
  std::vector<ScenePlane> planes;  // nearest hit wins; the first is usually a background wall
  std::vector<SimMover> movers;    // occlude the planes like any other plane
};

// Motion blur of the scene under head or mover motion: the scene layer is the mean of `samples`
// renders evenly spread over the exposure [t - exposure_s, t]. samples = 1: off. The device is
// not blurred: it moves with the cameras.
struct SimMotionBlurConfig {
  double exposure_s = 0.0;
  int samples = 1;
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
  SimTrajectory trajectory;    // head: world_from_left(t); static = the world is the rig frame
  SimMotionBlurConfig motion_blur;
  double noise_sigma = 1.0;    // Gaussian sensor noise, grey levels (0..255)
  double fps = 30.0;
  std::string encoding = "mono8";  // "mono8" or "bgr8"
  std::string validate() const;
};

// Loads and validates config/sim_rig.yaml; throws ConfigError naming the parameter. Relative
// texture image paths resolve against the file's folder; "skimage:NAME" names an image of
// scikit-image's data folder (/usr/lib/python3/dist-packages/skimage/data/NAME).
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
  cv::Mat left_depth;               // CV_32FC1, z in metres per raw left pixel in the left optical
                                    // frame at time_s; +inf = no hit
  StereoObservation observations;   // every visible corner, true raw pixel positions
  StereoRig truth;                  // the calibration in force for this frame
  Eigen::Isometry3d world_from_left = Eigen::Isometry3d::Identity();  // head pose at time_s
  double time_s = 0.0;              // scene time of the frame (end of its exposure)
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
