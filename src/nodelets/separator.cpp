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
// Teaching I_C (the device image, only valid for the calibration it was taught under):
//  - hardware: the `teach` service averages the next teach_frames light-on settled frames; the
//    scene must be covered (or dark) meanwhile;
//  - simulator (teach_from_ground_truth): the scene cannot be covered, so I_C is the mean over
//    teach_frames light-on settled frames of I_E - ground_truth image_scene of the same stamp,
//    which is the device-only image. It is taught automatically at the first light-on frames and,
//    with reteach_on_epoch_change, again whenever calibration_epoch differs from the template's
//    (the device image moves with zoom); on hardware an epoch change is only warned about.
// Diagnostics (StageDiagnostics): rates, latency, mode (passthrough and why, or separating),
// method, template epoch and input copies (must stay 0).
#include <cv_bridge/cv_bridge.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <chrono>
#include <memory>
#include <mutex>
#include <vector>

#include "embedded_calibration_stereo/CalibrationMode.h"
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

}  // namespace

// Threads: the nodelet's (single-threaded) callback queue runs onInit, frameCb, truthCb, the
// teach service and the publishers' connect callbacks; state_mutex_ still guards separator_ and
// teach_ so that the class stays correct if it is moved to the multi-threaded handle. The inputs
// (un)subscribe under their own mutex; need() is called outside state_mutex_ (unsubscribing
// waits for a callback of that subscription running on another thread). separator_ points to
// an immutable StereoSeparator: frameCb takes its own reference and separates outside the lock
// (both cameras in parallel, ecs::separateStereo). Published messages are never modified after publishing. diagnostics_
// reports on a wall timer of the same queue and guards its own counters.
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
    teach_frames_ = read.atLeast("teach_frames", 8, 1);
    teach_from_truth_ = read.get("teach_from_ground_truth", false);
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
    teach_srv_ = nh.advertiseService("teach", &SeparatorNodelet::teachService, this);
    diagnostics_ = std::make_unique<StageDiagnostics>(nh, pnh, "separator");
    diagnostics_->set("method", method);
    diagnostics_->set("template epoch", "none (not taught)");
    for (LazySubscription* input : inputs()) input->start();  // subscribed while someone listens
    NODELET_INFO("Separator: %s, teach %d frames from %s, %s sync, queue %d", method.c_str(), teach_frames_,
                 teach_from_truth_ ? "ground truth (simulator)" : "the teach service (scene covered)",
                 approximate ? "approximate" : "exact", queue_size);
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
      reportWarning("separation not taught yet: republishing the raw light-on frames");
      return publishRaw(left, right, "not taught");
    }
    if (reteach_on_epoch_change_ && separator->epoch() != mode->calibration_epoch) {
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

  bool teachService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
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
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::SeparatorNodelet, nodelet::Nodelet)
