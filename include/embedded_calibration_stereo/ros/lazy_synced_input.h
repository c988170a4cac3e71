#pragma once
// The synchronised inputs of a stage nodelet (Rectifier, Disparity, Separator, PatternTracker),
// subscribed lazily as image_pipeline does: only while someone subscribes to one of the stage's
// outputs, or while the owner needs them for work of its own (a teach). One message of each topic
// is joined by ExactTime, or by ApproximateTime with approximate_sync (stereo_image_proc's
// parameters: queue_size, approximate_sync). Images come through image_transport's raw transport:
// within one manager the published message itself is delivered (zero-copy).
// In front of the synchroniser, every message passes a StampGuard (stamp_guard.h: a message
// stamped far from the other inputs is dropped with a warning, so that it never fills the
// synchroniser's queue; tolerance: the private parameter stamp_tolerance_s), and every image a
// check that its data can be read (malformedImage: dropped with a throttled error). A
// calibration_mode input joins the synchroniser only for a frame whose image has arrived (or
// arrives soon after), once per stamp (frame_stamp_gate.h): a stream of modes at stamps no image
// has cannot evict the live frames from the synchroniser's queue.
//
// Use: construct, pass connectCallback()/imageConnectCallback() to the outputs' advertise(),
// watch() each output, then start().
//
// Threads: every (un)subscription happens under the object's own mutex; the stamp guard has its
// own. The frame callback runs
// on the queue of the node handle given to the constructor, the connect callbacks on the outputs'
// queue. need() may be called from the frame callback (roscpp lets a subscriber be shut down from
// its own callback) when both kinds of callback share one single-threaded queue, as in the
// nodelets: unsubscribing waits for a callback of that subscription running on another thread,
// which must then not be waiting for this mutex.
#include <image_transport/image_transport.h>
#include <image_transport/subscriber_filter.h>
#include <message_filters/subscriber.h>
#include <message_filters/sync_policies/approximate_time.h>
#include <message_filters/sync_policies/exact_time.h>
#include <message_filters/synchronizer.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>

#include <array>
#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/ros/frame_stamp_gate.h"
#include "embedded_calibration_stereo/ros/stamp_guard.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"  // ErrorThrottle

namespace embedded_calibration_stereo {

// The lazy switch, independent of the message types.
class LazySubscription {
 public:
  LazySubscription(std::function<void()> subscribe, std::function<void()> unsubscribe);
  LazySubscription(const LazySubscription&) = delete;
  LazySubscription& operator=(const LazySubscription&) = delete;

  // Connect callbacks for the outputs' advertise(): each re-evaluates whether inputs are needed.
  ros::SubscriberStatusCallback connectCallback();
  image_transport::SubscriberStatusCallback imageConnectCallback();
  // Listeners of `output` make the inputs needed (called after advertising it, before start()).
  void watch(const ros::Publisher& output);
  void watch(const image_transport::Publisher& output);
  // From now on the inputs follow the need; connect callbacks before it are ignored (the owner may
  // not have stored its publishers yet), start() counts their listeners itself.
  void start();
  // The owner needs the inputs (true) or no longer (false), whoever listens.
  void need(bool needed);
  bool subscribed() const;

 protected:
  // Ignores every later callback and need(): the owner's destructor calls it before its inputs go.
  void stop();

 private:
  void update();  // mutex_ held

  const std::function<void()> subscribe_, unsubscribe_;
  mutable std::mutex mutex_;  // guards everything below
  std::vector<std::function<uint32_t()>> listeners_;  // one per watched output
  bool started_ = false, needed_ = false, subscribed_ = false;
};

// A message_filters stage that passes on the messages `admit` accepts (LazySyncedInput's guard),
// and later those it kept (pass()); `passed` hears of each message passed on by add().
template <class M>
class AdmissionFilter : public message_filters::SimpleFilter<M> {
 public:
  using Event = ros::MessageEvent<M const>;
  using Admit = std::function<bool(const Event&)>;  // false: dropped, or kept for pass()
  using Passed = std::function<void(const M&)>;
  template <class F>
  AdmissionFilter(F& input, Admit admit, Passed passed = nullptr) : admit_(std::move(admit)), passed_(std::move(passed)) {
    connection_ = input.registerCallback(&AdmissionFilter::add, this);
  }
  ~AdmissionFilter() { connection_.disconnect(); }
  void pass(const Event& event) { this->signalMessage(event); }

 private:
  void add(const Event& event) {
    if (!admit_(event)) return;
    this->signalMessage(event);
    if (passed_) passed_(*event.getMessage());
  }
  const Admit admit_;
  const Passed passed_;
  message_filters::Connection connection_;
};

// Inputs of types M... on `topics` (relative to the node handle; sensor_msgs::Image topics are
// subscribed through image_transport, raw), joined before `callback` sees them.
template <class... M>
class LazySyncedInput : public LazySubscription {
 public:
  static constexpr size_t kTopics = sizeof...(M);
  using Callback = std::function<void(const boost::shared_ptr<const M>&...)>;
  using Topics = std::array<std::string, kTopics>;

