// Separator nodelet: removes the lit calibration device from calibration-mode frames so that
// depth keeps running while the light is on (core/separator.h does the work).
//
// Lazy: the inputs are subscribed only while someone subscribes to left|right/image_scene or a
// teach is running (lazy_synced_input.h).
// Per stereo frame (left|right/image_raw and calibration_mode, ExactTime, or ApproximateTime with
// approximate_sync):
//  - light off, or light on but not settled (mixed frames), or no template taught for the
//    frame's calibration epoch: the incoming message pointers are republished unchanged on
//    left|right/image_scene (zero-copy; depth never stops; a missing template is warned about);
//  - light on and settled: the separated images, in new messages with the raw headers.
//
// Where I_C (the device image, only valid for the calibration it was taught under) comes from,
// parameter device_template:
//  - learn: learned during normal operation (core/depth/device_image_learner.h): each light
//    window gives pairs (the last settled light-off frame before it with the first two settled
//    light-on frames; the last two settled light-on frames with the first settled light-off frame
//    after it); after each window the pairs of the current calibration epoch are learned on a
//    worker thread, until the result is ready: it becomes the template of that epoch and learning
//    stops until the next epoch (a run costs seconds of CPU). No covering, no truth.
//    An epoch change starts a new set of pairs; the old template is not used meanwhile (frames
//    pass unseparated, see reteach_on_epoch_change).
//  - teach (default), on hardware: the `teach` service averages the next teach_frames light-on
//    settled frames; the scene must be covered (or dark) meanwhile;
//  - teach, simulator (teach_from_ground_truth): the scene cannot be covered, so I_C is the mean
//    over teach_frames light-on settled frames of I_E - ground_truth image_scene of the same
//    stamp, which is the device-only image. It is taught automatically at the first light-on
//    frames and, with reteach_on_epoch_change, again whenever calibration_epoch differs from the
//    template's (the device image moves with zoom); on hardware an epoch change is only warned
//    about.
// Diagnostics (StageDiagnostics): rates, latency, mode (passthrough and why, or separating),
// method, template source and epoch, the last learning result (learn) and input copies (must
// stay 0).
#include <cv_bridge/cv_bridge.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <chrono>
#include <cmath>
#include <deque>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/core/depth/device_image_learner.h"
#include "embedded_calibration_stereo/core/depth/separator.h"
#include "embedded_calibration_stereo/core/geometry/config_error.h"
#include "embedded_calibration_stereo/ros/lazy_synced_input.h"
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

// A settled frame kept for learning: both images copied (the messages may be reused elsewhere).
struct KeptFrame {
  cv::Mat left, right;
  ros::Time stamp;
  uint32_t epoch = 0;
};

KeptFrame keep(const Image& left, const Image& right, uint32_t epoch) {
  const auto view = [](const Image& m) { return cv_bridge::toCvShare(m, boost::shared_ptr<void>())->image.clone(); };
  return {view(left), view(right), left.header.stamp, epoch};
}

// One learning run's result (both cameras), made on the worker thread.
struct LearnResult {
  ecs::LearnedDevice left, right;
  std::string error;  // non-empty: the run failed
};

}  // namespace

// Threads: the nodelet's (single-threaded) callback queue runs onInit, frameCb, truthCb, the
// teach service and the publishers' connect callbacks; state_mutex_ still guards separator_ and
// teach_ so that the class stays correct if it is moved to the multi-threaded handle. The inputs
// (un)subscribe under their own mutex; need() is called outside state_mutex_ (unsubscribing
// waits for a callback of that subscription running on another thread). separator_ points to
// an immutable StereoSeparator: frameCb takes its own reference and separates outside the lock
// (both cameras in parallel, ecs::separateStereo). Published messages are never modified after publishing. diagnostics_
// reports on a wall timer of the same queue and guards its own counters. With device_template
// learn, the pair sets, kept frames and learning_ belong to the callback thread; a learning run
// works on std::async's thread on a snapshot of the pairs (images never written after being
// kept) and hands its result back through the future, which only the callback thread reads
// (unloading waits for a run in progress: the future of std::async joins its thread).
class SeparatorNodelet : public nodelet::Nodelet {
 private:
  using FrameInput = LazySyncedInput<Image, Image, CalibrationMode>;
  using TruthInput = LazySyncedInput<Image, Image, CalibrationMode, Image, Image>;

