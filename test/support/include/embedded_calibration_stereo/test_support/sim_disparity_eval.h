#pragma once
// Disparity of the simulated head's moving, photographed world against the simulator's depth
// truth, for light-off frames and for light-on frames the product's Separator separated: the
// shared part of bench_disparity_sim and test_disparity_on_sim.
//
// The frames follow the driver's light schedule (periodic bursts), rendered every frame in
// order, so that the auto-exposure and the light's response see the stream the head sees. The
// Separator's device image is learned the way the Separator nodelet learns it, with no covered
// scene and no truth: each ended burst's 4 light-on frames nearest each end, paired with the
// settled light-off frame on their side (windowEnds + learnWindowDevice, separatorLearnerOptions),
// and a new burst's template replaces the one in use only when it leaves less of the device on
// that burst's middle frames (separationResidual). A burst's own frames are separated with the
// template in use before it ended, as in the nodelet, where learning finishes after the burst.
// The first burst is only learned from; the simulator's truth only scores.
//
// Scoring rectifies with the simulator's true calibration (a measurement of the matcher, not of
// the calibration) and takes the true disparity of the rectified left image from the depth
// truth (rectifiedDisparityFromDepth: d = f' B / z on the rectified grid). Every pixel with
// truth counts, the left border band the right camera does not see included (Middlebury's "all"
// convention, as test_middlebury and evaluateBadPixels).
#include <opencv2/core.hpp>
#include <cstdint>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/disparity.h"

namespace embedded_calibration_stereo::core {

// The names among "sad", "bm", "sgbm", "census_sgm" that parseDisparityAlgorithm accepts, in
// that order: a matcher added under one of these names is picked up without a change here.
std::vector<std::string> acceptedDisparityAlgorithms();

// Errors of disparity maps against truth, summed over frames.
struct DisparityScore {
  int64_t evaluated = 0;  // pixels with truth
  int64_t bad = 0;        // |d - truth| > threshold, or no disparity
  int64_t invalid = 0;    // no disparity
  int64_t inliers = 0;    // valid and |d - truth| <= threshold
  double inlier_square_sum = 0.0;  // of (d - truth), over the inliers, px^2
  void add(const DisparityScore& other);
  double badPercent() const { return evaluated ? 100.0 * bad / evaluated : 0.0; }
  double invalidPercent() const { return evaluated ? 100.0 * invalid / evaluated : 0.0; }
  double inlierRmsPx() const;  // the sub-pixel accuracy of the matches that are right
};

// disparity: CV_32F px, NaN/inf = invalid; truth: CV_32F px, <= 0 or non-finite = unknown.
// Throws std::invalid_argument on other types or sizes.
DisparityScore scoreDisparity(const cv::Mat& disparity, const cv::Mat& truth, double threshold_px = 2.0);

// One scored stereo frame, rectified with the true calibration.
struct RectifiedSample {
  cv::Mat left, right;  // CV_8UC1: the light-off frame, or the separated light-on frame
  cv::Mat raw_left;     // light-on frames: the rectified left image before separation
  cv::Mat truth;        // CV_32F: true disparity of `left`, 0 = unknown
  int frame = 0;        // index in the driver's stream
  int burst = 0;        // the scored burst it belongs to (0 = the first scored one)
};

struct SimDisparitySetOptions {
  std::string config_path;  // a sim rig YAML (config/drive_photo.yaml)
  uint64_t seed = 1;        // noise seed of frame k: seed * 1000003 + k
  int scored_bursts = 3;    // bursts scored, after the one learned from first
  int lit_per_burst = 2;    // settled light-on frames scored per burst, evenly spread
  int off_per_burst = 2;    // settled light-off frames scored per burst: half (rounded up)
                            // the last ones before it, the rest the first ones after it
  double period_s = 1.3;    // between bursts: distinct stretches of the corridor
  int burst_frames = 10;    // settled light-on frames per burst (the driver's calibration_frames)
  int settle_frames = 2;    // unsettled frames after each switch (the driver's settle_frames)
  bool separate = true;     // false: the lit frames unseparated (shows the comparison can fail)
  // What the lit frames would score with an ideal separation, to tell the separation's share of
  // the lit-frame gap from what no separation can remove (a diagnosis: it reads the truth):
  //  - kNone: the Separator's output (or the raw frames, with separate false);
  //  - kIdeal: the true scene plus the sensor noise the lit frame has (its shot noise at the lit
  //    frame's signal, the read noise; the config's sensor model);
  //  - kIdealClipped: the same, except where the raw frame is clipped (kClippedGrey and above:
  //    the full well, less the noise around it), which keep the Separator's output: the scene
  //    there is lost.
  enum class Ideal { kNone, kIdeal, kIdealClipped };
  Ideal ideal = Ideal::kNone;
};

// Raw grey levels at or above this count as clipped for SimDisparitySetOptions::kIdealClipped:
// the simulated sensor's full well is 255.3 grey levels and its noise there about 2.3.
constexpr int kClippedGrey = 250;

struct SimDisparitySet {
  std::vector<RectifiedSample> light_off, lit;
  std::vector<std::string> log;  // what the Separator learned and used, one line per burst
};

// Renders, learns, separates and rectifies. Throws what loading the config or learning throws.
SimDisparitySet renderSimDisparitySet(const SimDisparitySetOptions& options);

// Runs one matcher over samples and sums its scores.
DisparityScore scoreMatcher(const DisparityOptions& options, const std::vector<RectifiedSample>& samples);

}  // namespace embedded_calibration_stereo::core
