// Separator nodelet: removes the lit calibration device from calibration-mode frames so that
// depth keeps running while the light is on (core/depth/separator.h does the work). Where the
// device template comes from and which frames are separated: core/depth/stereo_device_template.h;
// topics, parameters and behaviour: docs/nodelets.md#separator.
#include <cv_bridge/cv_bridge.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <chrono>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/core/depth/separator.h"
#include "embedded_calibration_stereo/core/depth/stereo_device_template.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"
#include "embedded_calibration_stereo/ros/freed_memory.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/lazy_synced_input.h"
#include "embedded_calibration_stereo/ros/light_burst.h"
#include "embedded_calibration_stereo/ros/output_image.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/stage_diagnostics.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

// Threads (docs/architecture.md#threads): the single-threaded callback queue runs initialise,
// frameCb, truthCb, the teach service, the connect callbacks and the diagnostics timer
// (StageDiagnostics guards its own counters). state_mutex_ still guards separator_ and teach_, so
// the class stays correct on a multi-threaded handle; the inputs (un)subscribe under their own
// mutex, so need() is called outside state_mutex_. separator_ is immutable: frameCb separates
// outside the lock (cameras in parallel). With learn, the burst collector, waiting_burst_ and
// learning_plan_ belong to the callback queue; a learning run works on std::async's thread on a
// burst's message pointers (never written) and returns through learning_ (unloading waits for it).
class SeparatorNodelet : public GuardedNodelet {
 public:
  SeparatorNodelet() : GuardedNodelet("Separator") {}

 private:
  using FrameInput = LazySyncedInput<Image, Image, CalibrationMode>;
  using TruthInput = LazySyncedInput<Image, Image, CalibrationMode, Image, Image>;

