#pragma once
// Confirms the calibration light's state from the images themselves, for heads whose cameras
// run under a driver we did not write: its latency between a light command and the exposure is
// unknown, and a frame exposed while the light changed must never be used.
//
// Each camera's frames are reduced to one number, the mean grey level of the device's regions
// (the taught board regions of the tracker's prior; the whole image when none are taught). The
// lit device adds a step to it. A frame is SETTLED when its level equals both neighbours' (within
// `plateau_fraction` of the step): a frame exposed while the light changed differs from the
// frame before or after it, so the frames on both sides of every change are unsettled. The
// state of a settled frame follows from the previous plateau with hysteresis: a rise of at least
// `switch_fraction` of the light's step (min_step before a step has been measured) switches it
// on, a fall of as much switches it off, anything smaller is the scene changing. Deciding a frame
// needs the next one, so the decision comes one frame late.
//
// Assumptions (docs/external_driver.md): the light is off when confirmation starts (the first
// plateau is taken as "off"), and the scene does not jump in brightness by half the light's step
// between two frames (a sudden change smaller than that is absorbed; a larger one while the
// light is off reads as the light switching on, and the light watch reports the mismatch when the
// light is commanded).
//
// Threading: plain values; each object is used by one thread at a time.
#include <opencv2/core.hpp>
#include <optional>
#include <string>

#include "embedded_calibration_stereo/core/tracker/board_prior.h"
#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo::core {

struct LightConfirmationOptions {
  // Smallest change of a camera's level (grey levels) taken as the light switching, until the
  // light's own step has been measured at a switch.
  double min_step = 8.0;
  // A switch: a change between two plateaus of at least this fraction of the measured step.
  double switch_fraction = 0.5;
  // A plateau: a frame differs from both neighbours by at most this fraction of the step
  // (of min_step before a step has been measured).
  double plateau_fraction = 0.05;
  // Empty when usable; otherwise a message naming the bad field.
  std::string validate() const;  // problem().text()
  ConfigProblem problem() const;
};

// The light as confirmed for one frame.
struct ConfirmedLight {
  bool light_on = false;  // the images show the device lit
  bool settled = false;   // and the light did not change during this frame or next to it
};

// Mean grey level of `image` (CV_8UC1 or CV_8UC3, channels averaged) inside `mask` (CV_8UC1,
// same size, non-zero = inside), or of the whole image when `mask` is empty.
double regionLevel(const cv::Mat& image, const cv::Mat& mask);

// The device's regions in one camera from its taught prior: every board's quadrilateral,
// `margin_squares` squares beyond its outer corners (the boards move a little with zoom and
// focus), filled into a CV_8UC1 mask of the prior's image size. Empty for a prior without boards.
cv::Mat boardRegionMask(const CameraPrior& prior, double margin_squares = 1.5);

// One camera: a level per frame in, the confirmed light of the previous frame out.
class LightLevelTracker {
 public:
  explicit LightLevelTracker(const LightConfirmationOptions& options = LightConfirmationOptions());

  // Adds the next frame's level; returns the decision for the frame before it (nothing for the
  // very first frame).
  std::optional<ConfirmedLight> push(double level);
  // The level changes its meaning from the next push (other regions): forgets levels, step and
  // state; frames are unsettled until the next switch shows the state again (a rise: on).
  void forgetLevels();

  bool lightOn() const { return on_; }
  // False after forgetLevels() until the next switch.
  bool known() const { return known_; }
  // The light's step measured at the switches (grey levels); 0 before the first switch.
  double step() const { return step_; }

 private:
  ConfirmedLight decide(double before, bool have_before, double level, double after);

  LightConfirmationOptions options_;
  int pending_ = 0;                    // levels held: 0, 1 (level_) or 2 (before_, level_)
  double before_ = 0.0, level_ = 0.0;  // the frames before and of the undecided frame
  std::optional<double> plateau_;      // level of the last settled frame
  bool on_ = false;  // off at the start: the first plateau is taken as "off"
  bool known_ = true;
  double step_ = 0.0;
};

// Both cameras of a stereo frame; a frame is settled only when both cameras are, on the same state.
class StereoLightConfirmer {
 public:
  explicit StereoLightConfirmer(const LightConfirmationOptions& options = LightConfirmationOptions());

  std::optional<ConfirmedLight> push(double left_level, double right_level);
  void forgetLevels();
  bool known() const { return left_.known() && right_.known(); }
  const LightLevelTracker& left() const { return left_; }
  const LightLevelTracker& right() const { return right_; }

 private:
  LightLevelTracker left_, right_;
};

// Checks that a commanded light does what it is told: once the command has had
// `max_delay_frames` frames to take effect (plus the frames the confirmation needs), a settled
// frame must show the commanded state.
class LightCommandWatch {
 public:
  explicit LightCommandWatch(int max_delay_frames) : max_delay_frames_(max_delay_frames) {}
  // Once per stereo frame: the commanded state when it arrived, and the light confirmed for the
  // frame decided at the same time (if any).
  void update(bool commanded_on, const std::optional<ConfirmedLight>& confirmed);
  // Empty while the light obeys; otherwise what is wrong, in words.
  const std::string& fault() const { return fault_; }

 private:
  int max_delay_frames_;
  bool commanded_on_ = false;
  long frames_since_command_ = 0;
  bool agreed_ = true;  // a settled frame has shown the commanded state since the command
  std::string fault_;
};

}  // namespace embedded_calibration_stereo::core
