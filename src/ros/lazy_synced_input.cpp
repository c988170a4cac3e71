#include "embedded_calibration_stereo/ros/lazy_synced_input.h"

namespace embedded_calibration_stereo {

LazySubscription::LazySubscription(std::function<void()> subscribe, std::function<void()> unsubscribe)
    : subscribe_(std::move(subscribe)), unsubscribe_(std::move(unsubscribe)) {}

ros::SubscriberStatusCallback LazySubscription::connectCallback() {
  return [this](const ros::SingleSubscriberPublisher&) {
    std::lock_guard<std::mutex> lock(mutex_);
    update();
  };
}

image_transport::SubscriberStatusCallback LazySubscription::imageConnectCallback() {
  return [this](const image_transport::SingleSubscriberPublisher&) {
    std::lock_guard<std::mutex> lock(mutex_);
    update();
  };
}

void LazySubscription::watch(const ros::Publisher& output) {
  std::lock_guard<std::mutex> lock(mutex_);
  listeners_.push_back([output] { return output.getNumSubscribers(); });
}

void LazySubscription::watch(const image_transport::Publisher& output) {
  std::lock_guard<std::mutex> lock(mutex_);
  listeners_.push_back([output] { return output.getNumSubscribers(); });
}

void LazySubscription::start() {
  std::lock_guard<std::mutex> lock(mutex_);
  started_ = true;
  update();
}

void LazySubscription::stop() {
  std::lock_guard<std::mutex> lock(mutex_);
  started_ = false;
}

void LazySubscription::need(bool needed) {
  std::lock_guard<std::mutex> lock(mutex_);
  needed_ = needed;
  update();
}

bool LazySubscription::subscribed() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return subscribed_;
}

void LazySubscription::update() {
  if (!started_) return;
  bool wanted = needed_;
  for (const auto& listeners : listeners_) wanted = wanted || listeners() > 0;
  if (wanted == subscribed_) return;
  subscribed_ = wanted;
  if (wanted) {
    subscribe_();
  } else {
    unsubscribe_();
  }
}

}  // namespace embedded_calibration_stereo
