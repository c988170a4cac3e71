// The simulated stereo head: drift state, truth, cached per-camera layers, frame composition.
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "camera_rays.h"
#include "device_renderer.h"
#include "half_mirror_optics.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "scene_renderer.h"
#include "sensor_model.h"

namespace embedded_calibration_stereo::core {

namespace {

// Corners closer than this to the image border are not reported (a detector cannot refine them).
constexpr double kObservationMarginPx = 5.0;

// Rows per noise band: each band has its own RNG stream so the noise does not depend on how
// cv::parallel_for_ splits the image.
constexpr int kNoiseBandRows = 16;

// How far (pixels) the device may have moved since its ghost was rendered before the ghost is
// rendered again (SimRig::Impl::ghost).
constexpr double kGhostReuseShiftPx = 0.1;

// Limits of a drift request (a simulation of small real-world changes, not arbitrary poses).
constexpr double kMinFocalScale = 0.5, kMaxFocalScale = 2.0;
constexpr double kMaxRotationDeg = 10.0;
constexpr double kMaxThermalRateDegPerS = 1.0;
constexpr double kMaxKnockTranslationM = 0.05;

struct DriftState {
  double focal_scale = 1.0;
  Eigen::Vector3d right_rotation_deg = Eigen::Vector3d::Zero();
  double thermal_rate_deg_per_s = 0.0;
  double thermal_start_s = 0.0;
  Eigen::Isometry3d knock = Eigen::Isometry3d::Identity();  // applied to right_from_left
};

StereoRig truthFor(const StereoRig& nominal, const DriftState& d, double time_s) {
  StereoRig rig = nominal;
  rig.left = nominal.left.withFocalScale(d.focal_scale);
  rig.right = nominal.right.withFocalScale(d.focal_scale);
  const double thermal_deg = d.thermal_rate_deg_per_s * std::max(0.0, time_s - d.thermal_start_s);
  // Rotation of the right camera about its own centre, in its own optical frame: the new
  // frame's axes are R_old * R_drift, so points map with R_drift^T.
  const Eigen::Matrix3d R_drift = rotationFromVectorDeg(d.right_rotation_deg) *
                                  rotationFromVectorDeg(Eigen::Vector3d(0.0, thermal_deg, 0.0));
  Eigen::Isometry3d camera_turn = Eigen::Isometry3d::Identity();
  camera_turn.linear() = R_drift.transpose();
  rig.right_from_left = camera_turn * d.knock * nominal.right_from_left;
  return rig;
}

std::string checkRequest(const DriftRequest& r) {
  if (!(r.focal_scale >= kMinFocalScale && r.focal_scale <= kMaxFocalScale))
    return "focal_scale must be in [0.5, 2] (1 = nominal), got " + std::to_string(r.focal_scale);
  if (!r.right_rotation_deg.allFinite() || r.right_rotation_deg.norm() > kMaxRotationDeg)
    return "right_rotation_deg must be finite with a norm <= 10 deg";
  if (!std::isfinite(r.thermal_rate_deg_per_s) || std::abs(r.thermal_rate_deg_per_s) > kMaxThermalRateDegPerS)
    return "thermal_rate_deg_per_s must be finite and within +-1 deg/s";
  if (!r.knock_rotation_deg.allFinite() || r.knock_rotation_deg.norm() > kMaxRotationDeg)
    return "knock_rotation_deg must be finite with a norm <= 10 deg";
  if (!r.knock_translation_m.allFinite() || r.knock_translation_m.norm() > kMaxKnockTranslationM)
    return "knock_translation_m must be finite with a norm <= 0.05 m";
  return "";
}

// What one camera sees, cached between frames: rendering it is the expensive part, composing a
// frame from it is cheap. The device layer changes only with the camera's truth (intrinsics and
// pose in the rig); the scene layer also with the head's and the movers' poses.
struct CameraLayers {
  bool valid = false;
  PinholeCamera camera;
  Eigen::Isometry3d rig_from_camera = Eigen::Isometry3d::Identity();
  std::vector<double> scene_key;  // poses the scene layer was rendered for (see ScenePoses)
  cv::Mat scene;     // CV_32F transmittance * scene radiance, grey levels
  cv::Mat device;    // CV_32F device radiance, fraction of full scale
  cv::Mat depth;     // CV_32F z of the scene hit in the left optical frame (left camera only)
};

// Where the scene is seen from during one exposure: per sample (the first at the frame's time,
// the others earlier in the exposure) the camera's and every mover's pose in the world.
struct ScenePoses {
  std::vector<Eigen::Isometry3d> world_from_camera;
  std::vector<std::vector<Eigen::Isometry3d>> world_from_movers;
  Eigen::Isometry3d left_from_world = Eigen::Isometry3d::Identity();  // at the frame's time

