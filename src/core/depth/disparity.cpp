#include "embedded_calibration_stereo/core/depth/disparity.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/depth/disparity_filling.h"
#include "embedded_calibration_stereo/core/depth/sad_matcher.h"

namespace embedded_calibration_stereo::core {

DisparityAlgorithm parseDisparityAlgorithm(const std::string& name) {
  if (name == "census_sgm") return DisparityAlgorithm::kCensusSgm;
  if (name == "sad") return DisparityAlgorithm::kSad;
  if (name == "bm") return DisparityAlgorithm::kBm;
  if (name == "sgbm") return DisparityAlgorithm::kSgbm;
  throw std::invalid_argument("disparity algorithm '" + name +
                              "' unknown; expected census_sgm, sad, bm or sgbm");
}

std::string toString(DisparityAlgorithm algorithm) {
  switch (algorithm) {
    case DisparityAlgorithm::kCensusSgm: return "census_sgm";
    case DisparityAlgorithm::kSad: return "sad";
    case DisparityAlgorithm::kBm: return "bm";
    case DisparityAlgorithm::kSgbm: return "sgbm";
  }
  return "?";
}

int parseSgbmMode(const std::string& name) {
  if (name == "sgbm") return cv::StereoSGBM::MODE_SGBM;
  if (name == "hh") return cv::StereoSGBM::MODE_HH;
  if (name == "sgbm_3way") return cv::StereoSGBM::MODE_SGBM_3WAY;
  if (name == "hh4") return cv::StereoSGBM::MODE_HH4;
  throw std::invalid_argument("sgbm_mode '" + name + "' unknown; expected sgbm, hh, sgbm_3way or hh4");
}

namespace {

// What each pixel is, before holes are filled: matched, or not; if not, hidden from the right
// camera where the matcher says so (`occluded`, nullptr when it cannot tell).
void markDisparity(const cv::Mat& disparity, const cv::Mat* occluded, cv::Mat* mask) {
  mask->create(disparity.size(), CV_8UC1);
  for (int y = 0; y < disparity.rows; ++y) {
    const float* d = disparity.ptr<float>(y);
    const uint8_t* o = occluded ? occluded->ptr<uint8_t>(y) : nullptr;
    uint8_t* m = mask->ptr<uint8_t>(y);
    for (int x = 0; x < disparity.cols; ++x)
      m[x] = isValidDisparity(d[x]) ? kMaskMatched : (o && o[x] ? kMaskOccluded : kMaskNoMatch);
  }
}

bool isKnown(const std::string& name, int (*parse)(const std::string&)) {
  try {
    parse(name);
    return true;
  } catch (const std::invalid_argument&) {
    return false;
  }
}
int parseAlgorithmAsInt(const std::string& name) {
  return static_cast<int>(parseDisparityAlgorithm(name));
}

// Window limits per algorithm: OpenCV's, and for sad the 16-bit window sums' limit.
int minWindow(const std::string& algorithm) {
  return algorithm == "bm" ? 5 : (algorithm == "sad" ? 3 : 1);
}
int maxWindow(const std::string& algorithm) { return algorithm == "sad" ? 15 : 255; }

int nearestOdd(int v) { return v % 2 == 0 ? v + 1 : v; }

// Collects "field value -> fixed (why)" messages for clamp() and "field: problem" for validate().
struct Problems {
  std::vector<std::string> items;
  void add(const std::string& s) { items.push_back(s); }
  std::string joined() const {
    std::string out;
    for (const auto& s : items) out += (out.empty() ? "" : "; ") + s;
    return out;
  }
};

}  // namespace

namespace {
void checkCensusSgm(const DisparityOptions& o, Problems* problems);
}  // namespace

std::string DisparityOptions::validate() const {
  Problems p;
  if (!isKnown(algorithm, parseAlgorithmAsInt))
    p.add("algorithm '" + algorithm + "' unknown (census_sgm, sad, bm, sgbm)");
  if (!isKnown(sgbm_mode, parseSgbmMode))
    p.add("sgbm_mode '" + sgbm_mode + "' unknown (sgbm, hh, sgbm_3way, hh4)");
  if (prefilter_size < 5 || prefilter_size > 255 || prefilter_size % 2 == 0)
    p.add("prefilter_size must be odd in 5..255, got " + std::to_string(prefilter_size));
  if (prefilter_cap < 1 || prefilter_cap > 63)
    p.add("prefilter_cap must be in 1..63, got " + std::to_string(prefilter_cap));
  const int wmin = minWindow(algorithm), wmax = maxWindow(algorithm);
  if (correlation_window_size < wmin || correlation_window_size > wmax ||
      correlation_window_size % 2 == 0)
    p.add("correlation_window_size must be odd in " + std::to_string(wmin) + ".." +
          std::to_string(wmax) + " for " + algorithm + ", got " +
          std::to_string(correlation_window_size));
  if (min_disparity < -2048 || min_disparity > 2048)
    p.add("min_disparity must be in -2048..2048, got " + std::to_string(min_disparity));
  if (disparity_range < 16 || disparity_range > 4096 || disparity_range % 16 != 0)
    p.add("disparity_range must be a multiple of 16 in 16..4096, got " +
          std::to_string(disparity_range));
  if (!(uniqueness_ratio >= 0 && uniqueness_ratio <= 100))
    p.add("uniqueness_ratio must be in 0..100");
  if (texture_threshold < 0) p.add("texture_threshold must be >= 0");
  if (speckle_size < 0) p.add("speckle_size must be >= 0");
  if (speckle_range < 0) p.add("speckle_range must be >= 0");
  if (P1 < 0) p.add("P1 must be >= 0");
  if (P2 <= P1) p.add("P2 must be > P1 (P1 " + std::to_string(P1) + ", P2 " + std::to_string(P2) + ")");
  if (disp12MaxDiff < 0) p.add("disp12MaxDiff must be >= 0");
  checkCensusSgm(*this, &p);
  return p.joined();
}

namespace {

// census_sgm's own fields (validate() has the shared ones).
void checkCensusSgm(const DisparityOptions& o, Problems* problems) {
  Problems& p = *problems;
  const int sgm_census_threshold = o.sgm_census_threshold, sgm_paths = o.sgm_paths;
  const int sgm_P1 = o.sgm_P1, sgm_P2 = o.sgm_P2, median_size = o.median_size;
  if (sgm_census_threshold < 0 || sgm_census_threshold > 255)
    p.add("sgm_census_threshold must be in 0..255, got " + std::to_string(sgm_census_threshold));
  if (sgm_paths != 5 && sgm_paths != 8)
    p.add("sgm_paths must be 5 or 8, got " + std::to_string(sgm_paths));
  if (sgm_P1 < 0 || sgm_P1 > 63) p.add("sgm_P1 must be in 0..63, got " + std::to_string(sgm_P1));
  if (sgm_P2 <= sgm_P1 || sgm_P2 > 200)
    p.add("sgm_P2 must be above sgm_P1 and at most 200 (sgm_P1 " + std::to_string(sgm_P1) +
          ", sgm_P2 " + std::to_string(sgm_P2) + ")");
  if (o.sgm_edge_scale < 0) p.add("sgm_edge_scale must be >= 0");
  if (median_size != 0 && median_size != 3 && median_size != 5)
    p.add("median_size must be 0, 3 or 5, got " + std::to_string(median_size));
  if (o.algorithm == "census_sgm" && o.disparity_range > 512)
    p.add("disparity_range must be at most 512 for census_sgm, got " +
          std::to_string(o.disparity_range));
}

}  // namespace

std::vector<std::string> DisparityOptions::clamp() {
  Problems p;
  const auto fix = [&p](const char* name, auto& field, auto value, const char* why) {
    if (field == value) return;
    std::ostringstream s;
    s << name << " " << field << " -> " << value << " (" << why << ")";
    p.add(s.str());
    field = value;
  };
  if (!isKnown(algorithm, parseAlgorithmAsInt))
    fix("algorithm", algorithm, std::string("sgbm"), "unknown name");
  if (!isKnown(sgbm_mode, parseSgbmMode))
    fix("sgbm_mode", sgbm_mode, std::string("sgbm_3way"), "unknown name");
  fix("prefilter_size", prefilter_size, std::clamp(nearestOdd(prefilter_size), 5, 255),
      "odd, 5..255");
  fix("prefilter_cap", prefilter_cap, std::clamp(prefilter_cap, 1, 63), "1..63");
  const int wmin = minWindow(algorithm), wmax = maxWindow(algorithm);
  fix("correlation_window_size", correlation_window_size,
      std::clamp(nearestOdd(correlation_window_size), wmin, wmax), "odd, within the algorithm's limits");
  fix("min_disparity", min_disparity, std::clamp(min_disparity, -2048, 2048), "-2048..2048");
  fix("disparity_range", disparity_range,
      std::clamp((disparity_range + 15) / 16 * 16, 16, 4096), "multiple of 16, 16..4096");
  fix("uniqueness_ratio", uniqueness_ratio,
      std::isnan(uniqueness_ratio) ? 0.0 : std::clamp(uniqueness_ratio, 0.0, 100.0), "0..100");
  fix("texture_threshold", texture_threshold, std::max(texture_threshold, 0), ">= 0");
  fix("speckle_size", speckle_size, std::max(speckle_size, 0), ">= 0");
  fix("speckle_range", speckle_range, std::max(speckle_range, 0), ">= 0");
  fix("P1", P1, std::max(P1, 0), ">= 0");
  fix("P2", P2, std::max(P2, P1 + 1), "> P1");
  fix("disp12MaxDiff", disp12MaxDiff, std::max(disp12MaxDiff, 0), ">= 0");
  fix("sgm_census_threshold", sgm_census_threshold, std::clamp(sgm_census_threshold, 0, 255), "0..255");
  fix("sgm_paths", sgm_paths, sgm_paths >= 7 ? 8 : 5, "5 or 8");
  fix("sgm_P1", sgm_P1, std::clamp(sgm_P1, 0, 63), "0..63");
  fix("sgm_P2", sgm_P2, std::clamp(sgm_P2, sgm_P1 + 1, 200), "above sgm_P1, at most 200");
  fix("sgm_edge_scale", sgm_edge_scale, std::max(sgm_edge_scale, 0), ">= 0");
  fix("median_size", median_size, median_size <= 1 ? 0 : (median_size <= 4 ? 3 : 5), "0, 3 or 5");
  if (algorithm == "census_sgm")
    fix("disparity_range", disparity_range, std::min(disparity_range, 512), "census_sgm: at most 512");
  return p.items;
}

DisparityComputer::DisparityComputer(const DisparityOptions& options) : options_(options) {
  const std::string problem = options_.validate();
  if (!problem.empty()) throw std::invalid_argument("disparity options: " + problem);
  algorithm_ = parseDisparityAlgorithm(options_.algorithm);
  const DisparityOptions& o = options_;
  const int lr = o.left_right_check ? o.disp12MaxDiff : -1;
  if (algorithm_ == DisparityAlgorithm::kBm) {
    auto bm = cv::StereoBM::create(o.disparity_range, o.correlation_window_size);
    bm->setPreFilterSize(o.prefilter_size);
    bm->setPreFilterCap(o.prefilter_cap);
    bm->setMinDisparity(o.min_disparity);
    bm->setTextureThreshold(o.texture_threshold);
    bm->setUniquenessRatio(static_cast<int>(o.uniqueness_ratio));
    bm->setSpeckleWindowSize(o.speckle_size);
    bm->setSpeckleRange(o.speckle_range);
    bm->setDisp12MaxDiff(lr);
    matcher_ = bm;
  } else if (algorithm_ == DisparityAlgorithm::kSgbm) {
    matcher_ = cv::StereoSGBM::create(o.min_disparity, o.disparity_range,
                                      o.correlation_window_size, o.P1, o.P2, lr, o.prefilter_cap,
                                      static_cast<int>(o.uniqueness_ratio), o.speckle_size,
                                      o.speckle_range, parseSgbmMode(o.sgbm_mode));
  }
}

cv::Mat DisparityComputer::compute(const cv::Mat& left, const cv::Mat& right) {
  cv::Mat disparity;
  compute(left, right, &disparity);
  return disparity;
}

void DisparityComputer::compute(const cv::Mat& left, const cv::Mat& right, cv::Mat* disparity_out,
                                cv::Mat* mask) {
  if (left.empty() || right.empty())
    throw std::invalid_argument("disparity: empty input image");
  if (left.type() != CV_8UC1 || right.type() != CV_8UC1)
    throw std::invalid_argument("disparity: images must be mono8 (CV_8UC1); got types " +
                                std::to_string(left.type()) + " and " +
                                std::to_string(right.type()));
  if (left.size() != right.size())
    throw std::invalid_argument("disparity: left and right image sizes differ");
  const DisparityOptions& o = options_;
  if (left.cols <= o.disparity_range + o.correlation_window_size)
    throw std::invalid_argument("disparity: image width " + std::to_string(left.cols) +
                                " too small for disparity_range + window");

  cv::Mat& disp16 = disparity16_;
  const bool census = algorithm_ == DisparityAlgorithm::kCensusSgm;
  if (census) {
    computeCensusSgmDisparity16(left, right, o.censusSgmParams(), &disp16,
                                mask ? &occluded_ : nullptr);
    if (o.median_size > 0) cv::medianBlur(disp16, disp16, o.median_size);
  } else if (algorithm_ == DisparityAlgorithm::kSad) {
    computeSadDisparity16(left, right, o.sadMatcherParams(), &disp16);
  } else {
    matcher_->compute(left, right, disp16);
  }
  if ((census || algorithm_ == DisparityAlgorithm::kSad) && o.speckle_size > 0)
    speckle_filter_.apply(&disp16, (o.min_disparity - 1) * cv::StereoMatcher::DISP_SCALE,
                          o.speckle_size, o.speckle_range * cv::StereoMatcher::DISP_SCALE);

  // Fixed point (1/16 px) -> float pixels; OpenCV marks invalid as below min_disparity.
  disparity_out->create(disp16.size(), CV_32FC1);  // keeps a buffer of this size and type
  cv::Mat& disparity = *disparity_out;
  const int invalid_below = o.min_disparity * cv::StereoMatcher::DISP_SCALE;
  const bool subpixel = o.subpixel;
  cv::parallel_for_(cv::Range(0, disp16.rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      const short* s = disp16.ptr<short>(y);
      float* d = disparity.ptr<float>(y);
      // Selects rather than branches, so that the compiler vectorises the loops.
      constexpr float kScale = 1.0f / cv::StereoMatcher::DISP_SCALE;
      if (subpixel) {
        for (int x = 0; x < disp16.cols; ++x) {
          const float v = s[x] * kScale;
          d[x] = s[x] < invalid_below ? kInvalidDisparity : v;
        }
      } else {
        for (int x = 0; x < disp16.cols; ++x) {
          const float v = std::round(s[x] * kScale);
          d[x] = s[x] < invalid_below ? kInvalidDisparity : v;
        }
      }
    }
  });
  if (mask) markDisparity(disparity, census ? &occluded_ : nullptr, mask);
  if (o.fill_holes) fillDisparityHoles(&disparity);
}

