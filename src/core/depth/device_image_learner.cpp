#include "embedded_calibration_stereo/core/depth/device_image_learner.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <numeric>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>  // cv::DISOpticalFlow
#include <stdexcept>
#include <utility>

namespace embedded_calibration_stereo::core {

std::string DeviceLearnerOptions::validate() const {
  std::vector<std::string> problems;
  if (min_pairs < 2) problems.push_back("min_pairs must be >= 2");
  if (max_pairs < min_pairs || max_pairs > 255) problems.push_back("max_pairs must be in [min_pairs, 255]");
  if (min_inliers < 1) problems.push_back("min_inliers must be >= 1");
  if (!(min_coverage > 0.0 && min_coverage <= 1.0)) problems.push_back("min_coverage must be in (0, 1]");
  if (!(max_standard_error > 0.0)) problems.push_back("max_standard_error must be > 0");
  if (iterations < 0 || iterations > 5) problems.push_back("iterations must be in [0, 5]");
  if (!(inlier_threshold > 0.0)) problems.push_back("inlier_threshold must be > 0");
  if (first_pass_pairs < 0) problems.push_back("first_pass_pairs must be >= 0");
  if (flow_refinement_iterations < 0 || flow_refinement_iterations > 20)
    problems.push_back("flow_refinement_iterations must be in [0, 20]");
  if (flow_finest_scale < 0 || flow_finest_scale > 4) problems.push_back("flow_finest_scale must be in [0, 4]");
  if (flow_patch_stride < 1 || flow_patch_stride > 7) problems.push_back("flow_patch_stride must be in [1, 7]");
  if (flow_pair_step < 1 || flow_pair_step > 4) problems.push_back("flow_pair_step must be in [1, 4]");
  std::string joined;
  for (const std::string& p : problems) joined += (joined.empty() ? "" : "; ") + p;
  return joined;
}

void LightPairSet::reset(uint32_t epoch) {
  pairs_.clear();
  epoch_ = epoch;
}

void LightPairSet::add(const cv::Mat& light_off, const cv::Mat& light_on, int frames_apart) {
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
  pairs_.push_back({light_off, light_on, frames_apart});
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

// One pair's sample of I_C in fixed point: kSampleSteps per grey level, kNoSample where the pair
// says nothing. A burst's samples are all held until they are combined: in 16 bits they take
// 0.72 MB a 752x480 pair instead of 1.8 (float and a mask), and the step, a sixteenth of a grey
// level, is far below the sensor's noise.
constexpr float kSampleSteps = 16.f;
constexpr int16_t kNoSample = std::numeric_limits<int16_t>::min();
struct Sample {
  cv::Mat value;  // CV_16SC(channels)
  double gain_on = 1.0;  // s of on = k * off_aligned + s * I_C
};

// The unaligned pass's sample: on - off (8 bits each), exact in fixed point.
cv::Mat unalignedSample(const LightPair& pair) {
  cv::Mat out;
  cv::subtract(pair.light_on, pair.light_off, out, cv::noArray(), CV_MAKETYPE(CV_16S, pair.light_on.channels()));
  out.convertTo(out, -1, kSampleSteps);
  return out;
}

// The sample (on - k * aligned) / s (float images) in fixed point, kNoSample where `valid`
// (CV_8U) is 0, in one pass: no float image of it is made.
cv::Mat alignedSample(const cv::Mat& on, const cv::Mat& aligned, double k, double s, const cv::Mat& valid) {
  const int channels = on.channels(), width = on.cols * channels;
  cv::Mat out(on.size(), CV_MAKETYPE(CV_16S, channels));
  const float gain = static_cast<float>(k), steps = static_cast<float>(kSampleSteps / s);
  // Saturated one step short of kNoSample: no value reads as missing.
  const auto value = [&](float o, float a) {
    return cv::saturate_cast<int16_t>(std::max((o - gain * a) * steps, -32767.f));
  };
  // Mono rows 8 pixels at a time, the same bits (rounding to nearest even, saturating packs).
  const cv::v_float32x4 v_gain = cv::v_setall_f32(gain), v_steps = cv::v_setall_f32(steps),
                        v_floor = cv::v_setall_f32(-32767.f);
  const cv::v_int16x8 v_missing = cv::v_setall_s16(kNoSample);
  for (int y = 0; y < on.rows; ++y) {
    const float *o = on.ptr<float>(y), *a = aligned.ptr<float>(y);
    const uchar* v = valid.ptr<uchar>(y);
    int16_t* d = out.ptr<int16_t>(y);
    int i = 0;
    for (; channels == 1 && i + 8 <= width; i += 8) {
      const cv::v_float32x4 lo = cv::v_max((cv::v_load(o + i) - v_gain * cv::v_load(a + i)) * v_steps, v_floor);
      const cv::v_float32x4 hi = cv::v_max((cv::v_load(o + i + 4) - v_gain * cv::v_load(a + i + 4)) * v_steps, v_floor);
      const cv::v_int16x8 sample = cv::v_pack(cv::v_round(lo), cv::v_round(hi));
      const cv::v_uint16x8 is_valid = cv::v_load_expand(v + i) != cv::v_setzero_u16();
      cv::v_store(d + i, cv::v_select(cv::v_reinterpret_as_s16(is_valid), sample, v_missing));
    }
    for (; i < width; ++i) d[i] = v[i / channels] ? value(o[i], a[i]) : kNoSample;
  }
  return out;
}

// Least-squares k, s of on = k * a + s * c over `mask`, twice: the second time without the
// pixels whose residual exceeds 3 robust sigmas of the first (the scene moved there). Two gains
// need far fewer pixels than an image has: every fourth pixel of every fourth row is used.
void fitGains(const cv::Mat& on, const cv::Mat& a, const cv::Mat& c, const cv::Mat& mask, double* k,
              double* s) {
  constexpr int kStep = 4;
  double limit = std::numeric_limits<double>::infinity();
  for (int pass = 0; pass < 2; ++pass) {
    double aa = 0, ac = 0, cc = 0, ao = 0, co = 0;
    std::vector<float> residuals;
    if (pass == 0) residuals.reserve(on.total() / (kStep * kStep));
    for (int y = 0; y < on.rows; y += kStep) {
      const float *o = on.ptr<float>(y), *pa = a.ptr<float>(y), *pc = c.ptr<float>(y);
      const uchar* m = mask.ptr<uchar>(y);
      for (int x = 0; x < on.cols; x += kStep) {
        if (!m[x]) continue;
        if (pass == 1 && !(std::abs(o[x] - *k * pa[x] - *s * pc[x]) <= limit)) continue;
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
    for (int y = 0; y < on.rows; y += kStep) {
      const float *o = on.ptr<float>(y), *pa = a.ptr<float>(y), *pc = c.ptr<float>(y);
      const uchar* m = mask.ptr<uchar>(y);
      for (int x = 0; x < on.cols; x += kStep)
        if (m[x]) residuals.push_back(static_cast<float>(std::abs(o[x] - *k * pa[x] - *s * pc[x])));
    }
    if (residuals.empty()) return;
    std::nth_element(residuals.begin(), residuals.begin() + residuals.size() / 2, residuals.end());
    limit = std::max(3.0, 3.0 * 1.4826 * residuals[residuals.size() / 2]);
  }
}

// The flow of an aligned pass from the pair's light-on frame without the lit pattern (as far as
// `device`, float, knows it) to its light-off frame: scene_on(x) ~ off(x + flow(x)), CV_32FC2.
cv::Mat pairFlow(const LightPair& pair, const cv::Mat& device, cv::DISOpticalFlow* dis) {
  const cv::Mat on_grey = toFloat(grey(pair.light_on));
  const cv::Mat off_grey8 = grey(pair.light_off);
  const cv::Mat device_grey = channelMean(device);
  cv::Mat scene_on;
  {
    // Its gain first: on ~ k off + s I_C without alignment is biased by the motion, but only the
    // pattern's removal needs it, and a few percent off leaves a faint pattern the flow ignores.
    double k = 1.0, s = 1.0;
    fitGains(on_grey, toFloat(off_grey8), device_grey, cv::Mat(on_grey.size(), CV_8U, cv::Scalar(255)), &k, &s);
    cv::Mat(on_grey - s * device_grey).convertTo(scene_on, CV_8U);
  }
  cv::Mat flow;
  dis->calc(scene_on, off_grey8, flow);
  return flow;
}

// A flow turned into the remap's map in place: x + flow(x).
void flowToMap(cv::Mat* flow) {
  for (int y = 0; y < flow->rows; ++y) {
    cv::Point2f* m = flow->ptr<cv::Point2f>(y);
    for (int x = 0; x < flow->cols; ++x) m[x] += cv::Point2f(static_cast<float>(x), static_cast<float>(y));
  }
}

// The pair's sample of I_C through `map` (a flow of pairFlow's made a map by flowToMap; only
// read). The pair's images are converted to float here, on every pass, rather than kept
// converted: a burst's pairs in float would hold about 3 MB each for the whole learning.
Sample alignedPairSample(const LightPair& pair, const cv::Mat& device, const cv::Mat& map) {
  const cv::Mat on = toFloat(pair.light_on), off = toFloat(pair.light_off);
  const cv::Size size = on.size();
  const cv::Mat on_grey = pair.light_on.channels() == 1 ? on : toFloat(grey(pair.light_on));
  cv::Mat valid_map(size, CV_8U);
  const float right = static_cast<float>(size.width - 1), bottom = static_cast<float>(size.height - 1);
  for (int y = 0; y < size.height; ++y) {
    const cv::Point2f* m = map.ptr<cv::Point2f>(y);
    uchar* valid = valid_map.ptr<uchar>(y);
    // Where the flow points outside the light-off frame there is nothing to subtract.
    for (int x = 0; x < size.width; ++x)
      valid[x] = m[x].x >= 0.f && m[x].y >= 0.f && m[x].x <= right && m[x].y <= bottom ? 255 : 0;
  }
  cv::Mat aligned;
  cv::remap(off, aligned, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(-1));

  Sample sample;
  double k = 1.0, s = 1.0;
  fitGains(on_grey, channelMean(aligned), channelMean(device), valid_map, &k, &s);
  if (!(s > 0.05)) s = 1.0;  // a degenerate fit: keep the scale of the estimate
  sample.value = alignedSample(on, aligned, k, s, valid_map);
  sample.gain_on = s;
  return sample;
}

// The pair's sample of I_C; `device` (float, the pair's channels) empty for the unaligned pass.
Sample samplePair(const LightPair& pair, const cv::Mat& device, cv::DISOpticalFlow* dis) {
  if (!device.empty()) {
    cv::Mat map = pairFlow(pair, device, dis);
    flowToMap(&map);
    return alignedPairSample(pair, device, map);
  }
  Sample sample;
  sample.value = unalignedSample(pair);
  return sample;
}

// Pairs of one light-off frame, as positions in the pass's list, by frames apart; the flow is
// computed for the first, every step-th after it and the last, the others interpolate it. A part
// that does not sample its last pair leaves it to the next part, which starts there.
struct FlowRun {
  std::vector<int> positions;
  bool sample_last = true;
};

// The runs of an aligned pass: the pairs grouped by their light-off frame, each group with frames
// apart strictly increasing cut in two at a computed pair (the halves run in parallel: one extra
// flow), any other pair a run of its own.
std::vector<FlowRun> flowRuns(const std::vector<LightPair>& pairs, const std::vector<int>& use, int step) {
  std::map<const uchar*, std::vector<int>> groups;
  for (int i = 0; i < static_cast<int>(use.size()); ++i) groups[pairs[use[i]].light_off.data].push_back(i);
  const auto apart = [&](int position) { return pairs[use[position]].frames_apart; };
  std::vector<FlowRun> runs;
  for (auto& group : groups) {
    std::vector<int>& p = group.second;
    std::stable_sort(p.begin(), p.end(), [&](int a, int b) { return apart(a) < apart(b); });
    bool increasing = apart(p[0]) > 0;
    for (size_t i = 1; i < p.size(); ++i) increasing &= apart(p[i]) > apart(p[i - 1]);
    const int m = static_cast<int>(p.size()), computed = (m - 2 + step) / step + 1;  // 0, step, ..., m - 1
    if (!increasing) {
      for (int position : p) runs.push_back({{position}, true});
    } else if (computed < 3) {
      runs.push_back({p, true});
    } else {
      const int split = (computed / 2) * step;
      runs.push_back({std::vector<int>(p.begin(), p.begin() + split + 1), false});
      runs.push_back({std::vector<int>(p.begin() + split, p.end()), true});
    }
  }
  return runs;
}

// Samples one run in order, holding two computed flows at a time (as maps). Over a frame period
// or two the scene's motion is smooth, so the map between is interpolated linearly in frames
// apart; where it is not (an edge that appears or hides), the combination's inlier test takes the
// sample out. The last map between two computed ones is written over the first of them, which
// is no longer needed then: with every other flow computed, no third map is held.
void sampleRun(const std::vector<LightPair>& pairs, const std::vector<int>& use, const FlowRun& run, int step,
               const cv::Mat& device, cv::DISOpticalFlow* dis, std::vector<Sample>* samples) {
  const std::vector<int>& p = run.positions;
  const int m = static_cast<int>(p.size());
  const auto pair = [&](int i) -> const LightPair& { return pairs[use[p[i]]]; };
  const auto map = [&](int i) {
    cv::Mat flow = pairFlow(pair(i), device, dis);
    flowToMap(&flow);
    return flow;
  };
  cv::Mat map_a = map(0), between;
  for (int a = 0; a + 1 < m;) {
    const int b = std::min(a + step, m - 1);
    const cv::Mat map_b = map(b);
    (*samples)[p[a]] = alignedPairSample(pair(a), device, map_a);
    for (int i = a + 1; i < b; ++i) {
      const double w = static_cast<double>(pair(i).frames_apart - pair(a).frames_apart) /
                       (pair(b).frames_apart - pair(a).frames_apart);
      cv::Mat& out = i + 1 == b ? map_a : between;
      cv::addWeighted(map_a, 1.0 - w, map_b, w, 0.0, out);
      (*samples)[p[i]] = alignedPairSample(pair(i), device, out);
    }
    map_a = map_b;
    a = b;
  }
  if (run.sample_last) (*samples)[p[m - 1]] = alignedPairSample(pair(m - 1), device, map_a);
}

// The comparators of a sorting network for n values: Batcher's odd-even merge sort for the next
// power of two, keeping those between the first n (the others would compare a value with the
// +infinity padding, which never moves).
std::vector<std::pair<int, int>> sortingNetwork(int n) {
  int p2 = 1;
  while (p2 < n) p2 *= 2;
  std::vector<std::pair<int, int>> network;
  for (int p = 1; p < p2; p *= 2)
    for (int k = p; k >= 1; k /= 2)
      for (int j = k % p; j + k < p2; j += 2 * k)
        for (int i = 0; i < std::min(k, p2 - j - k); ++i)
          if ((i + j) / (2 * p) == (i + j + k) / (2 * p) && i + j + k < n) network.emplace_back(i + j, i + j + k);
  return network;
}

// What the inliers of one pixel give: their mean (`median` when there is none), their count and
// the standard error of the mean.
struct Robust {
  float mean;
  int count;
  float standard_error;
};
inline Robust inlierMean(double sum, double sum2, int count, float median) {
  const double mean = count ? sum / count : median;
  // Spread of the inliers; with one inlier nothing is known of it.
  const double var = count > 1 ? std::max(0.0, (sum2 - count * mean * mean) / (count - 1)) : 1e6;
  return {static_cast<float>(mean), count, static_cast<float>(std::sqrt(var / std::max(count, 1)))};
}

// The median of sorted[0, m) and what the values[0, m) within `threshold` of it give.
inline Robust robustMean(const float* values, const float* sorted, int m, double threshold) {
  const float median = m % 2 ? sorted[m / 2] : 0.5f * (sorted[m / 2] + sorted[m / 2 - 1]);
  double sum = 0, sum2 = 0;
  int count = 0;
  for (int i = 0; i < m; ++i) {
    if (std::abs(values[i] - median) > threshold) continue;
    sum += values[i];
    sum2 += double(values[i]) * values[i];
    ++count;
  }
  return inlierMean(sum, sum2, count, median);
}

// Mono pixels whose samples are all valid (nearly all of them) are sorted kLanes at a time by a
// sorting network, branch-free (SIMD min and max); the others one by one.
constexpr int kLanes = 8;
static_assert(kLanes % cv::v_float32x4::nlanes == 0, "kLanes: whole SIMD vectors");

// One image row as combine() reads and writes it: the samples' rows and the outputs' rows.
struct CombineRow {
  std::vector<const int16_t*> values;  // per sample: its values (channels interleaved)
  float scale = 1.f;                   // grey levels per step of the values
  float* out = nullptr;                // the estimate
  uchar* support = nullptr;          // inliers per pixel; null when not wanted
  float* standard_error = nullptr;   // null when not wanted
  int channels = 1;
  double threshold = 0.0;            // inliers are within this of the median
};

// Buffers a worker reuses from pixel to pixel (allocated once per band of rows).
struct CombineScratch {
  std::vector<float> block;   // n samples x kLanes pixels, sample-major
  std::vector<float> block_values;  // the same, unsorted
  std::vector<float> values;  // one pixel's valid samples
  std::vector<float> sorted;  // the same, sorted
};

// Points `row` at row y of the samples and of the outputs (`support`, `standard_error` may be null).
void pointAtRow(const std::vector<Sample>& samples, int y, cv::Mat* device, cv::Mat* support,
                cv::Mat* standard_error, CombineRow* row) {
  for (size_t i = 0; i < samples.size(); ++i) row->values[i] = samples[i].value.ptr<int16_t>(y);
  row->out = device->ptr<float>(y);
  row->support = support ? support->ptr<uchar>(y) : nullptr;
  row->standard_error = standard_error ? standard_error->ptr<float>(y) : nullptr;
}

// One pixel, any number of channels, any valid flags: each channel's valid samples sorted and
// reduced by robustMean; the pixel's support and standard error are those of its worst channel.
void combinePixel(const CombineRow& row, int x, CombineScratch* scratch) {
  const int n = static_cast<int>(row.values.size());
  std::vector<float>& values = scratch->values;
  std::vector<float>& sorted = scratch->sorted;
  int worst_count = 255;
  float worst_se = 0.f;
  for (int ch = 0; ch < row.channels; ++ch) {
    const int at = x * row.channels + ch;
    int m = 0;
    for (int i = 0; i < n; ++i)
      if (row.values[i][at] != kNoSample) values[m++] = row.scale * row.values[i][at];
    if (m == 0) {
      row.out[at] = 0.f;
      worst_count = 0;
      worst_se = 1e9f;
      continue;
    }
    for (int i = 0; i < m; ++i) {  // insertion sort: a few dozen samples at most
      const float v = values[i];
      int j = i;
      for (; j > 0 && sorted[j - 1] > v; --j) sorted[j] = sorted[j - 1];
      sorted[j] = v;
    }
    const Robust r = robustMean(values.data(), sorted.data(), m, row.threshold);
    row.out[at] = r.mean;
    worst_count = std::min(worst_count, r.count);
    worst_se = std::max(worst_se, r.standard_error);
  }
  if (row.support) row.support[x] = static_cast<uchar>(std::min(worst_count, 255));
  if (row.standard_error) row.standard_error[x] = worst_se;
}

// The samples' values at the kLanes pixels from x on, in grey levels, into `block` (sample-major);
// false when a sample is missing at one of them.
bool loadBlock(const CombineRow& row, int x, float* block) {
  bool all = true;
  for (size_t i = 0; i < row.values.size(); ++i) {
    const int16_t* v = row.values[i] + x;
    float* b = block + i * kLanes;
    for (int l = 0; l < kLanes; ++l) {
      all &= v[l] != kNoSample;
      b[l] = row.scale * v[l];
    }
  }
  return all;
}

// Sorts each of the kLanes columns of `block` (n values, sample-major) with the network.
void sortBlock(const std::vector<std::pair<int, int>>& network, float* block) {
  for (const std::pair<int, int>& c : network) {
    float* a = block + c.first * kLanes;
    float* b = block + c.second * kLanes;
    for (int l = 0; l < kLanes; l += cv::v_float32x4::nlanes) {
      const cv::v_float32x4 va = cv::v_load(a + l), vb = cv::v_load(b + l);
      cv::v_store(a + l, cv::v_min(va, vb));
      cv::v_store(b + l, cv::v_max(va, vb));
    }
  }
}

// kLanes mono pixels from x on whose samples are all valid (`values`, as loadBlock gives them):
// copied to `block`, sorted by the network, then the median and the inliers' sums lane by lane
// (as robustMean, in the same order, so that both paths give the same bits).
void combineBlock(const CombineRow& row, int x, const std::vector<std::pair<int, int>>& network,
                  const float* values, float* block) {
  const int n = static_cast<int>(row.values.size());
  std::memcpy(block, values, n * kLanes * sizeof(float));
  sortBlock(network, block);
  const float* lower = block + ((n - 1) / 2) * kLanes;
  const float* upper = block + (n / 2) * kLanes;
  float median[kLanes];
  double sum[kLanes] = {}, sum2[kLanes] = {}, count[kLanes] = {};
  for (int l = 0; l < kLanes; ++l) median[l] = n % 2 ? upper[l] : 0.5f * (upper[l] + lower[l]);
  for (int i = 0; i < n; ++i) {
    const float* v = values + i * kLanes;
    for (int l = 0; l < kLanes; ++l) {
      const double value = v[l], inlier = std::abs(v[l] - median[l]) <= row.threshold ? 1.0 : 0.0;
      sum[l] += inlier * value;
      sum2[l] += inlier * value * value;
      count[l] += inlier;
    }
  }
  for (int l = 0; l < kLanes; ++l) {
    const Robust r = inlierMean(sum[l], sum2[l], static_cast<int>(count[l]), median[l]);
    row.out[x + l] = r.mean;
    if (row.support) row.support[x + l] = static_cast<uchar>(std::min(r.count, 255));
    if (row.standard_error) row.standard_error[x + l] = r.standard_error;
  }
}

// One row: mono pixels kLanes at a time where all samples are valid, every other pixel alone.
void combineRow(const CombineRow& row, int width, const std::vector<std::pair<int, int>>& network,
                CombineScratch* scratch) {
  int x = 0;
  for (; row.channels == 1 && x + kLanes <= width; x += kLanes) {
    if (loadBlock(row, x, scratch->block_values.data())) {
      combineBlock(row, x, network, scratch->block_values.data(), scratch->block.data());
    } else {
      for (int l = 0; l < kLanes; ++l) combinePixel(row, x + l, scratch);
    }
  }
  for (; x < width; ++x) combinePixel(row, x, scratch);
}

// Per pixel: the median of the valid samples (each step worth `scale` grey levels), then the mean
// of those within `threshold` grey levels of it. `support` and `standard_error` may be null (an
// intermediate pass needs the estimate only).
void combine(const std::vector<Sample>& samples, float scale, double threshold, cv::Mat* device,
             cv::Mat* support, cv::Mat* standard_error) {
  const cv::Size size = samples.front().value.size();
  const int channels = samples.front().value.channels();
  device->create(size, CV_MAKETYPE(CV_32F, channels));
  if (support) support->create(size, CV_8U);
  if (standard_error) standard_error->create(size, CV_32F);
  const int n = static_cast<int>(samples.size());
  const std::vector<std::pair<int, int>> network = sortingNetwork(n);
  cv::parallel_for_(cv::Range(0, size.height), [&](const cv::Range& rows) {
    CombineRow row;
    row.values.resize(n);
    row.scale = scale;
    row.channels = channels;
    row.threshold = threshold;
    CombineScratch scratch;
    scratch.block.resize(n * kLanes);
    scratch.block_values.resize(n * kLanes);
    scratch.values.resize(n);
    scratch.sorted.resize(n);
    for (int y = rows.start; y < rows.end; ++y) {
      pointAtRow(samples, y, device, support, standard_error, &row);
      combineRow(row, size.width, network, &scratch);
    }
  });
}

cv::Ptr<cv::DISOpticalFlow> learnerFlow(const DeviceLearnerOptions& options) {
  cv::Ptr<cv::DISOpticalFlow> dis = cv::DISOpticalFlow::create(cv::DISOpticalFlow::PRESET_MEDIUM);
  dis->setVariationalRefinementIterations(options.flow_refinement_iterations);
  dis->setFinestScale(options.flow_finest_scale);
  dis->setPatchStride(options.flow_patch_stride);
  return dis;
}

// The samples of the pairs `use`, in that order; `device` empty for the unaligned pass. Flow is
// per pair (or per run of pairs) and independent: in parallel, one DIS instance each, or one
// after the other (options.parallel_pairs).
std::vector<Sample> samplePass(const std::vector<LightPair>& pairs, const std::vector<int>& use, const cv::Mat& device,
                               const DeviceLearnerOptions& options) {
  std::vector<Sample> samples(use.size());
  const bool interpolate = !device.empty() && options.flow_pair_step > 1;
  const std::vector<FlowRun> runs = interpolate ? flowRuns(pairs, use, options.flow_pair_step) : std::vector<FlowRun>();
  const int tasks = static_cast<int>(interpolate ? runs.size() : use.size());
  const auto body = [&](const cv::Range& r) {
    const cv::Ptr<cv::DISOpticalFlow> dis = learnerFlow(options);
    for (int i = r.start; i < r.end; ++i) {
      if (interpolate)
        sampleRun(pairs, use, runs[i], options.flow_pair_step, device, dis.get(), &samples);
      else
        samples[i] = samplePair(pairs[use[i]], device, dis.get());
    }
  };
  if (options.parallel_pairs)
    cv::parallel_for_(cv::Range(0, tasks), body);
  else
    body(cv::Range(0, tasks));
  return samples;
}

}  // namespace

LearnedDevice learnDeviceImage(const std::vector<LightPair>& pairs, const DeviceLearnerOptions& options,
                               uint32_t epoch) {
  const std::string problems = options.validate();
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
  // Every pair, and the first aligned pass's: the first_pass_pairs fewest frames apart.
  std::vector<int> all(n);
  std::iota(all.begin(), all.end(), 0);
  std::vector<int> closest = all;
  std::stable_sort(closest.begin(), closest.end(),
                   [&](int a, int b) { return pairs[a].frames_apart < pairs[b].frames_apart; });
  if (options.first_pass_pairs > 0 && options.first_pass_pairs < n) closest.resize(options.first_pass_pairs);
  for (int pass = 0; pass <= options.iterations; ++pass) {
    const std::vector<int>& use = pass == 1 ? closest : all;
    const int m = static_cast<int>(use.size());
    double scale = 1.0;  // of the samples' grey levels
    const std::vector<Sample> samples = samplePass(pairs, use, device, options);
    if (pass > 0) {
      // Each sample is on the scale of the previous estimate; that scale is pinned to the median
      // pair's light-on gain, so that it cannot drift from pass to pass.
      std::vector<double> gains;
      for (const Sample& s : samples) gains.push_back(s.gain_on);
      std::nth_element(gains.begin(), gains.begin() + m / 2, gains.end());
      scale = gains[m / 2];
    }
    const bool last = pass == options.iterations;
    combine(samples, static_cast<float>(scale / kSampleSteps), options.inlier_threshold, &device,
            last ? &learned.support : nullptr, last ? &learned.standard_error : nullptr);
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

}  // namespace embedded_calibration_stereo::core
