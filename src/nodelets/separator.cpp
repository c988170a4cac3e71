// Separator nodelet: removes the lit calibration device from calibration-mode frames so that
// depth keeps running while the light is on (core/separator.h does the work).
//
// Lazy: the inputs are subscribed only while someone subscribes to left|right/image_scene, a
// teach is running or, with device_template learn, until the first template (lazy_synced_input.h).
// Per stereo frame (left|right/image_raw and calibration_mode, ExactTime, or ApproximateTime with
// approximate_sync):
//  - light off, or light on but not settled (mixed frames), or no template taught for the
//    frame's calibration epoch: the incoming message pointers are republished unchanged on
//    left|right/image_scene (zero-copy; depth never stops; a missing template is warned about);
//  - light on and settled: the separated images, in new messages with the raw headers.
//
// Where I_C (the device image) comes from, parameter device_template:
//  - learn (default): learned from every light burst (at least 3 settled light-on frames between
//    settled light-off frames; core/tracker/window_tracker.h learnWindowDevice): its
//    learn_frames_per_end light-on frames nearest each end, paired with the light-off frame on
//    their side, on a worker thread when the burst ends. No covering, no truth. Each burst's
//    result replaces the template in use when it separates the burst's middle light-on frames
//    (not learned from) with less of the device left (core separationResidual): bursts come when
//    the calibration may have changed (zoom, focus and knocks move the device image), and a
//    template of the device as it was leaves its edges. Before the first template, the first learn_frames_per_end * 2 light-on frames
//    of the burst under way are learned at once (paired with the light-off frame before it), so
//    that the rest of the first burst is separated too. A new calibration does not stop the
//    separation: the template stays in use until the next burst's replaces it.
//  - teach, on hardware: the `teach` service averages the next teach_frames light-on settled
//    frames; the scene must be covered (or dark) meanwhile (a factory step). A template taught
//    under another calibration epoch is not used (reteach_on_epoch_change; teach again);
//  - teach, for tests of other components only (teach_from_ground_truth): I_C is the mean over
//    teach_frames light-on settled frames of I_E - ground_truth image_scene of the same stamp,
//    taught at the first light-on frames and at each epoch change. No product launch file sets
//    it.
// Diagnostics (StageDiagnostics): rates, latency, mode (passthrough and why, or separating),
// method, template source and epoch, the last learning result (learn) and input copies (must
// stay 0).
#include <cv_bridge/cv_bridge.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <algorithm>
#include <chrono>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/core/depth/device_image_learner.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"
#include "embedded_calibration_stereo/core/depth/separator.h"
#include "embedded_calibration_stereo/core/geometry/config_error.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/lazy_synced_input.h"
#include "embedded_calibration_stereo/ros/light_burst.h"
#include "embedded_calibration_stereo/ros/output_image.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/stage_diagnostics.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

