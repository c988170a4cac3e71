#pragma once
// Learning the device image I_C of one camera during normal operation, with no covered scene and
// no simulator truth: from light-on frames and the light-off frames taken around them while the
// head moves and the scene changes.
//
// Model. A light-off frame is g_off * S(t_off), a light-on frame g_on * (S(t_on) + I_C) (S: the
// scene seen through the half-mirror, g: the exposure gain, which the auto-exposure changes
// between the two frames). The boards are fixed in the image; the scene is not. For each pair
// (light-off, light-on) a few frames apart:
//  1. the light-off frame is aligned to the light-on one by dense optical flow (DIS), computed
//     against the light-on frame with the current estimate of I_C subtracted, so the lit pattern
//     (static, absent from the light-off frame) does not pull the flow to zero;
//  2. the gains are fitted: on = k * off_aligned + s * I_C (least squares, trimmed), and the
//     pair's sample of I_C is (on - k * off_aligned) / s;
//  3. per pixel, the samples of all pairs are combined robustly: the median, then the mean of the
//     samples within `inlier_threshold` of it. A sample far from the median is where the scene
//     moved (a mover, an occlusion edge, parallax the flow missed) and is left out.
// The first pass has no estimate of I_C: it takes the per-pixel median of unaligned differences,
// then `iterations` passes of 1-3 refine it (the first of them, optionally, with the pairs
// closest in time only: first_pass_pairs). The scale of I_C is the median pair's light-on gain;
// the Separator's per-tile alpha absorbs the rest.
//
// Confidence: per pixel, the number of inlier samples (`support`) and the standard error of the
// estimate (the inliers' spread / sqrt(count)). Ready when at least `min_pairs` pairs were used
// and `min_coverage` of the pixels have `min_inliers` inliers and a standard error at most
// `max_standard_error` grey levels. The pair count matters most under motion: each window adds
// independent scene errors that the per-pixel combination averages out (docs/figures.md).
//
// Zoom, focus and knocks move the device image: pairs are only combined within one calibration
// epoch. The caller (the Separator nodelet) starts a new set of pairs at each epoch change.
//
// Board geometry is not used: the device image is whatever stays put while the scene moves.
//
// Threading: LightPairSet is not thread-safe (one owner thread). learnDeviceImage() is a pure
// function of its arguments (the pairs' images are never written after being added, so a
// snapshot of the set may be learned on another thread while the owner adds more pairs).
#include <opencv2/core.hpp>
#include <cstdint>
#include <deque>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/separator.h"

namespace embedded_calibration_stereo::core {

struct DeviceLearnerOptions {
  int max_pairs = 24;               // pairs kept (the oldest are dropped), >= min_pairs
  int min_pairs = 12;               // readiness: pairs used, >= 2 (the Separator: 4 per window)
  int min_inliers = 3;              // readiness: inlier samples a pixel needs, >= 1
  double min_coverage = 0.99;       // readiness: fraction of pixels meeting both, (0, 1]
  double max_standard_error = 3.0;  // readiness: per pixel, grey levels, > 0
  int iterations = 2;               // alignment passes after the unaligned first pass, 0..5
  double inlier_threshold = 6.0;    // grey levels from the per-pixel median, > 0
  // The first alignment pass uses only this many pairs (0: all), those whose two frames are the
  // fewest frames apart (LightPair::frames_apart): the scene moved least between them, so their
  // flow is the most reliable, and that pass's estimate only serves to remove the pattern for
  // the next pass's flow. The later passes use every pair.
  int first_pass_pairs = 0;
  // Variational refinement iterations per pyramid level of the flow (DIS; its medium preset has 5).
  int flow_refinement_iterations = 5;
  // The flow's finest pyramid level: 0 full resolution, 1 half (DIS's medium preset), 2 a
  // quarter, ...; DIS interpolates the flow up from there. Each level finer costs about 4 times.
  int flow_finest_scale = 1;
  // Pixels between the flow's patches, < 8 (DIS's medium preset: 3, with patches 8 wide). A
  // sparser lattice has fewer patches to search and fewer overlaps to blend.
  int flow_patch_stride = 3;
  // Of the pairs that share a light-off frame (a burst's), the aligned passes compute the flow of
  // every flow_pair_step-th by frames apart (and of the last) and interpolate it in time for the
  // pairs between; 1: every pair's own. Needs the pairs' frames_apart.
  int flow_pair_step = 1;
  // Pairs in parallel (a DIS instance and a pair's working images per thread), or one after the
  // other with each flow, remap and combination parallel inside: a third less memory at the peak,
  // and OpenCV's parallel region (one at a time per process: another thread's parallel loop
  // started meanwhile runs serially) held a few milliseconds at a time rather than for a whole
  // pass, at the cost of more CPU.
  bool parallel_pairs = true;
  // Empty when usable; otherwise one message per problem, joined by "; ".
  std::string validate() const;
};

// One light-off frame and one light-on frame of one camera, a few frames apart.
struct LightPair {
  cv::Mat light_off, light_on;  // CV_8UC1 or CV_8UC3, one size and type; never written after
  int frames_apart = 0;         // frame periods between the two (0: not known)
};

// The pairs of one camera under one calibration epoch.
class LightPairSet {
 public:
  explicit LightPairSet(int max_pairs = 24) : max_pairs_(max_pairs) {}
  // Starts over (a new calibration epoch).
  void reset(uint32_t epoch);
  // Keeps references to both images (the caller must not write them afterwards). Throws
  // std::invalid_argument on an empty image, an unsupported type, or a size or type different
  // from the pairs already held.
  void add(const cv::Mat& light_off, const cv::Mat& light_on, int frames_apart = 0);
  std::vector<LightPair> snapshot() const { return {pairs_.begin(), pairs_.end()}; }
  int size() const { return static_cast<int>(pairs_.size()); }
  uint32_t epoch() const { return epoch_; }

 private:
  int max_pairs_;
  uint32_t epoch_ = 0;
  std::deque<LightPair> pairs_;
};

struct LearnedDevice {
  DeviceTemplate device_template;  // I_C (frames_averaged = pairs used) and the epoch
  cv::Mat support;                 // CV_8U: inlier samples per pixel
  cv::Mat standard_error;          // CV_32F: grey levels per pixel
  double coverage = 0.0;           // fraction of pixels meeting the readiness criterion
  int pairs = 0;
  bool ready = false;
  std::string summary() const;     // e.g. "12 pairs, coverage 99.6 %, ready"
};

// Learns I_C from the pairs (all of one camera). Throws std::invalid_argument on invalid options,
// fewer than 2 pairs or pairs of different sizes or types.
LearnedDevice learnDeviceImage(const std::vector<LightPair>& pairs,
                               const DeviceLearnerOptions& options, uint32_t epoch);

}  // namespace embedded_calibration_stereo::core