int DisparityOptions::windowRadius() const {
  return algorithm == "census_sgm" ? kCensusSgmWindow / 2 : correlation_window_size / 2;
}

CensusSgmParams DisparityOptions::censusSgmParams() const {
  CensusSgmParams p;
  p.min_disparity = min_disparity;
  p.num_disparities = disparity_range;
  p.census_threshold = sgm_census_threshold;
  p.paths = sgm_paths;
  p.P1 = sgm_P1;
  p.P2 = sgm_P2;
  p.edge_scale = sgm_edge_scale;
  p.uniqueness_ratio = uniqueness_ratio;
  p.left_right_check = left_right_check;
  p.left_right_tolerance = std::max(1, disp12MaxDiff);
  p.subpixel = subpixel;
  return p;
}

SadMatcherParams DisparityOptions::sadMatcherParams() const {
  SadMatcherParams p;
  p.window_size = correlation_window_size;
  p.min_disparity = min_disparity;
  p.num_disparities = disparity_range;
  p.prefilter_cap = prefilter_cap;
  p.uniqueness_ratio = uniqueness_ratio;
  p.left_right_check = left_right_check;
  p.left_right_tolerance = std::max(1, disp12MaxDiff);
  p.subpixel = subpixel;
  return p;
}

DisparityOptions DisparityOptions::stereoImageProcDefaults(const std::string& algorithm) {
  DisparityOptions o;
  o.algorithm = algorithm;
  o.prefilter_size = 9;
  o.prefilter_cap = 31;
  o.correlation_window_size = 15;
  o.min_disparity = 0;
  o.disparity_range = 64;
  o.uniqueness_ratio = 15;
  o.texture_threshold = 10;
  o.speckle_size = 100;
  o.speckle_range = 4;
  o.P1 = 200;
  o.P2 = 400;
  o.disp12MaxDiff = 0;
  o.sgbm_mode = "sgbm";                    // fullDP false
  o.left_right_check = algorithm != "bm";  // stereo_image_proc sets disp12MaxDiff on SGBM only
  o.fill_holes = false;
  return o;
}

}  // namespace embedded_calibration_stereo::core