namespace {

using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

// Both cameras' separators, immutable once built (frames keep their own reference).
struct StereoSeparator {
  StereoSeparator(const ecs::SeparatorOptions& options, ecs::DeviceTemplate left_template,
                  ecs::DeviceTemplate right_template)
      : left(options, std::move(left_template)), right(options, std::move(right_template)) {}
  ecs::ImageSeparator left, right;
  uint32_t epoch() const { return left.deviceTemplate().calibration_epoch; }
};

// Running sum of device frames of one teach (both cameras), CV_64F.
struct TeachAccumulator {
  bool active = false;
  uint32_t epoch = 0;
  int frames = 0;
  cv::Mat left_sum, right_sum;
};

// Adds `image - scene` (scene may be empty: the frame itself) to `sum`.
void accumulate(const cv::Mat& image, const cv::Mat& scene, cv::Mat* sum) {
  cv::Mat device;
  image.convertTo(device, CV_64F);
  if (!scene.empty()) {
    cv::Mat scene64;
    scene.convertTo(scene64, CV_64F);
    device -= scene64;  // noise may make it negative: kept, so the mean stays unbiased
  }
  if (sum->empty()) {
    *sum = device;
  } else {
    *sum += device;
  }
}

ecs::DeviceTemplate templateFrom(const cv::Mat& sum, int frames, uint32_t epoch) {
  ecs::DeviceTemplate templ;
  sum.convertTo(templ.device, CV_32F, 1.0 / frames);
  templ.calibration_epoch = epoch;
  templ.frames_averaged = frames;
  return templ;  // default alpha curve (alpha 1): paper_global_alpha without a taught curve
}

// One learning run's result (both cameras), made on the worker thread.
struct LearnResult {
  ecs::LearnedDevice left, right;
  std::shared_ptr<const StereoSeparator> separator;  // built from them
  // What the new template and the one in use leave of the device on the burst's middle frames
  // (left + right; negative: not scored, no template in use).
  double residual_new = -1.0, residual_in_use = -1.0;
  int light_on_frames = 0;  // of the burst, used or not
  bool whole_burst = true;  // false: the first frames of a burst under way
  double stamp = 0.0;       // the burst's last light-on frame used
  std::string error;        // non-empty: the run failed
};

// The light-on frames of one camera a template learned from the burst's ends did not see (at
// most 3, evenly spaced; all of them for a burst no longer than its ends).
std::vector<cv::Mat> middleFrames(const ecs::WindowFrames& frames, int per_end) {
  const int n = static_cast<int>(frames.light_on.size());
  if (n <= 2 * per_end) return frames.light_on;
  std::vector<cv::Mat> middle;
  const int first = per_end, count = n - 2 * per_end, step = std::max(1, count / 3);
  for (int i = first; i < first + count && middle.size() < 3; i += step) middle.push_back(frames.light_on[i]);
  return middle;
}

// Scores the new template and the one in use on the burst's middle frames (both cameras).
void scoreTemplates(const LightBurst& burst, int per_end, const StereoSeparator& in_use, LearnResult* result) {
  result->residual_new = result->residual_in_use = 0.0;
  for (int c = 0; c < 2; ++c) {
    const std::vector<cv::Mat> middle = middleFrames(windowFrames(burst, c), per_end);
    result->residual_new += ecs::separationResidual(c ? result->separator->right : result->separator->left, middle);
    result->residual_in_use += ecs::separationResidual(c ? in_use.right : in_use.left, middle);
  }
}

// Learns both cameras' device images from a burst (worker thread): its per_end light-on frames
// nearest each end when it ended, all of them while it is under way; scores the result against
// the template in use (when there is one).
LearnResult learnBurst(const LightBurst& burst, bool whole, int per_end, const ecs::DeviceLearnerOptions& options,
                       const ecs::SeparatorOptions& separator_options,
                       const std::shared_ptr<const StereoSeparator>& in_use, uint32_t epoch) {
  LearnResult result;
  result.light_on_frames = static_cast<int>(burst.light_on.size());
  result.whole_burst = whole;
  result.stamp = burst.light_on.back().first->header.stamp.toSec();
  try {
    ecs::LearnedDevice learned[2];
    std::string errors[2];
    cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& range) {
      for (int c = range.start; c < range.end; ++c) try {
          ecs::WindowFrames frames = windowFrames(burst, c);
          if (whole) frames = ecs::windowEnds(frames, per_end);
          learned[c] = ecs::learnWindowDevice(frames, options);
          learned[c].device_template.calibration_epoch = epoch;
        } catch (const std::exception& e) {
          errors[c] = (c ? "right: " : "left: ") + std::string(e.what());
        }
    });
    result.error = errors[0].empty() ? errors[1] : errors[0];
    if (!result.error.empty()) return result;
    result.left = std::move(learned[0]);
    result.right = std::move(learned[1]);
    result.separator = std::make_shared<const StereoSeparator>(separator_options, result.left.device_template,
                                                               result.right.device_template);
    if (in_use) scoreTemplates(burst, per_end, *in_use, &result);
  } catch (const std::exception& e) {
    result.error = e.what();
  }
  return result;
}

}  // namespace

