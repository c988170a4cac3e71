#include "embedded_calibration_stereo/test_support/sim_disparity_eval.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <memory>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <utility>

#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/depth/separator.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/depth/stereo_device_template.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"

namespace embedded_calibration_stereo::core {

std::vector<std::string> acceptedDisparityAlgorithms() {
  std::vector<std::string> names;
  for (const char* name : {"sad", "bm", "sgbm", "census_sgm"}) {
    try {
      parseDisparityAlgorithm(name);
      names.push_back(name);
    } catch (const std::invalid_argument&) {
      // not in this build: the list follows whatever the library offers
    }
  }
  return names;
}

void DisparityScore::add(const DisparityScore& other) {
  evaluated += other.evaluated;
  bad += other.bad;
  invalid += other.invalid;
  inliers += other.inliers;
  inlier_square_sum += other.inlier_square_sum;
}

double DisparityScore::inlierRmsPx() const {
  return inliers ? std::sqrt(inlier_square_sum / static_cast<double>(inliers)) : 0.0;
}

DisparityScore scoreDisparity(const cv::Mat& disparity, const cv::Mat& truth, double threshold_px) {
  const BadPixelStats b = evaluateBadPixels(disparity, truth, threshold_px);  // the core's scoring
  DisparityScore s;
  s.evaluated = b.evaluated;
  s.bad = b.bad;
  s.invalid = b.invalid;
  s.inliers = b.inliers;
  s.inlier_square_sum = b.inlier_square_sum;
  return s;
}

DisparityScore scoreMatcher(const DisparityOptions& options, const std::vector<RectifiedSample>& samples) {
  DisparityComputer computer(options);
  DisparityScore total;
  for (const RectifiedSample& s : samples) total.add(scoreDisparity(computer.compute(s.left, s.right), s.truth));
  return total;
}

namespace {

constexpr int kLearnFramesPerEnd = 4;  // the Separator nodelet's learn_frames_per_end default

struct StreamFrame {
  SimFrame sim;
  LightState light;
  int index = 0;
};

// The camera driver's stream: the light schedule stepped once per frame, every frame rendered
// in order with the light command, as the simulated driver renders it.
class DriverStream {
 public:
  DriverStream(const SimRig* sim, const SimDisparitySetOptions& o)
      : sim_(sim), schedule_(scheduleConfig(o)), fps_(sim->config().fps), seed_(o.seed) {}

  StreamFrame next() {
    StreamFrame f;
    f.index = frame_;
    const double t = frame_ / fps_;
    f.light = schedule_.step(t);
    if (f.light.switched) switch_time_s_ = t;
    SimRenderRequest r;
    r.time_s = t;
    r.light_level = f.light.light_level;
    r.noise_seed = seed_ * 1000003u + static_cast<uint64_t>(frame_);
    r.has_light_command = true;
    r.light_command.on = f.light.light_on;
    r.light_command.switch_time_s = switch_time_s_;
    f.sim = sim_->render(r);
    ++frame_;
    return f;
  }

 private:
  static LightScheduleConfig scheduleConfig(const SimDisparitySetOptions& o) {
    LightScheduleConfig c;
    c.period_s = o.period_s;
    c.settle_frames = o.settle_frames;
    c.calibration_frames = o.burst_frames;
    c.first_burst_delay_s = 0.5;  // the drivers' delay: a settled light-off frame before the first burst
    return c;
  }

