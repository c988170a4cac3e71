#include "embedded_calibration_stereo/core/depth/device_image_learner.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>  // cv::DISOpticalFlow
#include <stdexcept>

namespace ecs {

std::string DeviceLearnerOptions::Check() const {
  std::vector<std::string> problems;
  if (min_pairs < 2) problems.push_back("min_pairs must be >= 2");
  if (max_pairs < min_pairs || max_pairs > 255) problems.push_back("max_pairs must be in [min_pairs, 255]");
  if (min_inliers < 1) problems.push_back("min_inliers must be >= 1");
  if (!(min_coverage > 0.0 && min_coverage <= 1.0)) problems.push_back("min_coverage must be in (0, 1]");
  if (!(max_standard_error > 0.0)) problems.push_back("max_standard_error must be > 0");
  if (iterations < 0 || iterations > 5) problems.push_back("iterations must be in [0, 5]");
  if (!(inlier_threshold > 0.0)) problems.push_back("inlier_threshold must be > 0");
  std::string joined;
  for (const std::string& p : problems) joined += (joined.empty() ? "" : "; ") + p;
  return joined;
}

void LightPairSet::reset(uint32_t epoch) {
  pairs_.clear();
  epoch_ = epoch;
}

void LightPairSet::add(const cv::Mat& light_off, const cv::Mat& light_on) {
  for (const cv::Mat* m : {&light_off, &light_on}) {
    if (m->empty()) throw std::invalid_argument("light pair: empty image");
    if (m->type() != CV_8UC1 && m->type() != CV_8UC3)
      throw std::invalid_argument("light pair: expected CV_8UC1 (mono8) or CV_8UC3 (bgr8), got type " +
                                  std::to_string(m->type()));
  }
  if (light_off.size() != light_on.size() || light_off.type() != light_on.type())
    throw std::invalid_argument("light pair: light-off and light-on images differ in size or type");
  if (!pairs_.empty() && (pairs_.front().light_on.size() != light_on.size() ||
                          pairs_.front().light_on.type() != light_on.type()))
    throw std::invalid_argument("light pair: size or type differs from the pairs held");
  pairs_.push_back({light_off, light_on});
  while (static_cast<int>(pairs_.size()) > max_pairs_) pairs_.pop_front();
}

std::string LearnedDevice::summary() const {
  char text[160];
  std::snprintf(text, sizeof(text), "%d pairs, coverage %.1f %%, %s", pairs, 100.0 * coverage,
                ready ? "ready" : "not ready");
  return text;
}

namespace {

cv::Mat grey(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat out;
  cv::cvtColor(image, out, cv::COLOR_BGR2GRAY);
  return out;
}

cv::Mat toFloat(const cv::Mat& image) {
  cv::Mat out;
  image.convertTo(out, CV_MAKETYPE(CV_32F, image.channels()));
  return out;
}

// The mean over channels of a float image (the grey estimate of I_C the flow is run against).
cv::Mat channelMean(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat out;
  cv::transform(image, out, cv::Matx13f(0.114f, 0.587f, 0.299f));  // as COLOR_BGR2GRAY
  return out;
}

// One pair's sample of I_C and where it is valid.
struct Sample {
  cv::Mat value;  // CV_32FC(channels)
  cv::Mat valid;  // CV_8U
  double gain_on = 1.0;  // s of on = k * off_aligned + s * I_C
};

// Least-squares k, s of on = k * a + s * c over `mask`, twice: the second time without the
// pixels whose residual exceeds 3 robust sigmas of the first (the scene moved there).
void fitGains(const cv::Mat& on, const cv::Mat& a, const cv::Mat& c, const cv::Mat& mask, double* k,
              double* s) {
  cv::Mat use = mask.clone();
  for (int pass = 0; pass < 2; ++pass) {
    double aa = 0, ac = 0, cc = 0, ao = 0, co = 0;
    for (int y = 0; y < on.rows; ++y) {
      const float *o = on.ptr<float>(y), *pa = a.ptr<float>(y), *pc = c.ptr<float>(y);
      const uchar* m = use.ptr<uchar>(y);
      for (int x = 0; x < on.cols; ++x) {
        if (!m[x]) continue;
        aa += pa[x] * pa[x];
        ac += pa[x] * pc[x];
        cc += pc[x] * pc[x];
        ao += pa[x] * o[x];
        co += pc[x] * o[x];
      }
    }
    const double det = aa * cc - ac * ac;
    if (!(std::abs(det) > 1e-9 * std::max(1.0, aa * cc))) return;  // keep the previous values
    *k = (ao * cc - co * ac) / det;
    *s = (co * aa - ao * ac) / det;
    if (pass == 1) break;
    cv::Mat residual = cv::abs(on - *k * a - *s * c);
    std::vector<float> values;
    values.reserve(on.total() / 4);
    for (int y = 0; y < on.rows; y += 2) {
      const float* r = residual.ptr<float>(y);
      const uchar* m = use.ptr<uchar>(y);
      for (int x = 0; x < on.cols; x += 2)
        if (m[x]) values.push_back(r[x]);
    }
    if (values.empty()) return;
    std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
    const double limit = std::max(3.0, 3.0 * 1.4826 * values[values.size() / 2]);
    use &= residual <= limit;
  }
}

// The pair's sample of I_C; `device` (float, the pair's channels) empty for the unaligned pass.
Sample samplePair(const LightPair& pair, const cv::Mat& device, cv::DISOpticalFlow* dis) {
  Sample sample;
  const cv::Mat on = toFloat(pair.light_on), off = toFloat(pair.light_off);
  const cv::Size size = on.size();
  if (device.empty()) {
    sample.value = on - off;
    sample.valid = cv::Mat(size, CV_8U, cv::Scalar(255));
    return sample;
  }
  const cv::Mat device_grey = channelMean(device);
  // The light-on frame without the lit pattern (as far as it is known), against which the
  // scene's motion is measured.
  cv::Mat on_grey = toFloat(grey(pair.light_on)), scene_on;
  {
    // Its gain first: on ~ k off + s I_C without alignment is biased by the motion, but only the
    // pattern's removal needs it, and a few percent off leaves a faint pattern the flow ignores.
    double k = 1.0, s = 1.0;
    const cv::Mat off_grey = toFloat(grey(pair.light_off));
    fitGains(on_grey, off_grey, device_grey, cv::Mat(size, CV_8U, cv::Scalar(255)), &k, &s);
    cv::Mat(on_grey - s * device_grey).convertTo(scene_on, CV_8U);
  }
  cv::Mat flow;
  dis->calc(scene_on, grey(pair.light_off), flow);  // scene_on(x) ~ off(x + flow(x))
  cv::Mat map(size, CV_32FC2);
  for (int y = 0; y < size.height; ++y) {
    const cv::Point2f* f = flow.ptr<cv::Point2f>(y);
    cv::Point2f* m = map.ptr<cv::Point2f>(y);
    for (int x = 0; x < size.width; ++x) m[x] = cv::Point2f(x + f[x].x, y + f[x].y);
  }
  cv::Mat aligned, inside;
  cv::remap(off, aligned, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(-1));
  // Where the flow points outside the light-off frame there is nothing to subtract.
  cv::Mat ones(size, CV_32F, cv::Scalar(1)), weight;
  cv::remap(ones, weight, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
  inside = weight > 0.999f;

  double k = 1.0, s = 1.0;
  fitGains(on_grey, channelMean(aligned), device_grey, inside, &k, &s);
  if (!(s > 0.05)) s = 1.0;  // a degenerate fit: keep the scale of the estimate
  sample.value = (on - k * aligned) * (1.0 / s);
  sample.valid = inside;
  sample.gain_on = s;
  return sample;
}

// Per pixel: the median of the valid samples, then the mean of those within `threshold` of it.
void combine(const std::vector<Sample>& samples, double threshold, cv::Mat* device, cv::Mat* support,
             cv::Mat* standard_error) {
  const cv::Size size = samples.front().value.size();
  const int channels = samples.front().value.channels();
  device->create(size, CV_MAKETYPE(CV_32F, channels));
  support->create(size, CV_8U);
  standard_error->create(size, CV_32F);
  const int n = static_cast<int>(samples.size());
  cv::parallel_for_(cv::Range(0, size.height), [&](const cv::Range& rows) {
    std::vector<float> values(n), sorted(n);
    for (int y = rows.start; y < rows.end; ++y) {
      float* out = device->ptr<float>(y);
      uchar* count_out = support->ptr<uchar>(y);
      float* se_out = standard_error->ptr<float>(y);
      for (int x = 0; x < size.width; ++x) {
        int worst_count = 255;
        float worst_se = 0.f;
        for (int ch = 0; ch < channels; ++ch) {
          int m = 0;
          for (int i = 0; i < n; ++i)
            if (samples[i].valid.ptr<uchar>(y)[x]) values[m++] = samples[i].value.ptr<float>(y)[x * channels + ch];
          if (m == 0) {
            out[x * channels + ch] = 0.f;
            worst_count = 0;
            worst_se = 1e9f;
            continue;
          }
          std::copy(values.begin(), values.begin() + m, sorted.begin());
          std::nth_element(sorted.begin(), sorted.begin() + m / 2, sorted.begin() + m);
          float median = sorted[m / 2];
          if (m % 2 == 0) median = 0.5f * (median + *std::max_element(sorted.begin(), sorted.begin() + m / 2));
          double sum = 0, sum2 = 0;
          int count = 0;
          for (int i = 0; i < m; ++i) {
            if (std::abs(values[i] - median) > threshold) continue;
            sum += values[i];
            sum2 += double(values[i]) * values[i];
            ++count;
          }
          const double mean = count ? sum / count : median;
          out[x * channels + ch] = static_cast<float>(mean);
          // Spread of the inliers; with one inlier nothing is known of it.
          const double var = count > 1 ? std::max(0.0, (sum2 - count * mean * mean) / (count - 1)) : 1e6;
          worst_count = std::min(worst_count, count);
          worst_se = std::max(worst_se, static_cast<float>(std::sqrt(var / std::max(count, 1))));
        }
        count_out[x] = static_cast<uchar>(std::min(worst_count, 255));
        se_out[x] = worst_se;
      }
    }
  });
}

}  // namespace

LearnedDevice learnDeviceImage(const std::vector<LightPair>& pairs, const DeviceLearnerOptions& options,
                               uint32_t epoch) {
  const std::string problems = options.Check();
  if (!problems.empty()) throw std::invalid_argument("device image learner: " + problems);
  if (pairs.size() < 2) throw std::invalid_argument("device image learner: needs at least 2 light pairs");
  for (const LightPair& p : pairs) {
    if (p.light_on.empty() || p.light_off.empty() || p.light_on.size() != pairs.front().light_on.size() ||
        p.light_on.type() != pairs.front().light_on.type() || p.light_off.size() != p.light_on.size() ||
        p.light_off.type() != p.light_on.type() ||
        (p.light_on.type() != CV_8UC1 && p.light_on.type() != CV_8UC3))
      throw std::invalid_argument("device image learner: light pairs must be CV_8UC1 or CV_8UC3 of one size");
  }
  LearnedDevice learned;
  cv::Mat device;
  const int n = static_cast<int>(pairs.size());
  std::vector<Sample> samples(n);
  for (int pass = 0; pass <= options.iterations; ++pass) {
    // Flow is per pair and independent: pairs run in parallel, one DIS instance each.
    cv::parallel_for_(cv::Range(0, n), [&](const cv::Range& r) {
      cv::Ptr<cv::DISOpticalFlow> dis = cv::DISOpticalFlow::create(cv::DISOpticalFlow::PRESET_MEDIUM);
      for (int i = r.start; i < r.end; ++i) samples[i] = samplePair(pairs[i], device, dis.get());
    });
    if (pass > 0) {
      // Each sample is on the scale of the previous estimate; that scale is pinned to the median
      // pair's light-on gain, so that it cannot drift from pass to pass.
      std::vector<double> gains;
      for (const Sample& s : samples) gains.push_back(s.gain_on);
      std::nth_element(gains.begin(), gains.begin() + n / 2, gains.end());
      const double median_gain = gains[n / 2];
      for (Sample& s : samples) s.value *= median_gain;
    }
    combine(samples, options.inlier_threshold, &device, &learned.support, &learned.standard_error);
  }
  learned.device_template.device = device;
  learned.device_template.calibration_epoch = epoch;
  learned.device_template.frames_averaged = n;
  learned.pairs = n;
  const cv::Mat good = (learned.support >= options.min_inliers) &
                       (learned.standard_error <= static_cast<float>(options.max_standard_error));
  learned.coverage = static_cast<double>(cv::countNonZero(good)) / good.total();
  learned.ready = n >= options.min_pairs && learned.coverage >= options.min_coverage;
  return learned;
}

}  // namespace ecs
