#pragma once
// The time-dependent and sensor parts of a real head's optics for the simulated rig:
//  - LightResponse: the calibration light's level after its on/off commands (a delay, then a
//    linear rise or fall; a command during a change starts from the level reached), and its
//    mean over an exposure interval: a frame exposed while the light changes is partly lit;
//  - AutoExposure: a gain that follows the left image's mean grey level towards a target, in
//    log gain with a time constant in frames (first order), metered on each rendered frame;
//  - composeSensor(): gain * (scene + device) then shot + read noise (or the Gaussian noise)
//    and 8-bit quantisation with saturation.
//
// Threading: LightResponse and AutoExposure carry state between frames and are not
// thread-safe (SimRig serialises render()); composeSensor() uses cv::parallel_for_ internally.
#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {
namespace sim {

class LightResponse {
 public:
  explicit LightResponse(const SimLightResponseConfig& config);
  // The command in force (from the frame it was given with on); a command that differs from
  // the last one starts a change at switch_time_s + delay_s. Commands come in time order.
  void command(bool on, double switch_time_s);
  // Level in [0, 1] at time t, and its mean over [t0, t1] (the level at t0 when t1 <= t0).
  double levelAt(double t) const;
  double meanLevel(double t0, double t1) const;
  // Drops what no query at or after `t` needs (frames come in time order).
  void forgetBefore(double t);

 private:
  struct Ramp {  // from `from` at start_s towards `to` at `rate` per second (0 = a step)
    double start_s, from, to, rate;
    double at(double t) const;
    double endS() const;  // when it reaches `to`
  };
  SimLightResponseConfig config_;
  std::vector<Ramp> ramps_;  // start times ascending; each one holds until the next starts
  bool last_on_ = false;
  double last_switch_s_ = -1e300;
};

class AutoExposure {
 public:
  explicit AutoExposure(const SimExposureConfig& config);
  double gain() const { return gain_; }  // for the next frame
  // The mean grey level of the frame just rendered with gain(): with mode auto, moves the
  // gain by log g <- log g + a (log target - log mean), a = 1 - exp(-1 / time_constant_frames).
  void meter(double mean_grey);

 private:
  SimExposureConfig config_;
  double gain_;
};

// Noise and quantisation of the cameras' frames: signal = scene_gain * scene +
// device_gain * device (grey levels); with the sensor model the signal is clipped at the full
// well and gets noise of sigma sqrt(read_e^2 + gain_e_per_dn * signal) / gain_e_per_dn,
// otherwise Gaussian noise of noise_sigma; then rounded and saturated to 8 bit. The noise is
// drawn per band of `band_rows` rows from its own stream (seeded from the camera's seed and the
// band), so it does not depend on how the image is split between threads. Beside each image,
// the noise-free scene at scene_gain, rounded the same way.
struct SensorParams {
  double scene_gain = 1.0, device_gain = 0.0;
  double noise_sigma = 0.0;  // without the sensor model
  SimSensorConfig sensor;
};
struct SensorLayers {
  cv::Mat scene, device;  // CV_32F grey levels, the same size for every camera
  uint64_t seed;          // of the camera's noise
};
struct SensorImages {
  cv::Mat image, scene;  // CV_8U: what the sensor delivers, and the scene without noise or device
};
// Every camera in one pass over the rows (one hand-off to the threads per frame). out[c]'s
// images are cv::Mat::create()d: empty ones get fresh buffers.
void composeSensor(const SensorParams& params, const SensorLayers* layers, int cameras, int band_rows,
                   SensorImages* out);

// splitmix64 finaliser (the noise streams' seeding).
uint64_t mixSeed(uint64_t x);

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