  std::vector<double> key() const {
    std::vector<double> k;
    const auto add = [&](const Eigen::Isometry3d& pose) {
      k.insert(k.end(), pose.matrix().data(), pose.matrix().data() + 16);
    };
    for (size_t i = 0; i < world_from_camera.size(); ++i) {
      add(world_from_camera[i]);
      for (const Eigen::Isometry3d& m : world_from_movers[i]) add(m);
    }
    return k;
  }
  bool samplesDiffer() const {
    for (size_t i = 1; i < world_from_camera.size(); ++i) {
      if (!(world_from_camera[i].matrix().array() == world_from_camera[0].matrix().array()).all()) return true;
      for (size_t m = 0; m < world_from_movers[i].size(); ++m)
        if (!(world_from_movers[i][m].matrix().array() == world_from_movers[0][m].matrix().array()).all()) return true;
    }
    return false;
  }
};

void toEncoding(const cv::Mat& mono, const std::string& encoding, cv::Mat* out) {
  if (encoding == "bgr8")
    cv::cvtColor(mono, *out, cv::COLOR_GRAY2BGR);
  else
    *out = mono;
}

}  // namespace

struct SimRig::Impl {
  explicit Impl(const SimRigConfig& config)
      : scene(config.scene), light_response(config.optics.light), exposure(config.optics.exposure) {}
  sim::SceneRenderer scene;  // immutable textures

  std::mutex drift_mutex;  // guards drift and latest_time_s
  DriftState drift;
  double latest_time_s = 0.0;

  std::mutex render_mutex;  // guards everything below (render() caches)
  sim::CameraRays rays[2];
  bool rays_valid[2] = {false, false};
  CameraLayers layers[2];
  sim::LightResponse light_response;  // the light's level over time (optics.light)
  sim::AutoExposure exposure;         // the gain of the next frame (optics.exposure)
  // Per camera, fixed by the rays, applied to layers that a moving head (the scene) or a drift
  // (the device) re-renders every frame: the scene path's transmittance times its vignetting,
  // and the device path's vignetting (empty without). Empty until needed or after the rays change.
  cv::Mat scene_factor[2], device_vignetting[2];
  // The ghost layer per camera (renderGhost()) and the pose and intrinsics it was rendered for:
  // at its weight (half a percent on a real head) a ghost that moved by kGhostReuseShiftPx is
  // the same to a hundredth of a grey level, so a drift re-renders it only now and then.
  cv::Mat ghost[2];
  Eigen::Isometry3d ghost_pose[2];
  PinholeCamera ghost_camera[2];