  void onInit() override {
    try {
      initialise();
    } catch (const std::exception& e) {  // before anything is advertised: nothing to release
      NODELET_FATAL("Separator cannot start: %s", e.what());
      throw;
    }
  }

  void initialise() {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const ParameterReader read(pnh);
    const std::string method = read.get("method", "regional_alpha");
    try {
      options_.method = ecs::parseSeparationMethod(method);
    } catch (const std::exception& e) {
      throw ecs::ConfigError("method", e.what());
    }
    learn_ = read.choice("device_template", "teach", {"teach", "learn"}) == "learn";
    teach_frames_ = read.atLeast("teach_frames", 8, 1);
    teach_from_truth_ = read.get("teach_from_ground_truth", false);
    if (learn_ && teach_from_truth_)
      throw ecs::ConfigError("teach_from_ground_truth", "applies to device_template teach only, not learn");
    learn_options_.min_pairs = read.inRange("learn_min_pairs", learn_options_.min_pairs, 2, 64);
    learn_options_.max_pairs = read.inRange("learn_max_pairs", learn_options_.max_pairs, learn_options_.min_pairs, 64);
    learn_options_.min_coverage = read.inRange("learn_min_coverage", learn_options_.min_coverage, 0.5, 1.0);
    learn_left_ = ecs::LightPairSet(learn_options_.max_pairs);
    learn_right_ = ecs::LightPairSet(learn_options_.max_pairs);
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
    for (LazySubscription* input : inputs()) input->start();  // subscribed while someone listens
    if (learn_) {
      NODELET_INFO("Separator: %s, device image learned from the light windows (at least %d light pairs), %s sync, "
                   "queue %d",
                   method.c_str(), learn_options_.min_pairs, approximate ? "approximate" : "exact", queue_size);
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
    needInputsForTeach(teaching);
    if (!separator) {
      reportWarning(learn_ ? "device image not learned yet: republishing the raw light-on frames"
                           : "separation not taught yet: republishing the raw light-on frames");
      return publishRaw(left, right, learn_ ? "learning" : "not taught");
    }
    if (reteach_on_epoch_change_ && separator->epoch() != mode->calibration_epoch) {
      reportWarning("template taught under calibration epoch " + std::to_string(separator->epoch()) +
                    ", frames are epoch " + std::to_string(mode->calibration_epoch) +
                    (learn_                ? ": re-learning, republishing raw frames meanwhile"
                     : teach_from_truth_ ? ": re-teaching, republishing raw frames meanwhile"
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
    needInputsForTeach(teaching);
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

  // device_template learn: collects light pairs around each light window and learns after it.
  // Callback thread only.
  void learnFrom(const ImageConstPtr& left, const ImageConstPtr& right, const CalibrationMode& mode) {
    collectLearned();
    if (!mode.settled) return;
    const uint32_t epoch = mode.calibration_epoch;
    if (learned_epoch_ == epoch) return;  // learned: nothing more to collect until the next epoch
    if (epoch != learn_left_.epoch()) {
      if (learn_left_.size() > 0) NODELET_INFO("Separator: calibration epoch %u: learning the device image again", epoch);
      learn_left_.reset(epoch);
      learn_right_.reset(epoch);
    }
    // Pairs only within one epoch and a short time (the scene moves between the two frames).
    const auto pairable = [&](const KeptFrame& f) {
      return f.epoch == epoch && std::abs((left->header.stamp - f.stamp).toSec()) <= kMaxPairGapS;
    };
    try {
      if (!mode.light_on) {
        if (!recent_on_.empty()) {  // the first settled light-off frame after a window
          const KeptFrame off = keep(*left, *right, epoch);
          for (const KeptFrame& on : recent_on_)
            if (pairable(on)) addPair(off, on);
          recent_on_.clear();
          last_off_ = off;
          startLearning();
        } else {
          last_off_.reset();  // kept lazily: copied when the next frame turns out to be lit
          last_off_msgs_ = {left, right, epoch};
        }
        settled_on_ = 0;
        return;
      }
      if (!last_off_ && last_off_msgs_.left) last_off_ = keep(*last_off_msgs_.left, *last_off_msgs_.right, last_off_msgs_.epoch);
      const KeptFrame on = keep(*left, *right, epoch);
      if (++settled_on_ <= kPairsPerSwitch && last_off_ && pairable(*last_off_)) addPair(*last_off_, on);
      recent_on_.push_back(on);
      while (static_cast<int>(recent_on_.size()) > kPairsPerSwitch) recent_on_.pop_front();
    } catch (const std::exception& e) {  // e.g. the image size changed: start over
      reportError(std::string("cannot learn from this frame: ") + e.what());
      learn_left_.reset(epoch);
      learn_right_.reset(epoch);
      recent_on_.clear();
      last_off_.reset();
    }
  }

  void addPair(const KeptFrame& off, const KeptFrame& on) {
    learn_left_.add(off.left, on.left);
    learn_right_.add(off.right, on.right);
  }

  // After a window: learns the current pairs on a worker thread (one run at a time).
  void startLearning() {
    if (learning_.valid() || learn_left_.size() < learn_options_.min_pairs) return;
    const uint32_t epoch = learn_left_.epoch();
    learning_ = std::async(std::launch::async, [options = learn_options_, left = learn_left_.snapshot(),
                                                right = learn_right_.snapshot(), epoch] {
      LearnResult result;
      try {
        result.left = ecs::learnDeviceImage(left, options, epoch);
        result.right = ecs::learnDeviceImage(right, options, epoch);
      } catch (const std::exception& e) {
        result.error = e.what();
      }
      return result;
    });
  }

  // Takes a finished learning run's result; adopts its template when ready and of the current epoch.
  void collectLearned() {
    if (!learning_.valid() || learning_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
    const LearnResult result = learning_.get();
    if (!result.error.empty()) return reportError("learning the device image failed: " + result.error);
    const uint32_t epoch = result.left.device_template.calibration_epoch;
    diagnostics_->set("learning", "left " + result.left.summary() + "; right " + result.right.summary());
    if (!result.left.ready || !result.right.ready || epoch != learn_left_.epoch()) return;
    std::shared_ptr<const StereoSeparator> learned;
    try {
      learned = std::make_shared<const StereoSeparator>(options_, result.left.device_template,
                                                        result.right.device_template);
    } catch (const std::exception& e) {
      return reportError(std::string("learned device image unusable: ") + e.what());
    }
    bool first;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      first = !separator_ || separator_->epoch() != epoch;
      separator_ = learned;
    }
    learned_epoch_ = epoch;
    learn_left_.reset(epoch);  // the pairs are no longer needed
    learn_right_.reset(epoch);
    recent_on_.clear();
    last_off_.reset();
    if (first)
      NODELET_INFO("Separator: device image learned for calibration epoch %u (left %s; right %s)", epoch,
                   result.left.summary().c_str(), result.right.summary().c_str());
    diagnostics_->set("template epoch", std::to_string(epoch));
  }

  bool teachService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    if (learn_) {
      res.success = false;
      res.message = "device_template is learn: the device image is learned from the light windows, no teach needed";
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
  static constexpr int kPairsPerSwitch = 2;    // light-on frames paired with each light-off frame
  static constexpr double kMaxPairGapS = 0.5;  // s between the frames of a pair
  bool learn_ = false;
  ecs::DeviceLearnerOptions learn_options_;
  ecs::LightPairSet learn_left_, learn_right_;
  struct OffMessages {
    ImageConstPtr left, right;
    uint32_t epoch = 0;
  } last_off_msgs_;
  std::optional<KeptFrame> last_off_;  // the last settled light-off frame, once copied
  std::deque<KeptFrame> recent_on_;    // the last settled light-on frames of the window
  int settled_on_ = 0;                 // settled light-on frames since the last light-off one
  std::future<LearnResult> learning_;
  std::optional<uint32_t> learned_epoch_;  // the epoch whose template was learned
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::SeparatorNodelet, nodelet::Nodelet)