  // `private_nh`: where image_transport reads its transport hint parameter and the guard its
  // stamp_tolerance_s (throws core::ConfigError naming it when unusable); its namespace (the
  // nodelet's name) names the owner in warnings.
  LazySyncedInput(const ros::NodeHandle& nh, const ros::NodeHandle& private_nh, Topics topics,
                  bool approximate_sync, int queue_size, Callback callback)
      : LazySubscription([this] { subscribeAll(std::index_sequence_for<M...>()); },
                         [this] { unsubscribeAll(std::index_sequence_for<M...>()); }),
        nh_(nh),
        private_nh_(private_nh),
        it_(nh),
        topics_(std::move(topics)),
        queue_size_(queue_size),
        callback_(std::move(callback)) {
    for (size_t i = 0; i < kTopics; ++i) resolved_[i] = nh_.resolveName(topics_[i]);
    guard_ = std::make_unique<StampGuard>(std::vector<std::string>(resolved_.begin(), resolved_.end()),
                                          readStampTolerance(private_nh_), private_nh_.getNamespace());
    gate_ = std::make_unique<FrameStampGate>(std::vector<std::string>(resolved_.begin(), resolved_.end()),
                                             private_nh_.getNamespace());
    makeAdmissions(std::index_sequence_for<M...>());
    std::apply(
        [&](auto&... admissions) {
          if (approximate_sync) {
            approximate_ = std::make_unique<message_filters::Synchronizer<Approximate>>(Approximate(queue_size),
                                                                                       *admissions...);
            approximate_->registerCallback(&LazySyncedInput::onMessages, this);
          } else {
            exact_ = std::make_unique<message_filters::Synchronizer<Exact>>(Exact(queue_size), *admissions...);
            exact_->registerCallback(&LazySyncedInput::onMessages, this);
          }
        },
        admissions_);
  }

  ~LazySyncedInput() { stop(); }

  // The resolved name of topic `i` (as given to the constructor), for messages.
  const std::string& topic(size_t i) const { return resolved_.at(i); }
  bool approximate() const { return approximate_ != nullptr; }
  // Messages dropped for their stamp, and images dropped as unreadable, since the start.
  uint64_t droppedForStamp() const { return guard_->dropped() + gate_->dropped(); }
  uint64_t droppedMalformed() const { return malformed_; }

 private:
  template <class T>
  using Filter = std::conditional_t<std::is_same<T, sensor_msgs::Image>::value, image_transport::SubscriberFilter,
                                    message_filters::Subscriber<T>>;
  using Exact = message_filters::sync_policies::ExactTime<M...>;
  using Approximate = message_filters::sync_policies::ApproximateTime<M...>;

  // message_filters binds member functions: forwards to callback_.
  void onMessages(const boost::shared_ptr<const M>&... messages) { callback_(messages...); }

  template <class T>
  static constexpr bool kImage = std::is_same<T, sensor_msgs::Image>::value;
  template <class T>
  static constexpr bool kPerFrame = std::is_same<T, CalibrationMode>::value;  // matched to images by the gate

  template <size_t... I>
  void makeAdmissions(std::index_sequence<I...>) {
    admissions_ = std::make_tuple(std::make_unique<AdmissionFilter<M>>(
        std::get<I>(filters_), [this](const ros::MessageEvent<M const>& event) { return admit<I>(event); },
        [this](const M& message) { passed(message); })...);
  }
  template <size_t I, class T>
  bool admit(const ros::MessageEvent<T const>& event) {
    const T& message = *event.getMessage();
    if constexpr (kImage<T>) {
      if (!readable(I, message)) return false;
    }
    if (!guard_->admit(I, message.header.stamp)) return false;
    if constexpr (kPerFrame<T>) {
      const auto verdict = gate_->offer(I, message.header.stamp, event.getPublisherName(),
                                        [this, event] { std::get<I>(admissions_)->pass(event); });
      return verdict == FrameStampGate::Verdict::kPass;
    }
    return true;
  }
  // After an image went on, the per-frame messages of its stamp follow it.
  template <class T>
  void passed(const T& message) {
    if constexpr (kImage<T>)
      for (const FrameStampGate::Release& release : gate_->image(message.header.stamp)) release();
  }
  bool readable(size_t index, const sensor_msgs::Image& image) {
    const std::string problem = malformedImage(image);
    if (problem.empty()) return true;
    ++malformed_;
    // Keyed by topic: one camera's broken images must not hide the other's.
    if (unreadable_.shouldReport(resolved_[index]))
      ROS_ERROR("%s: image dropped on %s: %s", private_nh_.getNamespace().c_str(), resolved_[index].c_str(),
                problem.c_str());
    return false;
  }

  template <size_t... I>
  void subscribeAll(std::index_sequence<I...>) {
    guard_->reset();  // stamps from before an unsubscription are no reference
    gate_->reset();
    (subscribeOne(std::get<I>(filters_), topics_[I]), ...);
  }
  template <size_t... I>
  void unsubscribeAll(std::index_sequence<I...>) {
    (std::get<I>(filters_).unsubscribe(), ...);
  }
  void subscribeOne(image_transport::SubscriberFilter& filter, const std::string& topic) {
    filter.subscribe(it_, topic, queue_size_, image_transport::TransportHints("raw", ros::TransportHints(), private_nh_));
  }
  template <class T>
  void subscribeOne(message_filters::Subscriber<T>& filter, const std::string& topic) {
    filter.subscribe(nh_, topic, queue_size_);
  }

  ros::NodeHandle nh_, private_nh_;
  image_transport::ImageTransport it_;
  const Topics topics_;
  Topics resolved_;
  const int queue_size_;
  const Callback callback_;
  std::unique_ptr<StampGuard> guard_;
  std::unique_ptr<FrameStampGate> gate_;
  std::atomic<uint64_t> malformed_{0};
  ErrorThrottle unreadable_{StampGuard::kWarnPeriodS};  // unreadable images' errors, per topic
  std::tuple<Filter<M>...> filters_;  // declared before the admissions and synchronisers: they outlive them
  std::tuple<std::unique_ptr<AdmissionFilter<M>>...> admissions_;  // filters_ -> admissions_ -> synchroniser
  std::unique_ptr<message_filters::Synchronizer<Exact>> exact_;
  std::unique_ptr<message_filters::Synchronizer<Approximate>> approximate_;
};

}  // namespace embedded_calibration_stereo
