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
// The optics of a real head (half-mirror ghost, vignetting, exposure, the light's response,
// shot + read noise) are optional, ideal by default (half_mirror_optics.h, sensor_model.h).
//
// Threading: render() may run on one thread while setDrift()/truthAt() run on another;
// the drift state is guarded by a mutex and render() works on a snapshot of it. render() itself
// is meant for one thread at a time (its layer caches, the auto-exposure and the light response
// state are serialised by a second mutex).
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
#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo::core {

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
// renders evenly spread over the exposure [t, t + exposure_s]. samples = 1: off. The device is
// not blurred: it moves with the cameras.
struct SimMotionBlurConfig {
  double exposure_s = 0.0;
  int samples = 1;
};

// The optics of a real head (docs/simulator.md has the formulas). Every default is the ideal
// head: with all of them the image is the one the simulator rendered before they existed.

// The half-mirror's second surface: a weak copy of the device image, shifted in the image.
struct SimGhostConfig {
  double thickness_mm = 0.0;        // glass plate thickness
  double angle_deg = 45.0;          // angle between the optical axis and the mirror plane
  double refractive_index = 1.517;  // of the glass (N-BK7)
  double back_reflectance = 0.0;    // reflectance of the back surface; 0 = no ghost (ideal)
  double direction_deg = 90.0;      // image direction of the ghost's shift: 0 = +u, 90 = +v
};

// Fall-off with the field angle theta of each pixel's ray: cos(theta)^(4 * strength).
struct SimVignettingConfig {
  double scene = 0.0;   // scene path (through the half-mirror); 0 = none (ideal)
  double device = 0.0;  // device path (reflected by the mirrors); 0 = none (ideal)
};

// Exposure and gain: a multiplier of the whole signal before noise and quantisation.
struct SimExposureConfig {
  std::string mode = "fixed";         // "fixed": `gain` always; "auto": auto-exposure from `gain`
  double gain = 1.0;                  // fixed gain, or the auto-exposure's initial gain
  double target_mean = 100.0;         // auto: the mean grey level it steers the left image to
  double time_constant_frames = 8.0;  // auto: frames to close 63 % of the gap (in log gain)
  double min_gain = 0.25, max_gain = 4.0;  // auto: limits
  double time_s = 0.0;                // integration time from the frame time: the light is
                                      // averaged over it (0 = an instant)
};

// How the calibration light's level follows its on/off command.
struct SimLightResponseConfig {
  std::string model = "schedule";  // "schedule": the driver's linear ramp over settle_frames
                                   // (ideal); "response": delay, then linear rise or fall
  double rise_time_s = 0.0;        // response: 0 -> 1 time after the delay
  double fall_time_s = 0.0;        // response: 1 -> 0 time after the delay
  double delay_s = 0.0;            // response: command -> start of the change
};

// Shot + read noise; when not enabled the Gaussian `noise_sigma` applies (ideal: today's).
struct SimSensorConfig {
  bool enabled = false;         // set by the presence of `optics.sensor` in the YAML
  double gain_e_per_dn = 47.0;  // electrons per grey level
  double read_noise_e = 15.0;   // read noise, electrons rms
  double full_well_e = 12000.0; // the signal saturates there, electrons
};

struct SimOpticsConfig {
  double transmittance = 0.5;  // t: scene -> camera through the half-mirror
  double reflectance = 0.5;    // r: lit device -> camera
  double device_white = 0.95;  // radiance of lit white squares, fraction of full scale
  double device_black = 0.05;  // radiance of lit black squares and of the device housing
  double psf_sigma_px = 1.0;   // Gaussian lens blur of scene and device, pixels (0 = none)
  SimGhostConfig ghost;
  SimVignettingConfig vignetting;
  SimExposureConfig exposure;
  SimLightResponseConfig light;
  SimSensorConfig sensor;
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
  std::string validate() const;  // "parameter: problem", empty when usable
  ConfigProblem problem() const;
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

// The light's commanded state for a frame, for optics.light.model "response".
struct SimLightCommand {
  bool on = false;
  double switch_time_s = -1e300;  // when it was last switched, on render()'s clock
};

// One frame's inputs (render()'s arguments, plus the light command).
struct SimRenderRequest {
  double time_s = 0.0;
  double light_level = 0.0;  // the schedule's level (used unless the light response applies)
  uint64_t noise_seed = 0;
  bool has_light_command = false;  // the light response needs the command; without it the
  SimLightCommand light_command;   // schedule's level is rendered
};

struct SimFrame {
  cv::Mat left, right;              // CV_8UC1 (mono8) or CV_8UC3 (bgr8)
  // transmittance * scene as the sensor sees it (vignetting, exposure gain), no device, no
  // noise; same type
  cv::Mat left_scene, right_scene;
  cv::Mat left_depth;               // CV_32FC1, z in metres per raw left pixel in the left optical
                                    // frame at time_s; +inf = no hit
  StereoObservation observations;   // every visible corner, true raw pixel positions
  StereoRig truth;                  // the calibration in force for this frame
  Eigen::Isometry3d world_from_left = Eigen::Isometry3d::Identity();  // head pose at time_s
  double time_s = 0.0;              // scene time of the frame (start of its exposure)
  double light_level = 0.0;         // the light level rendered (mean over the exposure)
  double exposure_gain = 1.0;       // the exposure gain applied to this frame
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
  // Same, with the light command. Auto-exposure and the light response carry state from one
  // frame to the next: frames rendered in the same order render the same images.
  SimFrame render(const SimRenderRequest& request) const;

  // The scene renderer's row kernels: "baseline" (the build's own SIMD: SSE2 or NEON) always,
  // "avx2" on x86-64 CPUs with AVX2 and FMA; by default the widest the CPU runs. They render
  // the same images to float rounding; choosing one is for tests and benchmarks. Returns false
  // (and keeps the kernel) for a name this build or CPU cannot run.
  static std::vector<std::string> sceneKernelNames();
  bool useSceneKernel(const std::string& name);
  std::string sceneKernel() const;

 private:
  struct Impl;
  SimRigConfig config_;
  std::vector<VirtualBoard> boards_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace embedded_calibration_stereo::core