  // One learning run's result, with what the log says of its burst.
  struct LearnRun {
    core::StereoLearnResult result;
    int light_on_frames = 0;  // of the burst, used or not
    bool whole_burst = true;  // false: the first frames of a burst under way
    double stamp = 0.0;       // the burst's last light-on frame used
  };
  struct PendingBurst {
    LightBurst burst;
    uint32_t epoch = 0;
  };

  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const ParameterReader read(pnh);
    const std::string method = read.get("method", "regional_alpha");
    try {
      options_.method = core::parseSeparationMethod(method);
    } catch (const std::exception& e) {
      throw core::ConfigError("method", e.what());
    }
    teach_from_truth_ = read.get("teach_from_ground_truth", false);  // tests only: implies teach
    learn_ = read.choice("device_template", teach_from_truth_ ? "teach" : "learn", {"teach", "learn"}) == "learn";
    teach_.emplace(read.atLeast("teach_frames", 8, 1), options_);
    if (learn_ && teach_from_truth_)
      throw core::ConfigError("teach_from_ground_truth", "applies to device_template teach only, not learn");
    learning_plan_.emplace(read.inRange("learn_frames_per_end", 4, 1, 30));
    learn_options_ = core::separatorLearnerOptions();
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
                   method.c_str(), learning_plan_->perEnd(), approximate ? "approximate" : "exact", queue_size);
    } else {
      NODELET_INFO("Separator: %s, teach %d frames from %s, %s sync, queue %d", method.c_str(), teach_->framesNeeded(),
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
    std::shared_ptr<const core::StereoSeparator> separator;
    if (mode->light_on && mode->settled) separator = teachOrTakeSeparator(*left, *right, mode->calibration_epoch);
    switch (core::routeFrame(mode->light_on, mode->settled, separator.get(), mode->calibration_epoch,
                            !learn_ && reteach_on_epoch_change_)) {
      case core::SceneRoute::kLightOff: return publishRaw(left, right, "light off");
      case core::SceneRoute::kLightChanging: return publishRaw(left, right, "light changing");
      case core::SceneRoute::kNoTemplate:
        reportWarning(learn_ ? "device image not learned yet: republishing the raw light-on frames"
                             : "separation not taught yet: republishing the raw light-on frames");
        return publishRaw(left, right, learn_ ? "learning" : "not taught");
      case core::SceneRoute::kOtherEpoch:
        reportWarning("template taught under calibration epoch " + std::to_string(separator->epoch()) +
                      ", frames are epoch " + std::to_string(mode->calibration_epoch) +
                      (teach_from_truth_ ? ": re-teaching, republishing raw frames meanwhile"
                                         : ": call teach with the scene covered; republishing raw frames"));
        return publishRaw(left, right, "template of another epoch");
      case core::SceneRoute::kSeparate: break;
    }
    try {
      const auto start = std::chrono::steady_clock::now();
      const cv_bridge::CvImageConstPtr left_in = cv_bridge::toCvShare(left), right_in = cv_bridge::toCvShare(right);
      diagnostics_->checkShared(left_in->image, *left);
      diagnostics_->checkShared(right_in->image, *right);
      const OutputImage left_out = newImageLike(*left), right_out = newImageLike(*right);
      cv::Mat left_scene = left_out.view, right_scene = right_out.view;
      core::separateStereo(separator->left, separator->right, left_in->image, right_in->image, &left_scene,
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

  // A settled light-on frame: a teach frame (the teach service's), or the start of a teach from
  // the truth (no template, or one of another epoch with reteach_on_epoch_change). Returns the
  // template in use.
  std::shared_ptr<const core::StereoSeparator> teachOrTakeSeparator(const Image& left, const Image& right,
                                                                   uint32_t epoch) {
    std::shared_ptr<const core::StereoSeparator> separator;
    bool teaching;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      if (!teach_from_truth_ && teach_->active()) addTeachFrame(left, right, nullptr, nullptr, epoch);
      separator = separator_;
      if (teach_from_truth_ && (!separator || (reteach_on_epoch_change_ && separator->epoch() != epoch)) &&
          teach_->startFor(epoch))
        logTeachStart(epoch);
      teaching = teach_->active();
    }
    needInputsForTeach(teaching || (learn_ && !learning_plan_->hasTemplate()));
    return separator;
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
      if (teach_->active()) addTeachFrame(*left, *right, left_truth.get(), right_truth.get(), mode->calibration_epoch);
      teaching = teach_->active();
    }
    needInputsForTeach(teaching || (learn_ && !learning_plan_->hasTemplate()));
  }

  void logTeachStart(uint32_t epoch) {
    NODELET_INFO("Separator: teaching the device image for calibration epoch %u (%d frames, %s)", epoch,
                 teach_->framesNeeded(),
                 teach_from_truth_ ? "light-on frame minus ground-truth scene" : "scene must be covered");
  }

  // Called with state_mutex_ held (StereoTemplateTeach::add).
  void addTeachFrame(const Image& left, const Image& right, const Image* left_truth, const Image* right_truth,
                     uint32_t epoch) {
    const auto view = [](const Image* m) {
      return m ? cv_bridge::toCvShare(*m, boost::shared_ptr<void>())->image : cv::Mat();
    };
    try {
      const core::StereoTemplateTeach::Step step =
          teach_->add(view(&left), view(&right), view(left_truth), view(right_truth), epoch);
      if (step.restarted) logTeachStart(epoch);
      if (!step.taught) return;
      separator_ = step.taught;
      NODELET_INFO("Separator: device image taught from %d frames, calibration epoch %u", teach_->framesNeeded(),
                   epoch);
      diagnostics_->set("template epoch", std::to_string(epoch));
    } catch (const std::exception& e) {
      reportError(std::string("teach failed: ") + e.what());
    }
  }

  // device_template learn: learns from each light burst (DeviceLearningPlan). Callback thread.
  void learnFrom(const ImageConstPtr& left, const ImageConstPtr& right, const CalibrationMode& mode) {
    collectLearned();
    if (!mode.settled) return;
    if (std::optional<EndedBurst> ended = bursts_.add(left, right, mode.light_on)) {
      if (!ended->problem.empty())
        return reportWarning("cannot learn the device image from the burst of " +
                             std::to_string(ended->light_on_frames) + " light-on frames that ended: " + ended->problem);
      return startLearning(std::move(ended->burst), true, mode.calibration_epoch);
    }
    if (!mode.light_on || learning_plan_->hasTemplate()) return;
    LightBurst now = bursts_.underWay();
    if (learning_plan_->learnUnderWay(static_cast<int>(now.light_on.size()), now.light_off_before.first != nullptr))
      startLearning(std::move(now), false, mode.calibration_epoch);
  }

  // One run at a time on a worker thread; a burst that ends meanwhile waits (the newest one).
  void startLearning(LightBurst burst, bool whole, uint32_t epoch) {
    if (learning_.valid()) {
      if (whole) waiting_burst_ = PendingBurst{std::move(burst), epoch};
      return;
    }
    std::shared_ptr<const core::StereoSeparator> in_use;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      in_use = separator_;
    }
    learning_ = std::async(std::launch::async, [burst = std::move(burst), whole, per_end = learning_plan_->perEnd(),
                                                options = learn_options_, separator_options = options_, in_use,
                                                epoch] {
      LearnRun run{{}, static_cast<int>(burst.light_on.size()), whole,
                   burst.light_on.back().first->header.stamp.toSec()};
      try {
        run.result = core::learnStereoDevice(windowFrames(burst, 0), windowFrames(burst, 1), whole, per_end, options,
                                            separator_options, in_use, epoch);
      } catch (const std::exception& e) {  // an image cv_bridge cannot read
        run.result.error = e.what();
      }
      releaseFreedMemory();  // learning freed tens of MB
      return run;
    });
  }

  // Takes a finished learning run's result and adopts its template (DeviceLearningPlan::adopt).
  void collectLearned() {
    if (!learning_.valid() || learning_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
    const LearnRun run = learning_.get();
    const core::StereoLearnResult& result = run.result;
    if (waiting_burst_) {
      PendingBurst next = std::move(*waiting_burst_);
      waiting_burst_.reset();
      startLearning(std::move(next.burst), true, next.epoch);
    }
    if (!result.error.empty()) return reportError("learning the device image failed: " + result.error);
    std::string summary = "left " + result.left.summary() + "; right " + result.right.summary();
    if (result.residual_in_use >= 0.0) {
      char text[160];
      std::snprintf(text, sizeof(text),
                    "; device left on the burst's middle frames: %.1f, with the template in use %.1f",
                    result.residual_new, result.residual_in_use);
      summary += text;
    }
    diagnostics_->set("learning", summary);
    if (!learning_plan_->adopt(result)) {
      NODELET_INFO("Separator: the device image learned from the burst ending at %.3f s separates it worse than the "
                   "template in use, which stays (%s)", run.stamp, summary.c_str());
      return;
    }
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      separator_ = result.separator;
    }
    NODELET_INFO("Separator: device image learned from %s %d light-on frames of the burst ending at %.3f s (%s)",
                 run.whole_burst ? "the" : "the first", run.light_on_frames, run.stamp, summary.c_str());
    if (!learning_plan_->hasTemplate()) needInputsForTeach(false);  // lazy again
    learning_plan_->adopted();
    diagnostics_->set("template epoch", std::to_string(result.separator->epoch()));
  }

  bool teachService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    if (learn_) {
      res.success = false;
      res.message = "device_template is learn: the device image is learned from the light bursts, no teach needed";
      return true;
    }
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      teach_->start();
    }
    needInputsForTeach(true);
    res.success = true;
    res.message = "averaging the next " + std::to_string(teach_->framesNeeded()) + " light-on settled frames" +
                  (teach_from_truth_ ? " minus the ground-truth scene" : ": keep the scene covered");
    return true;
  }

  core::SeparatorOptions options_;
  bool teach_from_truth_ = false, reteach_on_epoch_change_ = true;
  std::unique_ptr<FrameInput> frames_;  // created in initialise, before any callback
  std::unique_ptr<TruthInput> truth_;   // only with teach_from_ground_truth
  image_transport::Publisher left_pub_, right_pub_;
  ros::ServiceServer teach_srv_;
  ErrorThrottle errors_{5.0};
  std::unique_ptr<StageDiagnostics> diagnostics_;  // created in initialise, before any callback

  std::mutex state_mutex_;
  std::shared_ptr<const core::StereoSeparator> separator_;
  std::optional<core::StereoTemplateTeach> teach_;  // set in initialise

  // device_template learn (callback thread only, see the class comment).
  bool learn_ = true;
  std::optional<core::DeviceLearningPlan> learning_plan_;  // set in initialise
  core::DeviceLearnerOptions learn_options_;
  // A burst: at least 3 settled light-on frames; one the Separator saw no light-off frame before
  // (it subscribed during it) is learned from the light-off frame after it alone.
  LightBurstCollector bursts_{3, false};
  std::optional<PendingBurst> waiting_burst_;  // ended while a run was busy
  std::future<LearnRun> learning_;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::SeparatorNodelet, nodelet::Nodelet)
