#include "sensor_model.h"

#include <algorithm>
#include <cmath>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/imgproc.hpp>

namespace embedded_calibration_stereo::core {
namespace sim {

uint64_t mixSeed(uint64_t x) {
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

// --- LightResponse ---------------------------------------------------------------------

double LightResponse::Ramp::at(double t) const {
  if (t <= start_s) return from;
  if (rate <= 0.0) return to;
  const double moved = rate * (t - start_s);
  return to > from ? std::min(to, from + moved) : std::max(to, from - moved);
}

double LightResponse::Ramp::endS() const { return rate <= 0.0 ? start_s : start_s + std::abs(to - from) / rate; }

LightResponse::LightResponse(const SimLightResponseConfig& config) : config_(config) {
  ramps_.push_back({-1e300, 0.0, 0.0, 0.0});  // off since forever
}

void LightResponse::command(bool on, double switch_time_s) {
  if (on == last_on_ && switch_time_s == last_switch_s_) return;
  last_on_ = on;
  last_switch_s_ = switch_time_s;
  const double start = std::max(switch_time_s + config_.delay_s, ramps_.back().start_s);
  const double from = levelAt(start);
  const double time = on ? config_.rise_time_s : config_.fall_time_s;
  ramps_.push_back({start, from, on ? 1.0 : 0.0, time > 0.0 ? 1.0 / time : 0.0});
}

double LightResponse::levelAt(double t) const {
  // The last ramp started at or before t holds.
  size_t i = ramps_.size() - 1;
  while (i > 0 && ramps_[i].start_s > t) --i;
  return ramps_[i].at(t);
}

double LightResponse::meanLevel(double t0, double t1) const {
  if (!(t1 > t0)) return levelAt(t0);
  // Each ramp is piecewise linear (breaks at its start and end): the trapezoid rule on those
  // pieces is exact.
  double integral = 0.0;
  for (size_t i = 0; i < ramps_.size(); ++i) {
    const double a = std::max(t0, ramps_[i].start_s);
    const double b = std::min(t1, i + 1 < ramps_.size() ? ramps_[i + 1].start_s : t1);
    if (!(b > a)) continue;
    double points[4] = {a, std::clamp(ramps_[i].start_s, a, b), std::clamp(ramps_[i].endS(), a, b), b};
    std::sort(points, points + 4);
    for (int k = 0; k < 3; ++k)
      integral += 0.5 * (ramps_[i].at(points[k]) + ramps_[i].at(points[k + 1])) * (points[k + 1] - points[k]);
  }
  return integral / (t1 - t0);
}

void LightResponse::forgetBefore(double t) {
  size_t first = 0;
  while (first + 1 < ramps_.size() && ramps_[first + 1].start_s <= t) ++first;
  ramps_.erase(ramps_.begin(), ramps_.begin() + first);
}

// --- AutoExposure -----------------------------------------------------------------------

AutoExposure::AutoExposure(const SimExposureConfig& config) : config_(config), gain_(config.gain) {}

void AutoExposure::meter(double mean_grey) {
  if (config_.mode != "auto") return;
  const double a = 1.0 - std::exp(-1.0 / config_.time_constant_frames);
  // A black frame would ask for infinite gain: meter at least half a grey level.
  const double step = a * (std::log(config_.target_mean) - std::log(std::max(mean_grey, 0.5)));
  gain_ = std::clamp(gain_ * std::exp(step), config_.min_gain, config_.max_gain);
}

// --- composeSensor ----------------------------------------------------------------------

namespace {

// What composeSensor() does to one row, as constants.
struct RowSignal {
  float scene_gain, device_gain;
  bool sensor;                       // shot + read noise, clipped at the full well
  float full_well_dn, inv_e_per_dn, read_dn2;
  float noise_sigma;                 // without the sensor
  float value(float scene, float device, float normal) const {
    float s = scene_gain * scene + device_gain * device;
    if (sensor) {
      s = std::min(std::max(s, 0.0f), full_well_dn);
      return s + normal * std::sqrt(s * inv_e_per_dn + read_dn2);
    }
    return s + normal * noise_sigma;
  }
#if CV_SIMD128
  cv::v_float32x4 value4(const float* scene, const float* device, const float* normal) const {
    cv::v_float32x4 s = cv::v_fma(cv::v_load(scene), cv::v_setall_f32(scene_gain),
                                  cv::v_load(device) * cv::v_setall_f32(device_gain));
    const cv::v_float32x4 n = cv::v_load(normal);
    if (sensor) {
      s = cv::v_min(cv::v_max(s, cv::v_setzero_f32()), cv::v_setall_f32(full_well_dn));
      return cv::v_fma(n, cv::v_sqrt(cv::v_fma(s, cv::v_setall_f32(inv_e_per_dn), cv::v_setall_f32(read_dn2))), s);
    }
    return cv::v_fma(n, cv::v_setall_f32(noise_sigma), s);
  }
#endif
};

// One row of the sensor's image (out) and of the noise-free scene at the same gain (scene_out).
void composeRow(const RowSignal& signal, const float* scene, const float* device, const float* normal, int width,
                uchar* out, uchar* scene_out) {
  int x = 0;
#if CV_SIMD128
  const cv::v_float32x4 scene_gain = cv::v_setall_f32(signal.scene_gain);
  for (; x + 16 <= width; x += 16) {
    cv::v_int32x4 v[4], clean[4];
    for (int k = 0; k < 4; ++k) {
      v[k] = cv::v_round(signal.value4(scene + x + 4 * k, device + x + 4 * k, normal + x + 4 * k));
      clean[k] = cv::v_round(cv::v_load(scene + x + 4 * k) * scene_gain);
    }
    // Saturating, as convertTo.
    cv::v_store(out + x, cv::v_pack_u(cv::v_pack(v[0], v[1]), cv::v_pack(v[2], v[3])));
    cv::v_store(scene_out + x, cv::v_pack_u(cv::v_pack(clean[0], clean[1]), cv::v_pack(clean[2], clean[3])));
  }
#endif
  for (; x < width; ++x) {
    out[x] = cv::saturate_cast<uchar>(signal.value(scene[x], device[x], normal[x]));
    scene_out[x] = cv::saturate_cast<uchar>(signal.scene_gain * scene[x]);
  }
}

}  // namespace

void composeSensor(const SensorParams& p, const SensorLayers* layers, int cameras, int band_rows, SensorImages* out) {
  CV_Assert(cameras > 0 && band_rows > 0);
  const int W = layers[0].scene.cols, H = layers[0].scene.rows;
  for (int c = 0; c < cameras; ++c) {
    const SensorLayers& l = layers[c];
    CV_Assert(l.scene.type() == CV_32F && l.device.type() == CV_32F && l.scene.size() == cv::Size(W, H) &&
              l.device.size() == cv::Size(W, H));
    out[c].image.create(H, W, CV_8U);
    out[c].scene.create(H, W, CV_8U);
  }
  const double e_per_dn = p.sensor.gain_e_per_dn;
  const double read_dn = p.sensor.read_noise_e / e_per_dn;
  const bool noisy = p.sensor.enabled || p.noise_sigma > 0;
  // Unit deviates, scaled in the row pass: without the sensor model sigma is constant.
  const RowSignal signal{static_cast<float>(p.scene_gain), static_cast<float>(p.device_gain), p.sensor.enabled,
                         static_cast<float>(p.sensor.full_well_e / e_per_dn), static_cast<float>(1.0 / e_per_dn),
                         static_cast<float>(read_dn * read_dn), noisy ? static_cast<float>(p.noise_sigma) : 0.0f};
  const int bands = (H + band_rows - 1) / band_rows;
  // Every camera's bands in one parallel pass: one hand-off to the threads per frame.
  cv::parallel_for_(cv::Range(0, cameras * bands), [&](const cv::Range& range) {
    cv::Mat normal(band_rows, W, CV_32F, cv::Scalar(0));
    for (int task = range.start; task < range.end; ++task) {
      const int c = task / bands, band = task % bands;
      const SensorLayers& l = layers[c];
      const cv::Range rows(band * band_rows, std::min(H, (band + 1) * band_rows));
      if (noisy) {
        cv::Mat n = normal.rowRange(0, rows.size());
        cv::RNG rng(mixSeed(l.seed ^ mixSeed(static_cast<uint64_t>(band) + 1)));
        rng.fill(n, cv::RNG::NORMAL, 0.0, 1.0);
      }
      for (int row = rows.start; row < rows.end; ++row)
        composeRow(signal, l.scene.ptr<float>(row), l.device.ptr<float>(row), normal.ptr<float>(row - rows.start), W,
                   out[c].image.ptr<uchar>(row), out[c].scene.ptr<uchar>(row));
    }
  });
}

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
