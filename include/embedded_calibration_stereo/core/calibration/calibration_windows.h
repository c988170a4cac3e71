#pragma once
// The OnlineCalibrator's calibration windows: which frames' board observations belong to the
// open window (a frame's calibration_mode says light_on && settled, matched with its observation
// by stamp), when a window closes (the light goes off, or no settled frame came for
// window_timeout_s), what a time jump of the driver's stamps forgets, and the window of a
// recalibration request. With window_observations, the tracker's whole-burst observations are
// the automatic windows instead. docs/nodelets.md, "OnlineCalibrator".
//
// Stamps are the messages' header stamps in nanoseconds (exact: a frame is matched by equal
// stamps); wall times (the idle window's age) are seconds from any fixed origin.
//
// Threading: not thread-safe; the owner guards it with its own mutex.
#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/repeated_observations.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"

namespace embedded_calibration_stereo::core {

using StampNs = int64_t;  // a header stamp, nanoseconds; 0: none

// `stamp` in seconds, rounded as ros::Time::toSec() rounds it.
double stampSeconds(StampNs stamp);

struct CalibrationWindowOptions {
  bool auto_calibrate = true;        // the automatic windows are solved
  bool window_observations = false;  // the automatic windows are whole-burst observations
  int min_frames = 5;                // an automatic window with fewer frames is not solved
  int max_frames = 30;               // frames kept per automatic window (the first ones)
  double window_timeout_s = 5.0;     // an automatic window with no frame added for this long ends
  double stamp_tolerance_s = 2.0;    // calibration_mode going back further is a time jump
  size_t kept_frames = 64;           // modes and unmatched observations remembered
};

// One frame's calibration_mode.
struct FrameMode {
  StampNs stamp = 0;
  bool light_on = false;
  bool settled = false;
  uint32_t epoch = 0;  // its calibration_epoch
};

// A frame remembered: whether it belongs to a window, and its calibration epoch.
struct FrameSeen {
  StampNs stamp = 0;
  bool calibrating = false;  // light_on && settled
  uint32_t epoch = 0;
};

// What a calibration_mode message did.
struct ModeResult {
  enum class Kind {
    kDuplicate,  // a second message of a stamp: ignored
    kLate,       // older than the newest frame (within the tolerance): kept for matching only
    kCurrent,    // the newest frame: its epoch is the one in force
  };
  Kind kind = Kind::kCurrent;
  // Set when the stamp went back by more than stamp_tolerance_s: the newest stamp before the
  // jump. Every frame remembered was forgotten (another timeline) and the window restarted.
  std::optional<StampNs> time_jump_from;
  // The window the light going off closed, when it is to be solved.
  std::optional<std::vector<StereoObservation>> solve;
};

// What became of a per-frame observation.
enum class ObservationFate {
  kBackwards,  // its stamp is not after the previous observation's: dropped (counted)
  kNoBoard,    // nothing seen: nothing to add
  kMatched,    // its frame's mode was known: added to the window when the frame calibrates
  kPending,    // its mode has not come yet: kept (the newest kept_frames) until it does
};

// What became of a whole-burst (window) observation.
enum class WindowObservationFate {
  kRepeated,    // a copy of one seen recently: it teaches nothing new
  kBackwards,   // its stamp is not after the previous window observation's (counted)
  kForRequest,  // the burst of the running request: kept for takeRequestWindow()
  kIgnored,     // auto_calibrate off, or nothing seen
  kSolve,       // an automatic window: solve it
};

// Why an idle window ended the way it did (endIdleWindow()).
enum class IdleWindowEnd {
  kSolving,                    // solved
  kWindowObservationsInstead,  // not solved: window observations are solved instead
  kTooFewFrames,               // not solved: fewer than min_frames
  kAutoCalibrateOff,           // not solved: auto_calibrate is off
};

struct IdleWindow {
  double idle_s = 0.0;  // since a frame was last added
  size_t frames = 0;    // in the window
  IdleWindowEnd end = IdleWindowEnd::kSolving;
  std::vector<StereoObservation> solve;  // its frames when end == kSolving
};

class CalibrationWindows {
 public:
  explicit CalibrationWindows(CalibrationWindowOptions options);

