#pragma once
// Tracking a whole calibration window at once, with no still scene (ROS-free).
//
// The device's boards do not move during a window; the scene does (the head drives, people
// walk). Tracking each light-on frame on its own leaves the scene's pull on every corner, and
// that pull is nearly the same in all frames of a window (the scene moves little in a fraction
// of a second), so more frames do not average it out and the calibrator turns it into
// calibration error. Instead, per camera:
//  1. the device image I_C of this window is learned from its (light-off, light-on) pairs
//     (device_image_learner.h: the light-off frame aligned to the light-on frame by optical
//     flow, the pairs combined per pixel robustly): what stays put while the scene moves. Each
//     light-on frame is paired with the light-off frames on its nearer side (the first half of
//     the window with those before it, the second half with those after): the scene moved less
//     in between, so the flow is better, and it takes half the time of pairing every frame with
//     both sides (bench_calibrate_moving, docs/figures.md). The first alignment pass, which only
//     has to remove the pattern for the next pass's flow, uses the pairs closest in time;
//  2. the boards are tracked on I_C, which shows no scene (CameraTracker::trackSceneFree; the
//     board geometry is verified there, so no id can slip);
//  3. every corner is refined by a blurred-saddle model fit on I_C (saddle_refinement.h), free of
//     the sub-pixel bias of cv::cornerSubPix that would otherwise be the same in every window.
// The result is one observation per window, whose corner errors are independent from corner to
// corner (docs/figures.md measures them on drive_photo). Given a guide calibration, the
// observation also carries the scene correspondences of the window's light-off frames
// (scene_matches.h): epipolar constraints at every depth for the calibrator, taken under the
// same calibration as the boards.
//
// Threading: not thread-safe (one owner thread, e.g. the tracker nodelet's worker). Inside
// track(), each camera's device image is learned with its light pairs in parallel, one camera
// after the other (the learner holds every pair's sample); the corners of both cameras are then
// found in parallel.
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/scene_consistency.h"
#include "embedded_calibration_stereo/core/calibration/scene_matches.h"
#include "embedded_calibration_stereo/core/depth/device_image_learner.h"
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"
#include "embedded_calibration_stereo/core/tracker/saddle_refinement.h"

