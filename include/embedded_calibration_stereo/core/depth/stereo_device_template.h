#pragma once
// Where the Separator's device template (both cameras) comes from and when it is used
// (docs/nodelets.md#separator): taught by averaging light-on frames (device_template teach), or
// learned from each light burst (learn), replacing the template in use only when it separates
// the burst better; and which frames are separated at all.
//
// Threading: StereoSeparator is immutable (frames keep their own reference and separate on any
// thread); StereoTemplateTeach and DeviceLearningPlan are not thread-safe (one owner);
// learnStereoDevice is a pure function of its arguments (the Separator's learning worker).
#include <opencv2/core.hpp>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/device_image_learner.h"
#include "embedded_calibration_stereo/core/depth/separator.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"

namespace embedded_calibration_stereo::core {

// Both cameras' separators, immutable once built.
struct StereoSeparator {
  StereoSeparator(const SeparatorOptions& options, DeviceTemplate left_template, DeviceTemplate right_template)
      : left(options, std::move(left_template)), right(options, std::move(right_template)) {}
  ImageSeparator left, right;
  uint32_t epoch() const { return left.deviceTemplate().calibration_epoch; }
};

// What becomes of a frame on its way to image_scene.
enum class SceneRoute {
  kSeparate,       // separated with the template in use
  kLightOff,       // passed through: no device in it
  kLightChanging,  // passed through: light on but not settled (mixed frames)
  kNoTemplate,     // passed through: no template yet
  kOtherEpoch,     // passed through: the template is of another calibration epoch
};
// `separator`: the template in use (null: none); `epoch_must_match`: a template of another
// calibration epoch than the frame's is not used (taught templates with reteach_on_epoch_change;
// a learned one stays in use until the next burst replaces it).
SceneRoute routeFrame(bool light_on, bool settled, const StereoSeparator* separator, uint32_t frame_epoch,
                      bool epoch_must_match);

// device_template teach: the mean of `frames` settled light-on frames of one calibration epoch,
// each minus its scene when given (the simulator's truth), else as it is (the scene covered).
class StereoTemplateTeach {
 public:
  StereoTemplateTeach(int frames, const SeparatorOptions& options) : frames_(frames), options_(options) {}

  // Starts a teach over; it takes the epoch of its first frame.
  void start();
  // Starts a teach for `epoch` unless one for it is under way. True when it started one.
  bool startFor(uint32_t epoch);
  bool active() const { return active_; }
  uint32_t epoch() const { return epoch_; }
  int framesNeeded() const { return frames_; }

  struct Step {
    bool restarted = false;  // the frame was of another epoch: the teach started over with it
    std::shared_ptr<const StereoSeparator> taught;  // the teach's result once complete (it then ends)
  };
  // Adds a frame of `epoch` to the teach under way (`*_scene` empty: the frame itself is the
  // device). CV_8UC1 or CV_8UC3, one size. Throws std::invalid_argument when the complete teach
  // cannot make a separator; the teach ends either way.
  Step add(const cv::Mat& left, const cv::Mat& right, const cv::Mat& left_scene, const cv::Mat& right_scene,
           uint32_t epoch);

 private:
  void restart(uint32_t epoch);
  const int frames_;
  const SeparatorOptions options_;
  bool active_ = false;
  uint32_t epoch_ = 0;
  int count_ = 0;
  cv::Mat left_sum_, right_sum_;  // CV_64F
};

// The light-on frames of one camera a template learned from the burst's ends did not see (at
// most 3, evenly spaced; all of them for a burst no longer than its ends).
std::vector<cv::Mat> middleFrames(const WindowFrames& frames, int per_end);

// Both cameras' device images learned from one burst, and how they compare with the template
// in use.
struct StereoLearnResult {
  LearnedDevice left, right;
  std::shared_ptr<const StereoSeparator> separator;  // built from them
  // What the new template and the one in use leave of the device on the burst's middle frames
  // (left + right; negative: not scored, no template in use).
  double residual_new = -1.0, residual_in_use = -1.0;
  std::string error;  // non-empty: learning failed
};

// The learner's options for the Separator's templates: the window's (windowLearnerOptions),
// with the flow ending at a quarter of the resolution instead of half. The separated frames are
// as good and the learning takes half the CPU (docs/core.md). The window tracker keeps half:
// there the calibrations committed after a drift were worse with a quarter.
DeviceLearnerOptions separatorLearnerOptions();

// Learns both cameras from a burst (one after the other, each one's pairs in parallel): its
// `per_end` light-on frames nearest each end when `whole` (a burst that ended), all of them
// otherwise (a burst under way); scores the result against `in_use` (when given) on the middle
// frames. Never throws.
StereoLearnResult learnStereoDevice(const WindowFrames& left, const WindowFrames& right, bool whole, int per_end,
                                    const DeviceLearnerOptions& options, const SeparatorOptions& separator_options,
                                    const std::shared_ptr<const StereoSeparator>& in_use, uint32_t epoch);

// device_template learn: when a burst's device image is learned and when it replaces the template
// in use.
class DeviceLearningPlan {
 public:
  explicit DeviceLearningPlan(int per_end) : per_end_(per_end) {}
  // Before the first template, the burst under way is learned from its first 2 * per_end light-on
  // frames (with the light-off frame before it), so that the rest of the first burst is
  // separated. `light_on_frames`: its settled light-on frames kept so far.
  bool learnUnderWay(int light_on_frames, bool light_off_before) const;
  // A run's result replaces the template in use unless it separates the burst's middle frames
  // worse than it (a template of the device as it was leaves its edges).
  bool adopt(const StereoLearnResult& result) const;
  // `adopt` said yes and the result is in use.
  void adopted() { has_template_ = true; }
  bool hasTemplate() const { return has_template_; }
  int perEnd() const { return per_end_; }

 private:
  const int per_end_;
  bool has_template_ = false;
};

}  // namespace embedded_calibration_stereo::core