  const SimRig* sim_;
  LightSchedule schedule_;
  double fps_;
  uint64_t seed_;
  int frame_ = 0;
  double switch_time_s_ = -1e300;
};

// A burst's settled frames: the last `before` light-off frames before it, its light-on frames,
// the first `after` light-off frames after it (unsettled frames are skipped, as the Separator
// skips them).
struct Burst {
  std::vector<StreamFrame> before, on, after;
};

Burst nextBurst(DriverStream* stream, int before, int after) {
  Burst b;
  std::deque<StreamFrame> recent_off;
  while (b.on.empty() || static_cast<int>(b.after.size()) < after) {
    StreamFrame f = stream->next();
    if (!f.light.settled) continue;
    if (f.light.light_on) {
      b.on.push_back(std::move(f));
    } else if (b.on.empty()) {
      recent_off.push_back(std::move(f));
      if (static_cast<int>(recent_off.size()) > before) recent_off.pop_front();
    } else {
      b.after.push_back(std::move(f));
    }
  }
  b.before.assign(std::make_move_iterator(recent_off.begin()), std::make_move_iterator(recent_off.end()));
  return b;
}

const cv::Mat& image(const SimFrame& f, int camera) { return camera ? f.right : f.left; }

// One camera's burst as the Separator nodelet hands it to the learner: the light-off frame just
// before and just after it around its light-on frames.
WindowFrames windowOf(const Burst& b, int camera) {
  WindowFrames w;
  w.light_off_before.push_back(image(b.before.back().sim, camera));
  for (const StreamFrame& f : b.on) w.light_on.push_back(image(f.sim, camera));
  w.light_off_after.push_back(image(b.after.front().sim, camera));
  return w;
}

// The nodelet's middleFrames: at most 3 light-on frames the ends were not learned from.
std::vector<cv::Mat> middleFrames(const WindowFrames& w) {
  const int n = static_cast<int>(w.light_on.size());
  if (n <= 2 * kLearnFramesPerEnd) return w.light_on;
  std::vector<cv::Mat> middle;
  const int count = n - 2 * kLearnFramesPerEnd, step = std::max(1, count / 3);
  for (int i = kLearnFramesPerEnd; i < kLearnFramesPerEnd + count && middle.size() < 3; i += step)
    middle.push_back(w.light_on[i]);
  return middle;
}

struct StereoSeparators {
  StereoSeparators(const DeviceTemplate& l, const DeviceTemplate& r)
      : left(SeparatorOptions(), l), right(SeparatorOptions(), r) {}
  ImageSeparator left, right;  // the Separator nodelet's default options (regional alpha)
};

// Learns the burst's template and keeps it when there is none in use or when it leaves less of
// the device on the burst's middle frames than the one in use (the nodelet's rule).
std::string learnFromBurst(const Burst& b, std::shared_ptr<const StereoSeparators>* in_use) {
  LearnedDevice learned[2];
  WindowFrames frames[2];
  for (int c = 0; c < 2; ++c) {
    frames[c] = windowOf(b, c);
    learned[c] = learnWindowDevice(windowEnds(frames[c], kLearnFramesPerEnd), separatorLearnerOptions());
  }
  auto candidate = std::make_shared<const StereoSeparators>(learned[0].device_template, learned[1].device_template);
  std::string line = "learned from frames " + std::to_string(b.on.front().index) + ".." +
                     std::to_string(b.on.back().index) + " (left " + learned[0].summary() + ")";
  if (*in_use) {
    double residual_new = 0.0, residual_old = 0.0;
    for (int c = 0; c < 2; ++c) {
      const std::vector<cv::Mat> middle = middleFrames(frames[c]);
      residual_new += separationResidual(c ? candidate->right : candidate->left, middle);
      residual_old += separationResidual(c ? (*in_use)->right : (*in_use)->left, middle);
    }
    char buf[96];
    std::snprintf(buf, sizeof buf, "; residual %.2f against %.2f in use: ", residual_new, residual_old);
    line += buf;
    if (residual_new >= residual_old) return line + "kept the one in use";
    line += "replaces it";
  }
  *in_use = candidate;
  return line;
}

cv::Mat grey(const cv::Mat& m) {
  if (m.channels() == 1) return m;
  cv::Mat g;
  cv::cvtColor(m, g, cv::COLOR_BGR2GRAY);
  return g;
}

// Rectifies (left, right) with the frame's true calibration, with the frame's true disparity.
RectifiedSample rectifiedSample(const StreamFrame& f, const cv::Mat& left, const cv::Mat& right, int burst,
                                bool keep_raw) {
  const RectificationMaps maps = RectificationMaps::build(f.sim.truth, RectificationOptions());
  RectifiedSample s;
  std::tie(s.left, s.right) = maps.rectify(grey(left), grey(right));
  if (keep_raw) s.raw_left = maps.rectify(grey(f.sim.left), grey(f.sim.right)).first;
  s.truth = rectifiedDisparityFromDepth(f.sim.left_depth, maps);
  s.frame = f.index;
  s.burst = burst;
  return s;
}

// The true scene of one camera of a lit frame plus the noise the sensor model gives that frame's
// signal (its raw grey levels); see SimDisparitySetOptions::Ideal.
cv::Mat idealSeparation(const StreamFrame& f, int camera, const SimSensorConfig& sensor,
                        SimDisparitySetOptions::Ideal ideal, const cv::Mat& separated) {
  const cv::Mat raw = grey(image(f.sim, camera));
  const cv::Mat scene = grey(camera ? f.sim.right_scene : f.sim.left_scene);
  cv::Mat signal, sigma, noise(raw.size(), CV_32F), out;
  raw.convertTo(signal, CV_32F);
  const double read_dn = sensor.read_noise_e / sensor.gain_e_per_dn;
  cv::sqrt(signal / sensor.gain_e_per_dn + read_dn * read_dn, sigma);
  cv::RNG rng(static_cast<uint64_t>(f.index) * 2 + camera + 1);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, 1.0);
  scene.convertTo(signal, CV_32F);
  cv::Mat(signal + noise.mul(sigma)).convertTo(out, CV_8U);
  if (ideal == SimDisparitySetOptions::Ideal::kIdealClipped) grey(separated).copyTo(out, raw >= kClippedGrey);
  return out;
}

// The burst's scored frames: light-off ones as they are, light-on ones evenly spread and
// separated by the template in use (or raw when `separate` is false).
void scoreBurst(const Burst& b, int burst, const SimDisparitySetOptions& o, const StereoSeparators& sep,
                const SimSensorConfig& sensor, SimDisparitySet* out) {
  for (const auto* side : {&b.before, &b.after})
    for (const StreamFrame& f : *side) out->light_off.push_back(rectifiedSample(f, f.sim.left, f.sim.right, burst, false));
  const int n = static_cast<int>(b.on.size());
  for (int k = 0; k < o.lit_per_burst; ++k) {
    const StreamFrame& f = b.on[std::min(n - 1, (2 * k + 1) * n / (2 * o.lit_per_burst))];
    cv::Mat l = f.sim.left, r = f.sim.right;
    if (o.separate) {
      l = cv::Mat();
      r = cv::Mat();
      separateStereo(sep.left, sep.right, f.sim.left, f.sim.right, &l, &r);
    }
    if (o.ideal != SimDisparitySetOptions::Ideal::kNone) {
      l = idealSeparation(f, 0, sensor, o.ideal, l);
      r = idealSeparation(f, 1, sensor, o.ideal, r);
    }
    out->lit.push_back(rectifiedSample(f, l, r, burst, true));
  }
}

}  // namespace