  // A frame's calibration_mode; `now_s`: the wall time (a frame it matches is added now).
  ModeResult addMode(const FrameMode& mode, double now_s);

  // A frame's board observation (its stamp: `stamp`), added to the open window when its mode
  // says it calibrates and the window has room (max_frames, or the request's frames). `previous`
  // (optional) receives the previous observation's stamp, for the caller's warning.
  ObservationFate addObservation(StereoObservation observation, StampNs stamp, double now_s,
                                 StampNs* previous = nullptr);

  // A whole-burst observation stamped `stamp`. `*solve` receives it for kSolve; `previous` as
  // for addObservation().
  WindowObservationFate addWindowObservation(StereoObservation observation, StampNs stamp,
                                             std::optional<StereoObservation>* solve, StampNs* previous = nullptr);

  // An automatic window to which no frame was added for window_timeout_s (wall time `now_s`)
  // ends; nothing when none is open, a request runs, or it is younger.
  std::optional<IdleWindow> endIdleWindow(double now_s);

  // A recalibration request starts collecting `frames` frames from the newest frame on (the open
  // automatic window is dropped); with window_observations it also waits for its burst's
  // whole-burst observation (stamped after the request started).
  void startRequest(size_t frames);
  // True while a request collects and its window holds its frames.
  bool requestFull() const { return request_active_ && window_.size() >= request_frames_; }
  // Ends the request's collection: its frames (the window, closed at the newest frame).
  std::vector<StereoObservation> endRequest();
  // True when the request's whole-burst observation came.
  bool hasRequestWindow() const { return request_window_.has_value(); }
  // The request's whole-burst observation, if it came; it is no longer waited for.
  std::optional<StereoObservation> takeRequestWindow();
  // The request is over, however it ended.
  void requestDone();

  // A calibration/health verdict stamped `stamp_s`; below GOOD (`rig_changed`) says the rig
  // changed since then.
  void noteHealthVerdict(bool rig_changed, double stamp_s);
  // The newest health verdict below GOOD (stamp, s), if any: what a solve must not take from
  // earlier windows.
  std::optional<double> healthProblemS() const { return health_problem_s_; }

  // The frames remembered (the newest kept_frames), oldest first.
  const std::deque<FrameSeen>& frames() const { return frames_; }
  // Frames in the open window.
  size_t windowSize() const { return window_.size(); }
  // Observations and window observations dropped for a stamp not after the previous one.
  uint64_t backwards() const { return backwards_; }
  // Window observations accepted.
  uint64_t windowObservations() const { return window_observations_; }

 private:
  // The automatic windows of per-frame observations are solved (not when window observations are).
  bool solvesFrameWindows() const { return options_.auto_calibrate && !options_.window_observations; }
  bool stampAfterPrevious(StampNs stamp, StampNs* last);
  void addToWindow(StereoObservation observation, StampNs stamp, bool calibrating, double now_s);
  void forgetAfterTimeJump();
  void closeAtNewestFrame();

  CalibrationWindowOptions options_;
  std::deque<FrameSeen> frames_;
  std::deque<std::pair<StampNs, StereoObservation>> pending_;  // observations waiting for their mode
  std::vector<StereoObservation> window_;
  StampNs window_closed_at_ = 0;  // frames up to this stamp belong to a finished window
  double last_window_frame_s_ = 0.0;  // wall time a frame was last added to window_
  StampNs last_observation_ = 0, last_window_observation_ = 0;  // newest accepted (0: none yet)
  uint64_t backwards_ = 0, window_observations_ = 0;
  RepeatedObservations repeated_windows_;  // the latest window observations' contents
  bool request_active_ = false;  // a request is collecting its window
  size_t request_frames_ = 0;
  bool request_wants_window_ = false;  // its whole-burst observation (stamped after request_started_)
  StampNs request_started_ = 0;
  std::optional<StereoObservation> request_window_;
  std::optional<double> health_problem_s_;
};

}  // namespace embedded_calibration_stereo::core