namespace embedded_calibration_stereo::core {

// The device image learner's options a window is learned with by default.
DeviceLearnerOptions windowLearnerOptions();

struct WindowTrackerOptions {
  // Its readiness fields are not used (a window is what it is). By default the first alignment
  // pass uses the two pairs closest in time only (with a light-off frame on each side: the
  // light-on frame nearest each), whose scene moved least, and the flow's variational refinement
  // runs 2 iterations instead of DIS's medium preset's 5: faster, and the corners are no worse
  // (docs/figures.md).
  DeviceLearnerOptions learner = windowLearnerOptions();
  SaddleFitOptions saddle;       // radius_px is set per corner from the board's square size
  // Saddle window half-size as a fraction of the local square side, clamped to [2, max] px.
  double saddle_radius_squares = 0.45;
  int max_saddle_radius_px = 8;
  int min_light_on_frames = 3;   // fewer: no observation (a verification flash is one frame)
  // The light-off frames' scene correspondences (with a guide calibration only).
  bool scene_matches = true;
  SceneMatchOptions matching;
  // The matches of the light-off frames before the window and of those after it are compared
  // (scene_consistency.h); when the rig changed between them (a knock during the burst) the
  // window carries none: they would pull its solve between two rigs. Not with check_scene_sides
  // false.
  bool check_scene_sides = true;
  SceneConsistencyOptions scene_sides;
  // The boards do not move during a burst unless the camera does (a zoom step, a knock); a
  // device image learned from a burst during which they moved mixes two rigs, and a calibration
  // solved on it lies between them (its corners can be more than half a square from either).
  // The burst's first and last light-on frames are tracked on their own, each against the
  // light-off frame next to it; when one board's corners moved between them by more than
  // max_board_motion_px on average (in either camera), the window carries nothing. Both sides
  // need light-off frames; the check costs four single-frame trackings.
  bool check_board_motion = true;
  double max_board_motion_px = 0.5;
  // Empty when usable; otherwise one message per problem, joined by "; ".
  std::string validate() const;
};

// One camera's frames of one window: the settled light-on frames in time order, and the settled
// light-off frames taken before the window (e.g. the last one) and after it (the first one), in
// time order; either side may be empty, not both (both are far better: the scene moves one way
// only).
// CV_8UC1 or CV_8UC3 (BGR), all of one size and type.
struct WindowFrames {
  std::vector<cv::Mat> light_off_before, light_off_after, light_on;
};

// Learns one camera's device image I_C from its frames of one window (step 1 above): each
// light-on frame paired with the light-off frames on its nearer side. `options`' readiness
// fields are not used. Throws std::invalid_argument when the frames give fewer than 2 pairs or
// differ in size or type.
LearnedDevice learnWindowDevice(const WindowFrames& frames, const DeviceLearnerOptions& options);

// The window with only its `per_end` light-on frames nearest each end (all of them when it has
// no more than 2 * per_end), those that learnWindowDevice pairs with the light-off frames closest
// in time: learning a whole burst's device image for a fraction of the cost, for uses that need
// less than the tracker's precision (the Separator's template). per_end >= 1.
WindowFrames windowEnds(const WindowFrames& frames, int per_end);

struct WindowTrack {
  StereoObservation observation;  // corners of both cameras, stamped by the caller
  cv::Mat device[2];              // the learned I_C per camera (CV_32F, grey levels); empty if boards_moved
  int corners_tracked = 0;        // on I_C before the saddle fit
  int saddle_failures = 0;        // corners dropped because their saddle fit failed
  std::string scene_problem;      // why there are no scene correspondences (a problem of set-up); empty otherwise
  SceneConsistency scene_sides;   // the two sides' matches compared; not consistent: the window carries none
  // The burst's ends compared (check_board_motion): the largest mean displacement of one board's
  // corners between its first and last light-on frames, over both cameras. boards_moved: above
  // max_board_motion_px; the window is then neither learned nor tracked further: no device
  // images, no corners, no scene correspondences.
  bool board_motion_checked = false;
  double board_motion_px = 0.0;
  bool boards_moved = false;
};

class WindowTracker {
 public:
  // Throws ConfigError on an invalid prior or options. `guide`: a calibration close to the
  // head's (the nominal one will do: it only guides the scene matching's search); without it
  // the observations carry no scene correspondences.
  WindowTracker(const PatternPrior& prior, const TrackerOptions& tracker_options,
                const WindowTrackerOptions& options, std::optional<StereoRig> guide = std::nullopt);

  // Tracks one window. Throws std::invalid_argument when a camera has no light-off frame, fewer
  // than min_light_on_frames light-on frames, or frames of different sizes or types.
  WindowTrack track(const WindowFrames& left, const WindowFrames& right, double stamp);
  // Forget the boards' tracked state (the next window starts from the prior).
  void reset() { tracker_.reset(); }
  const WindowTrackerOptions& options() const { return options_; }

 private:
  // The light-off frames' scene correspondences into result->observation (with a guide only).
  void matchScene(const WindowFrames& left, const WindowFrames& right, WindowTrack* result);
  // Sets result->board_motion_* (and boards_moved) from the burst's first and last light-on
  // frames, tracked apart, without touching the tracker's state; no check when a side lacks
  // light-off frames.
  void checkBoardMotion(const WindowFrames* frames[2], WindowTrack* result);

  PatternTracker tracker_;  // its own board states, followed from window to window
  WindowTrackerOptions options_;
  std::optional<StereoRig> guide_;
  SceneMatchBuffers scene_buffers_;
};

// Refines tracked corners by the saddle fit on `image` (CV_32FC1 or CV_8UC1, scene-free); the
// lines through each corner come from its tracked neighbours. A corner whose fit fails, or
// that has no neighbour along a line, is dropped. Returns how many were dropped.
int refineCornersBySaddleFit(const cv::Mat& image, const CameraPrior& prior, const WindowTrackerOptions& options,
                             std::vector<BoardCorners>* boards);

}  // namespace embedded_calibration_stereo::core