SimDisparitySet renderSimDisparitySet(const SimDisparitySetOptions& o) {
  if (o.scored_bursts < 1 || o.lit_per_burst < 1 || o.off_per_burst < 2 || o.period_s <= 0.0 ||
      o.burst_frames < 2 * kLearnFramesPerEnd || o.settle_frames < 0)
    throw std::invalid_argument("renderSimDisparitySet: need >= 1 scored burst, >= 1 lit and >= 2 light-off frames "
                                "per burst, a positive period, bursts of >= 8 lit frames and settle frames >= 0");
  const SimRig sim(loadSimRigConfig(o.config_path));
  if (o.ideal != SimDisparitySetOptions::Ideal::kNone && !sim.config().optics.sensor.enabled)
    throw std::invalid_argument("renderSimDisparitySet: an ideal separation needs the config's optics.sensor");
  DriverStream stream(&sim, o);
  const int before = (o.off_per_burst + 1) / 2, after = o.off_per_burst - before;
  std::shared_ptr<const StereoSeparators> in_use;
  SimDisparitySet out;
  for (int b = 0; b <= o.scored_bursts; ++b) {
    const Burst burst = nextBurst(&stream, before, after);
    if (b > 0) scoreBurst(burst, b - 1, o, *in_use, sim.config().optics.sensor, &out);
    // The last burst's template would separate nothing scored.
    if (b < o.scored_bursts) out.log.push_back("burst " + std::to_string(b) + ": " + learnFromBurst(burst, &in_use));
  }
  return out;
}

}  // namespace embedded_calibration_stereo::core