  void updateLayers(int index, const SimRigConfig& config, const std::vector<VirtualBoard>& boards,
                    const PinholeCamera& camera, const Eigen::Isometry3d& rig_from_camera,
                    const ScenePoses& poses);
};

void SimRig::Impl::updateLayers(int index, const SimRigConfig& config,
                                const std::vector<VirtualBoard>& boards, const PinholeCamera& camera,
                                const Eigen::Isometry3d& rig_from_camera, const ScenePoses& poses) {
  CameraLayers& l = layers[index];
  const bool same_pose = (l.rig_from_camera.matrix().array() == rig_from_camera.matrix().array()).all();
  const bool same_device = l.valid && same_pose && sim::sameIntrinsics(l.camera, camera);
  std::vector<double> scene_key = poses.key();
  if (same_device && scene_key == l.scene_key) return;
  if (!rays_valid[index] || !sim::sameIntrinsics(rays[index].camera, camera)) {
    rays[index] = sim::computeCameraRays(camera);
    rays_valid[index] = true;
    scene_factor[index].release();
    device_vignetting[index].release();
    ghost[index].release();
  }
  // Fresh buffers each time: frames handed out earlier never alias the cache.
  CameraLayers fresh;
  const size_t samples = poses.samplesDiffer() ? poses.world_from_camera.size() : 1;
  scene.render(rays[index], poses.world_from_camera[0], poses.left_from_world, poses.world_from_movers[0],
               &fresh.scene, index == 0 ? &fresh.depth : nullptr);
  if (samples > 1) {
    // Motion blur: the mean radiance over the exposure; depth stays the frame time's.
    cv::Mat sub;
    for (size_t k = 1; k < samples; ++k) {
      scene.render(rays[index], poses.world_from_camera[k], poses.left_from_world, poses.world_from_movers[k],
                   &sub, nullptr);
      fresh.scene += sub;
    }
    fresh.scene *= 1.0 / static_cast<double>(samples);
  }
  // The lens blurs the sum of both light paths; by linearity each layer is blurred alone.
  // A symmetric PSF moves no corner and no edge.
  const double sigma = config.optics.psf_sigma_px;
  if (sigma > 0) cv::GaussianBlur(fresh.scene, fresh.scene, cv::Size(), sigma, 0, cv::BORDER_REPLICATE);
  if (same_device) {
    fresh.device = l.device;  // read-only from here on
  } else {
    sim::renderDevice(boards, rays[index], rig_from_camera, config.optics.device_white,
                      config.optics.device_black, &fresh.device);
    if (sigma > 0) cv::GaussianBlur(fresh.device, fresh.device, cv::Size(), sigma, 0, cv::BORDER_REPLICATE);
    if (config.optics.vignetting.device > 0.0 && device_vignetting[index].empty())
      device_vignetting[index] = sim::vignettingFactor(rays[index], config.optics.vignetting.device);
    const bool ghost_holds = !ghost[index].empty() && sim::sameIntrinsics(ghost_camera[index], camera) &&
                             sim::deviceShiftPx(boards, camera, ghost_pose[index], rig_from_camera) < kGhostReuseShiftPx;
    if (!ghost_holds) {
      sim::renderGhost(config.optics, boards, rays[index], rig_from_camera, &ghost[index]);
      ghost_pose[index] = rig_from_camera;
      ghost_camera[index] = camera;
    }
    sim::applyDeviceOptics(config.optics, ghost[index], device_vignetting[index], &fresh.device);
  }
  // Transmittance and vignetting: one factor per pixel (a scalar factor commutes with the blur).
  if (config.optics.vignetting.scene > 0.0) {
    if (scene_factor[index].empty())
      scene_factor[index] = sim::vignettingFactor(rays[index], config.optics.vignetting.scene) *
                            config.optics.transmittance;
    cv::multiply(fresh.scene, scene_factor[index], fresh.scene);
  } else {
    fresh.scene *= config.optics.transmittance;
  }
  fresh.camera = camera;
  fresh.rig_from_camera = rig_from_camera;
  fresh.scene_key = std::move(scene_key);
  fresh.valid = true;
  l = fresh;
}

SimRig::SimRig(SimRigConfig config) : config_(std::move(config)) {
  throwIfProblem(config_.problem());
  boards_ = config_.device.virtualBoards();
  impl_ = std::make_unique<Impl>(config_);
}

SimRig::~SimRig() = default;

std::string SimRig::setDrift(const DriftRequest& request) {
  double now;
  {
    std::lock_guard<std::mutex> lock(impl_->drift_mutex);
    now = impl_->latest_time_s;
  }
  return setDrift(request, now);
}

std::string SimRig::setDrift(const DriftRequest& request, double time_s) {
  const std::string problem = checkRequest(request);
  if (!problem.empty()) return problem;
  if (!std::isfinite(time_s)) return "time must be finite";
  std::lock_guard<std::mutex> lock(impl_->drift_mutex);
  DriftState& d = impl_->drift;
  if (request.reset) d = DriftState();
  d.focal_scale = request.focal_scale;
  d.right_rotation_deg = request.right_rotation_deg;
  d.thermal_rate_deg_per_s = request.thermal_rate_deg_per_s;
  d.thermal_start_s = time_s;
  Eigen::Isometry3d knock = Eigen::Isometry3d::Identity();
  knock.linear() = rotationFromVectorDeg(request.knock_rotation_deg);
  knock.translation() = request.knock_translation_m;
  d.knock = knock * d.knock;
  return "";
}

std::vector<std::string> SimRig::sceneKernelNames() {
  std::vector<std::string> names{sim::scene_kernel::baselineKernel().name};
  if (std::string(sim::scene_kernel::bestKernel().name) != names[0]) names.push_back(sim::scene_kernel::bestKernel().name);
  return names;
}

bool SimRig::useSceneKernel(const std::string& name) {
  for (const sim::scene_kernel::Kernel* k : {&sim::scene_kernel::baselineKernel(), &sim::scene_kernel::bestKernel()}) {
    if (name != k->name) continue;
    std::lock_guard<std::mutex> lock(impl_->render_mutex);
    impl_->scene.useKernel(*k);
    for (CameraLayers& l : impl_->layers) l.valid = false;  // render again with it
    return true;
  }
  return false;
}

std::string SimRig::sceneKernel() const { return impl_->scene.kernel().name; }

StereoRig SimRig::truthAt(double time_s) const {
  DriftState snapshot;
  {
    std::lock_guard<std::mutex> lock(impl_->drift_mutex);
    snapshot = impl_->drift;
  }
  return truthFor(config_.rig, snapshot, time_s);
}

namespace {

StereoObservation observe(const StereoRig& rig, const std::vector<VirtualBoard>& boards, double stamp) {
  StereoObservation obs;
  obs.stamp = stamp;
  const Eigen::Vector3d right_centre = rig.leftFromRight().translation();
  for (const VirtualBoard& b : boards) {
    const Eigen::Vector3d normal = b.rig_from_board.linear().col(2);
    const Eigen::Vector3d origin = b.rig_from_board.translation();
    for (int side = 0; side < 2; ++side) {
      const Eigen::Vector3d centre = side == 0 ? Eigen::Vector3d::Zero() : right_centre;
      if (normal.dot(centre - origin) <= 0) continue;  // the camera sees the board's back
      const PinholeCamera& cam = side == 0 ? rig.left : rig.right;
      BoardCorners corners;
      corners.board_id = b.virtual_id;
      for (int id = 0; id < b.cornerCount(); ++id) {
        const Eigen::Vector3d p_rig = b.cornerInRig(id);
        const Eigen::Vector3d p = side == 0 ? p_rig : Eigen::Vector3d(rig.right_from_left * p_rig);
        Eigen::Vector2d px;
        if (!cam.project(p, &px) || !cam.inImage(px, kObservationMarginPx)) continue;
        corners.corner_ids.push_back(id);
        corners.u.push_back(static_cast<float>(px.x()));
        corners.v.push_back(static_cast<float>(px.y()));
      }
      if (corners.size() > 0) (side == 0 ? obs.left : obs.right).push_back(corners);
    }
  }
  return obs;
}

}  // namespace

SimFrame SimRig::render(double time_s, double light_level, uint64_t noise_seed) const {
  SimRenderRequest request;
  request.time_s = time_s;
  request.light_level = light_level;
  request.noise_seed = noise_seed;
  return render(request);
}

SimFrame SimRig::render(const SimRenderRequest& request) const {
  const double time_s = request.time_s;
  {
    std::lock_guard<std::mutex> lock(impl_->drift_mutex);
    impl_->latest_time_s = std::max(impl_->latest_time_s, time_s);
  }
  SimFrame frame;
  frame.truth = truthAt(time_s);

  frame.time_s = time_s;
  frame.world_from_left = trajectoryPose(config_.trajectory, time_s);
  // Exposure samples, evenly over [t, t + exposure] (t starts the exposure, as for the light),
  // the first at t.
  const int samples = config_.motion_blur.exposure_s > 0 ? config_.motion_blur.samples : 1;
  std::vector<double> sample_times(samples, time_s);
  for (int k = 1; k < samples; ++k)
    sample_times[k] = time_s + config_.motion_blur.exposure_s * k / (samples - 1);
  ScenePoses poses[2];
  const Eigen::Isometry3d rig_from_camera[2] = {Eigen::Isometry3d::Identity(), frame.truth.leftFromRight()};
  for (double t : sample_times) {
    const Eigen::Isometry3d world_from_left = t == time_s ? frame.world_from_left : trajectoryPose(config_.trajectory, t);
    // The static world is the rig frame: keep the camera poses exactly as they are.
    const bool identity = world_from_left.matrix() == Eigen::Matrix4d::Identity();
    std::vector<Eigen::Isometry3d> movers;
    for (const SimMover& m : config_.scene.movers) movers.push_back(trajectoryPose(m.trajectory, t));
    for (int c = 0; c < 2; ++c) {
      poses[c].world_from_camera.push_back(identity ? rig_from_camera[c] : world_from_left * rig_from_camera[c]);
      poses[c].world_from_movers.push_back(movers);
    }
  }
  if (!(frame.world_from_left.matrix() == Eigen::Matrix4d::Identity()))
    poses[0].left_from_world = poses[1].left_from_world = frame.world_from_left.inverse();

  std::lock_guard<std::mutex> lock(impl_->render_mutex);
  const SimOpticsConfig& optics = config_.optics;
  double light_level = request.light_level;
  if (optics.light.model == "response" && request.has_light_command) {
    impl_->light_response.command(request.light_command.on, request.light_command.switch_time_s);
    impl_->light_response.forgetBefore(time_s);
    light_level = impl_->light_response.meanLevel(time_s, time_s + optics.exposure.time_s);
  }
  const double level = std::min(std::max(light_level, 0.0), 1.0);
  const double device_gain = level * config_.optics.reflectance * 255.0;
  const double gain = impl_->exposure.gain();
  frame.light_level = level;
  frame.exposure_gain = gain;

  impl_->updateLayers(0, config_, boards_, frame.truth.left, rig_from_camera[0], poses[0]);
  impl_->updateLayers(1, config_, boards_, frame.truth.right, rig_from_camera[1], poses[1]);
  const uint64_t seed = sim::mixSeed(request.noise_seed);
  const uint64_t right_seed = sim::mixSeed(seed ^ 0x5bd1e995ULL);
  const sim::SensorParams sensor{gain, gain * device_gain, config_.noise_sigma, optics.sensor};
  const sim::SensorLayers layers[2] = {{impl_->layers[0].scene, impl_->layers[0].device, seed},
                                       {impl_->layers[1].scene, impl_->layers[1].device, right_seed}};
  sim::SensorImages sensed[2];  // fresh buffers: toEncoding() may share them with the frame
  sim::composeSensor(sensor, layers, 2, kNoiseBandRows, sensed);
  toEncoding(sensed[0].image, config_.encoding, &frame.left);
  toEncoding(sensed[1].image, config_.encoding, &frame.right);
  toEncoding(sensed[0].scene, config_.encoding, &frame.left_scene);
  toEncoding(sensed[1].scene, config_.encoding, &frame.right_scene);
  // Metered on the image the sensor delivered (both cameras share one exposure setting).
  if (optics.exposure.mode == "auto") impl_->exposure.meter(cv::mean(frame.left)[0]);
  frame.left_depth = impl_->layers[0].depth.clone();
  frame.observations = observe(frame.truth, boards_, time_s);
  return frame;
}

}  // namespace embedded_calibration_stereo::core