// Threads: the nodelet's (single-threaded) callback queue runs onInit, frameCb, truthCb, the
// teach service and the publishers' connect callbacks; state_mutex_ still guards separator_ and
// teach_ so that the class stays correct if it is moved to the multi-threaded handle. The inputs
// (un)subscribe under their own mutex; need() is called outside state_mutex_ (unsubscribing
// waits for a callback of that subscription running on another thread). separator_ points to
// an immutable StereoSeparator: frameCb takes its own reference and separates outside the lock
// (both cameras in parallel, ecs::separateStereo). Published messages are never modified after
// publishing. diagnostics_ reports on a wall timer of the same queue and guards its own counters.
// With device_template learn, the burst collector, the waiting burst, has_template_ and
// learning_ belong to the callback thread; a learning run works on std::async's thread on a
// burst's message pointers (messages are never written after publishing) and hands its result
// back through the future, which only the callback thread reads (unloading waits for a run in
// progress: the future of std::async joins its thread).
class SeparatorNodelet : public GuardedNodelet {
 public:
  SeparatorNodelet() : GuardedNodelet("Separator") {}

 private:
  using FrameInput = LazySyncedInput<Image, Image, CalibrationMode>;
  using TruthInput = LazySyncedInput<Image, Image, CalibrationMode, Image, Image>;


  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const ParameterReader read(pnh);
    const std::string method = read.get("method", "regional_alpha");
    try {
      options_.method = ecs::parseSeparationMethod(method);
    } catch (const std::exception& e) {
      throw ecs::ConfigError("method", e.what());
    }
    teach_from_truth_ = read.get("teach_from_ground_truth", false);  // tests only: implies teach
    learn_ = read.choice("device_template", teach_from_truth_ ? "teach" : "learn", {"teach", "learn"}) == "learn";
    teach_frames_ = read.atLeast("teach_frames", 8, 1);
    if (learn_ && teach_from_truth_)
      throw ecs::ConfigError("teach_from_ground_truth", "applies to device_template teach only, not learn");
    learn_frames_per_end_ = read.inRange("learn_frames_per_end", 4, 1, 30);
    learn_options_ = ecs::windowLearnerOptions();
    reteach_on_epoch_change_ = read.get("reteach_on_epoch_change", true);
    const int queue_size = read.atLeast("queue_size", 5, 1);
    const bool approximate = read.get("approximate_sync", false);

