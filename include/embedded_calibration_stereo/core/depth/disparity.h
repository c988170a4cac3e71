#pragma once
// Disparity of a rectified mono8 stereo pair, by one of four matchers:
//   "census_sgm" - the default: semi-global matching of census costs along eight paths
//            (census_sgm_matcher.h), then a median filter;
//   "sad"  - the original head's block matcher, the fast mode: sum of absolute differences of
//            x-Sobel prefiltered images over a square window (sad_matcher.h), winner-take-all,
//            parabola sub-pixel, uniqueness and left-right check;
//   "bm"   - OpenCV StereoBM;
//   "sgbm" - OpenCV StereoSGBM in any of its modes (sgbm, hh, sgbm_3way, hh4).
// Parameter names are stereo_image_proc's (Disparity.cfg) so that configurations carry over;
// census_sgm's own parameters start with sgm_. Every matcher is followed by the speckle filter
// and hole filling (docs/depth.md has the measurements behind the defaults).
//
// Output: CV_32FC1, disparity in pixels of the left image (u_left - u_right), and
// kInvalidDisparity (NaN) where no disparity was found. With fill_holes on (the default), holes
// are filled from the background side, so every pixel of a row with any match is valid; the
// mask output (DisparityMask) then says which pixels were matched and which filled.
#include <cstdint>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/census_sgm_matcher.h"
#include "embedded_calibration_stereo/core/depth/sad_matcher.h"
#include "embedded_calibration_stereo/core/depth/speckle_filter.h"

namespace embedded_calibration_stereo::core {

constexpr float kInvalidDisparity = std::numeric_limits<float>::quiet_NaN();
inline bool isValidDisparity(float d) { return d == d; }  // false only for NaN

enum class DisparityAlgorithm { kCensusSgm, kSad, kBm, kSgbm };
DisparityAlgorithm parseDisparityAlgorithm(const std::string& name);  // throws invalid_argument
std::string toString(DisparityAlgorithm algorithm);

// What each pixel of a disparity map is (DisparityComputer::compute's mask, CV_8UC1).
enum DisparityMask : uint8_t {
  kMaskNoMatch = 0,    // no reliable match: left invalid, or filled when fill_holes is on
  kMaskOccluded = 128,  // hidden from the right camera (census_sgm only): filled from the background
  kMaskMatched = 255,  // matched
};

// OpenCV StereoSGBM mode by name: "sgbm", "hh", "sgbm_3way", "hh4"; throws invalid_argument.
int parseSgbmMode(const std::string& name);

struct DisparityOptions {
  // The defaults are the tuned configuration (test_middlebury.cpp, bench_disparity,
  // docs/depth.md): census_sgm with eight paths, 5% uniqueness, left-right check, a 3x3 median,
  // speckle filter and background hole filling. The sad-only fields (window, prefilter cap)
  // keep the values tuned for sad, the fast mode.
  std::string algorithm = "census_sgm";
  int prefilter_size = 9;             // bm only: normalisation window (odd, 5..255)
  int prefilter_cap = 31;             // sad, bm, sgbm: clip of the prefiltered values (1..63)
  int correlation_window_size = 11;   // sad, bm, sgbm: matching window (odd; bm >= 5, sad <= 15)
  int min_disparity = 0;
  int disparity_range = 64;           // number of disparities; multiple of 16
  double uniqueness_ratio = 5.0;      // percent margin of the best over other costs (0..100)
  int texture_threshold = 10;         // bm only
  int speckle_size = 100;             // max size of a speckle region to remove, pixels (0 = off)
  int speckle_range = 2;              // max disparity step inside one region, pixels
  int P1 = 200;                       // sgbm smoothness penalties (P2 > P1)
  int P2 = 800;
  int disp12MaxDiff = 1;              // tolerance of the left-right check, pixels
  std::string sgbm_mode = "sgbm_3way";  // sgbm, hh, sgbm_3way, hh4
  bool left_right_check = true;       // bm/sgbm: enables disp12MaxDiff; sad: own check
  bool subpixel = true;               // false rounds the output to whole pixels
  bool fill_holes = true;             // fill invalid pixels from the background neighbour
  // census_sgm only (census_sgm_matcher.h): the census's noise threshold (grey levels), paths
  // (8, or 5 for one pass: faster, less exact), penalties in census bits (the census has 24),
  // P2's softening across intensity steps (grey levels; 0 = off) and the median filter's size
  // after matching (0 = off, 3 or 5).
  int sgm_census_threshold = 2;
  int sgm_paths = 8;
  int sgm_P1 = 6;
  int sgm_P2 = 48;
  int sgm_edge_scale = 16;
  int median_size = 3;

  // Empty when the options are usable; otherwise one message per problem, joined by "; ".
  std::string validate() const;
  // Moves every invalid value to the nearest valid one; returns what changed (empty if none).
  std::vector<std::string> clamp();

  // The configuration stock stereo_image_proc runs by default (its Disparity.cfg: 15x15
  // window, range 64, uniqueness 15, speckle 100/4, SGBM P1 200 / P2 400, no hole filling),
  // for `algorithm` "bm" or "sgbm": the reference our defaults are measured against.
  static DisparityOptions stereoImageProcDefaults(const std::string& algorithm);

  // Half the matching window of the chosen algorithm (census_sgm: its 5x5 census), pixels.
  int windowRadius() const;

  // The "sad" matcher's parameters these options stand for (the matcher alone: the speckle
  // filter and hole filling are DisparityComputer's steps after it).
  SadMatcherParams sadMatcherParams() const;
  // The same for the "census_sgm" matcher.
  CensusSgmParams censusSgmParams() const;
};

// Computes disparity maps with one configuration.
// Threading: one thread at a time per instance (it keeps the OpenCV matcher and its scratch
// buffers); the matchers themselves run on cv::parallel_for_ (cv::setNumThreads bounds them).
class DisparityComputer {
 public:
  // Throws std::invalid_argument with validate()'s message when the options are invalid.
  explicit DisparityComputer(const DisparityOptions& options);
  const DisparityOptions& options() const { return options_; }

  // left, right: rectified CV_8UC1 images of one size (at least disparity_range + window wide).
  // Throws std::invalid_argument for other types or mismatched sizes.
  cv::Mat compute(const cv::Mat& left, const cv::Mat& right);
  // The same into *disparity, which is written in place when it already is CV_32FC1 of the
  // images' size (e.g. a header over an outgoing message's buffer: no copy to publish it), and,
  // when `mask` is given, what each pixel is (DisparityMask values, CV_8UC1), also in place.
  void compute(const cv::Mat& left, const cv::Mat& right, cv::Mat* disparity,
               cv::Mat* mask = nullptr);

 private:
  DisparityOptions options_;
  DisparityAlgorithm algorithm_;
  cv::Ptr<cv::StereoMatcher> matcher_;  // bm/sgbm
  SpeckleFilter speckle_filter_;        // sad, census_sgm (bm/sgbm filter inside OpenCV)
  cv::Mat disparity16_;                 // the matcher's fixed-point output, reused between frames
  cv::Mat occluded_;                    // census_sgm: pixels hidden from the right camera
};

}  // namespace embedded_calibration_stereo::core
