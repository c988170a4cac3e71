#pragma once
// The synchronised inputs of a stage nodelet (Rectifier, Disparity, Separator, PatternTracker),
// subscribed lazily as image_pipeline does: only while someone subscribes to one of the stage's
// outputs, or while the owner needs them for work of its own (a teach). One message of each topic
// is joined by ExactTime, or by ApproximateTime with approximate_sync (stereo_image_proc's
// parameters: queue_size, approximate_sync). Images come through image_transport's raw transport:
// within one manager the published message itself is delivered (zero-copy).
//
// Use: construct, pass connectCallback()/imageConnectCallback() to the outputs' advertise(),
// watch() each output, then start().
//
// Threads: every (un)subscription happens under the object's own mutex. The frame callback runs
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
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

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

// Inputs of types M... on `topics` (relative to the node handle; sensor_msgs::Image topics are
// subscribed through image_transport, raw), joined before `callback` sees them.
template <class... M>
class LazySyncedInput : public LazySubscription {
 public:
  static constexpr size_t kTopics = sizeof...(M);
  using Callback = std::function<void(const boost::shared_ptr<const M>&...)>;
  using Topics = std::array<std::string, kTopics>;

  // `private_nh`: where image_transport reads its transport hint parameter.
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
    std::apply(
        [&](auto&... filters) {
          if (approximate_sync) {
            approximate_ = std::make_unique<message_filters::Synchronizer<Approximate>>(Approximate(queue_size),
                                                                                       filters...);
            approximate_->registerCallback(&LazySyncedInput::onMessages, this);
          } else {
            exact_ = std::make_unique<message_filters::Synchronizer<Exact>>(Exact(queue_size), filters...);
            exact_->registerCallback(&LazySyncedInput::onMessages, this);
          }
        },
        filters_);
  }

  ~LazySyncedInput() { stop(); }

  // The resolved name of topic `i` (as given to the constructor), for messages.
  const std::string& topic(size_t i) const { return resolved_.at(i); }
  bool approximate() const { return approximate_ != nullptr; }

 private:
  template <class T>
  using Filter = std::conditional_t<std::is_same<T, sensor_msgs::Image>::value, image_transport::SubscriberFilter,
                                    message_filters::Subscriber<T>>;
  using Exact = message_filters::sync_policies::ExactTime<M...>;
  using Approximate = message_filters::sync_policies::ApproximateTime<M...>;

  // message_filters binds member functions: forwards to callback_.
  void onMessages(const boost::shared_ptr<const M>&... messages) { callback_(messages...); }

  template <size_t... I>
  void subscribeAll(std::index_sequence<I...>) {
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
  std::tuple<Filter<M>...> filters_;  // declared before the synchronisers: they outlive them
  std::unique_ptr<message_filters::Synchronizer<Exact>> exact_;
  std::unique_ptr<message_filters::Synchronizer<Approximate>> approximate_;
};

}  // namespace embedded_calibration_stereo