    frames_ = std::make_unique<FrameInput>(
        nh, pnh, FrameInput::Topics{"left/image_raw", "right/image_raw", "calibration_mode"}, approximate, queue_size,
        [this](const auto& left, const auto& right, const auto& mode) { frameCb(left, right, mode); });
    if (teach_from_truth_) {
      // The driver converts ground truth only for listeners: a small cost, only in the sim. The
      // simulator stamps the truth exactly as the frames: always ExactTime. roscpp shares one
      // subscription per topic between both inputs (no second transport of image_raw).
      truth_ = std::make_unique<TruthInput>(
          nh, pnh,
          TruthInput::Topics{"left/image_raw", "right/image_raw", "calibration_mode", "ground_truth/left/image_scene",
                             "ground_truth/right/image_scene"},
          false, queue_size, [this](const auto& l, const auto& r, const auto& m, const auto& lt, const auto& rt) {
            truthCb(l, r, m, lt, rt);
          });
    }
    image_transport::ImageTransport it(nh);
    const auto cb = frames_->imageConnectCallback();
    const auto truth_cb = truth_ ? truth_->imageConnectCallback() : image_transport::SubscriberStatusCallback();
    const auto both_cb = [cb, truth_cb](const image_transport::SingleSubscriberPublisher& p) {
      cb(p);
      if (truth_cb) truth_cb(p);
    };
    left_pub_ = it.advertise("left/image_scene", 2, both_cb, both_cb);
    right_pub_ = it.advertise("right/image_scene", 2, both_cb, both_cb);
    for (LazySubscription* input : inputs()) {
      input->watch(left_pub_);
      input->watch(right_pub_);
    }
    teach_srv_ = pnh.advertiseService("teach", &SeparatorNodelet::teachService, this);  // private, as the tracker's
    diagnostics_ = std::make_unique<StageDiagnostics>(nh, pnh, "separator");
    diagnostics_->set("method", method);
    diagnostics_->set("template epoch", "none (not taught)");
    diagnostics_->set("template source", learn_ ? "learn" : "teach");
    // Subscribed while someone listens; with learn, also until the first template, so that the
    // first burst is seen from its start (before depth has a listener).
    if (learn_) needInputsForTeach(true);
    for (LazySubscription* input : inputs()) input->start();
    if (learn_) {
      NODELET_INFO("Separator: %s, device image learned from each light burst (%d light-on frames of each end), "
                   "%s sync, queue %d",
                   method.c_str(), learn_frames_per_end_, approximate ? "approximate" : "exact", queue_size);
    } else {
      NODELET_INFO("Separator: %s, teach %d frames from %s, %s sync, queue %d", method.c_str(), teach_frames_,
                   teach_from_truth_ ? "ground truth (simulator)" : "the teach service (scene covered)",
                   approximate ? "approximate" : "exact", queue_size);
    }
  }

  // The inputs that exist (the truth only with teach_from_ground_truth).
  std::vector<LazySubscription*> inputs() {
    std::vector<LazySubscription*> out{frames_.get()};
    if (truth_) out.push_back(truth_.get());
    return out;
  }

  // A teach needs frames even when nobody listens to image_scene. Called without state_mutex_.
  void needInputsForTeach(bool teaching) {
    for (LazySubscription* input : inputs()) input->need(teaching);
  }

  void reportError(const std::string& message) {
    if (errors_.shouldReport(message)) NODELET_ERROR("Separator: %s", message.c_str());
  }

  void reportWarning(const std::string& message) {
    if (errors_.shouldReport(message)) NODELET_WARN("Separator: %s", message.c_str());
  }

  // `why`: the mode shown in the diagnostics.
  void publishRaw(const ImageConstPtr& left, const ImageConstPtr& right, const char* why) {
    left_pub_.publish(left);
    right_pub_.publish(right);
    diagnostics_->set("mode", std::string("passthrough (") + why + ")");
    diagnostics_->framePublished(left->header.stamp, 0.0);
  }

  void frameCb(const ImageConstPtr& left, const ImageConstPtr& right, const CalibrationMode::ConstPtr& mode) {
    const std::string problem =
        checkImagePair(*left, frames_->topic(0), *right, frames_->topic(1), {"mono8", "bgr8"});
    diagnostics_->frameIn();
    diagnostics_->set("light on", mode->light_on ? "true" : "false");
    if (!problem.empty()) return reportError("frame dropped: " + problem);
    if (learn_) learnFrom(left, right, *mode);
    if (!mode->light_on) return publishRaw(left, right, "light off");
    if (!mode->settled) return publishRaw(left, right, "light changing");

    std::shared_ptr<const StereoSeparator> separator;
    bool teaching;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      if (!teach_from_truth_ && teach_.active) addTeachFrame(*left, *right, nullptr, nullptr, mode->calibration_epoch);
      separator = separator_;
      if (teach_from_truth_ && (!separator || (reteach_on_epoch_change_ && separator->epoch() != mode->calibration_epoch)))
        startTeach(mode->calibration_epoch);
      teaching = teach_.active;
    }
    needInputsForTeach(teaching || (learn_ && !has_template_));
    if (!separator) {
      reportWarning(learn_ ? "device image not learned yet: republishing the raw light-on frames"
                           : "separation not taught yet: republishing the raw light-on frames");
      return publishRaw(left, right, learn_ ? "learning" : "not taught");
    }
    if (!learn_ && reteach_on_epoch_change_ && separator->epoch() != mode->calibration_epoch) {
      reportWarning("template taught under calibration epoch " + std::to_string(separator->epoch()) +
                    ", frames are epoch " + std::to_string(mode->calibration_epoch) +
                    (teach_from_truth_ ? ": re-teaching, republishing raw frames meanwhile"
                                       : ": call teach with the scene covered; republishing raw frames"));
      return publishRaw(left, right, "template of another epoch");
    }
    try {
      const auto start = std::chrono::steady_clock::now();
      const cv_bridge::CvImageConstPtr left_in = cv_bridge::toCvShare(left), right_in = cv_bridge::toCvShare(right);
      diagnostics_->checkShared(left_in->image, *left);
      diagnostics_->checkShared(right_in->image, *right);
      const OutputImage left_out = newImageLike(*left), right_out = newImageLike(*right);
      cv::Mat left_scene = left_out.view, right_scene = right_out.view;
      ecs::separateStereo(separator->left, separator->right, left_in->image, right_in->image, &left_scene,
                          &right_scene);
      left_pub_.publish(left_out.msg);
      right_pub_.publish(right_out.msg);
      diagnostics_->set("mode", "separating");
      diagnostics_->framePublished(left->header.stamp,
                                   std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
    } catch (const std::exception& e) {  // e.g. the image size changed since teaching
      reportError(frames_->topic(0) + ", " + frames_->topic(1) + ": cannot separate (" + e.what() +
                  "); republishing raw frames");
      publishRaw(left, right, "separation failed");
    }
  }

  // Simulator teach: the device image is the light-on frame minus the ground-truth scene.
  void truthCb(const ImageConstPtr& left, const ImageConstPtr& right, const CalibrationMode::ConstPtr& mode,
               const ImageConstPtr& left_truth, const ImageConstPtr& right_truth) {
    if (!mode->light_on || !mode->settled) return;
    if (checkImagePair(*left, frames_->topic(0), *right, frames_->topic(1), {"mono8", "bgr8"}).size() ||
        checkImagePair(*left, frames_->topic(0), *left_truth, truth_->topic(3), {left->encoding}).size() ||
        checkImagePair(*right, frames_->topic(1), *right_truth, truth_->topic(4), {right->encoding}).size())
      return reportError("ground truth does not match the raw images: cannot teach from it");
    bool teaching;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      if (teach_.active) addTeachFrame(*left, *right, left_truth.get(), right_truth.get(), mode->calibration_epoch);
      teaching = teach_.active;
    }
    needInputsForTeach(teaching || (learn_ && !has_template_));
  }

  // Called with state_mutex_ held.
  void startTeach(uint32_t epoch) {
    if (teach_.active && teach_.epoch == epoch) return;
    teach_ = TeachAccumulator();
    teach_.active = true;
    teach_.epoch = epoch;
    NODELET_INFO("Separator: teaching the device image for calibration epoch %u (%d frames, %s)", epoch, teach_frames_,
                 teach_from_truth_ ? "light-on frame minus ground-truth scene" : "scene must be covered");
  }

  // Called with state_mutex_ held. A teach adopts the epoch of its first frame; frames of
  // another epoch restart it (the device image moved).
  void addTeachFrame(const Image& left, const Image& right, const Image* left_truth, const Image* right_truth,
                     uint32_t epoch) {
    if (teach_.frames == 0) teach_.epoch = epoch;
    if (epoch != teach_.epoch) startTeach(epoch);
    const auto view = [](const Image& m) { return cv_bridge::toCvShare(m, boost::shared_ptr<void>())->image; };
    accumulate(view(left), left_truth ? view(*left_truth) : cv::Mat(), &teach_.left_sum);
    accumulate(view(right), right_truth ? view(*right_truth) : cv::Mat(), &teach_.right_sum);
    if (++teach_.frames < teach_frames_) return;
    try {
      separator_ = std::make_shared<const StereoSeparator>(options_, templateFrom(teach_.left_sum, teach_.frames, epoch),
                                                           templateFrom(teach_.right_sum, teach_.frames, epoch));
      NODELET_INFO("Separator: device image taught from %d frames, calibration epoch %u", teach_.frames, epoch);
      diagnostics_->set("template epoch", std::to_string(epoch));
    } catch (const std::exception& e) {
      reportError(std::string("teach failed: ") + e.what());
    }
    teach_ = TeachAccumulator();
  }

  // device_template learn: learns from each light burst (see the file comment). Callback thread.
  void learnFrom(const ImageConstPtr& left, const ImageConstPtr& right, const CalibrationMode& mode) {
    collectLearned();
    if (!mode.settled) return;
    if (std::optional<EndedBurst> ended = bursts_.add(left, right, mode.light_on)) {
      if (!ended->problem.empty())
        return reportWarning("cannot learn the device image from the burst of " +
                             std::to_string(ended->light_on_frames) + " light-on frames that ended: " + ended->problem);
      return startLearning(std::move(ended->burst), true, mode.calibration_epoch);
    }
    if (!mode.light_on || has_template_) return;
    // No template yet: learn from the first frames of this burst so that its rest is separated.
    LightBurst now = bursts_.underWay();
    if (now.light_off_before.first && static_cast<int>(now.light_on.size()) == 2 * learn_frames_per_end_)
      startLearning(std::move(now), false, mode.calibration_epoch);
  }

  // One run at a time on a worker thread; a burst that ends meanwhile waits (the newest one).
  void startLearning(LightBurst burst, bool whole, uint32_t epoch) {
    if (learning_.valid()) {
      if (whole) waiting_burst_ = PendingBurst{std::move(burst), epoch};
      return;
    }
    std::shared_ptr<const StereoSeparator> in_use;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      in_use = separator_;
    }
    learning_ = std::async(std::launch::async, [burst = std::move(burst), whole, per_end = learn_frames_per_end_,
                                                options = learn_options_, separator_options = options_, in_use,
                                                epoch] {
      return learnBurst(burst, whole, per_end, options, separator_options, in_use, epoch);
    });
  }

  // Takes a finished learning run's result and adopts its template (see the file comment).
  void collectLearned() {
    if (!learning_.valid() || learning_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
    const LearnResult result = learning_.get();
    if (waiting_burst_) {
      PendingBurst next = std::move(*waiting_burst_);
      waiting_burst_.reset();
      startLearning(std::move(next.burst), true, next.epoch);
    }
    if (!result.error.empty()) return reportError("learning the device image failed: " + result.error);
    std::string summary = "left " + result.left.summary() + "; right " + result.right.summary();
    if (result.residual_in_use >= 0.0) {
      char text[160];
      std::snprintf(text, sizeof(text), "; device left on the burst's middle frames: %.1f, with the template in use %.1f",
                    result.residual_new, result.residual_in_use);
      summary += text;
    }
    diagnostics_->set("learning", summary);
    if (has_template_ && result.residual_in_use >= 0.0 && result.residual_new > result.residual_in_use) {
      NODELET_INFO("Separator: the device image learned from the burst ending at %.3f s separates it worse than the "
                   "template in use, which stays (%s)", result.stamp, summary.c_str());
      return;
    }
    const std::shared_ptr<const StereoSeparator> learned = result.separator;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      separator_ = learned;
    }
    NODELET_INFO("Separator: device image learned from %s %d light-on frames of the burst ending at %.3f s (%s)",
                 result.whole_burst ? "the" : "the first", result.light_on_frames, result.stamp, summary.c_str());
    if (!has_template_) needInputsForTeach(false);  // lazy again
    has_template_ = true;
    diagnostics_->set("template epoch", std::to_string(learned->epoch()));
  }

  bool teachService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    if (learn_) {
      res.success = false;
      res.message = "device_template is learn: the device image is learned from the light bursts, no teach needed";
      return true;
    }
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      teach_ = TeachAccumulator();
      teach_.active = true;
    }
    needInputsForTeach(true);
    res.success = true;
    res.message = "averaging the next " + std::to_string(teach_frames_) + " light-on settled frames" +
                  (teach_from_truth_ ? " minus the ground-truth scene" : ": keep the scene covered");
    return true;
  }

  ecs::SeparatorOptions options_;
  int teach_frames_ = 8;
  bool teach_from_truth_ = false, reteach_on_epoch_change_ = true;
  std::unique_ptr<FrameInput> frames_;  // created in onInit, before any callback
  std::unique_ptr<TruthInput> truth_;   // only with teach_from_ground_truth
  image_transport::Publisher left_pub_, right_pub_;
  ros::ServiceServer teach_srv_;
  ErrorThrottle errors_{5.0};
  std::unique_ptr<StageDiagnostics> diagnostics_;  // created in onInit, before any callback

  std::mutex state_mutex_;
  std::shared_ptr<const StereoSeparator> separator_;
  TeachAccumulator teach_;

  // device_template learn (callback thread only, see the class comment).
  bool learn_ = true;
  int learn_frames_per_end_ = 4;
  ecs::DeviceLearnerOptions learn_options_;
  // A burst: at least 3 settled light-on frames; one the Separator saw no light-off frame before
  // (it subscribed during it) is learned from the light-off frame after it alone.
  LightBurstCollector bursts_{3, false};
  struct PendingBurst {
    LightBurst burst;
    uint32_t epoch = 0;
  };
  std::optional<PendingBurst> waiting_burst_;  // ended while a run was busy
  std::future<LearnResult> learning_;
  bool has_template_ = false;  // a learned template is in use
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::SeparatorNodelet, nodelet::Nodelet)
