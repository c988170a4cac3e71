#include "embedded_calibration_stereo/ros/frame_stamp_gate.h"

#include <ros/console.h>

#include <algorithm>
#include <cstdio>
#include <iterator>
#include <utility>

#include "embedded_calibration_stereo/ros/stamp_guard.h"

namespace embedded_calibration_stereo {

FrameStampGate::FrameStampGate(std::vector<std::string> topics, std::string owner, size_t held_per_input, Warn warn,
                               Clock clock)
    : topics_(std::move(topics)),
      owner_(std::move(owner)),
      held_per_input_(std::max<size_t>(1, held_per_input)),
      warn_(warn ? std::move(warn) : Warn([](const std::string& text) { ROS_WARN("%s", text.c_str()); })),
      clock_(clock ? std::move(clock) : Clock(steadySeconds)),
      inputs_(topics_.size()) {}

bool FrameStampGate::behindImages(const ros::Time& stamp) const {
  if (image_set_.size() < 2) return false;
  return stamp < *std::prev(image_set_.end(), 2);
}

void FrameStampGate::drop(size_t index, const ros::Time& stamp, const std::string& publisher, const char* why,
                          std::vector<std::string>* warnings) {
  Input& input = inputs_[index];
  ++dropped_;
  ++input.dropped_since_warning;
  const double now = clock_();
  if (input.warned_at >= 0 && now - input.warned_at < kWarnPeriodS) return;
  char text[640];
  std::snprintf(text, sizeof(text), "%s: dropped %llu message%s on %s (the last from %s, stamped %.3f s): %s",
                owner_.c_str(), static_cast<unsigned long long>(input.dropped_since_warning),
                input.dropped_since_warning == 1 ? "" : "s", topics_[index].c_str(),
                publisher.empty() ? "an unknown publisher" : publisher.c_str(), stamp.toSec(), why);
  warnings->push_back(text);
  input.warned_at = now;
  input.dropped_since_warning = 0;
}

std::vector<FrameStampGate::Release> FrameStampGate::image(const ros::Time& stamp) {
  std::vector<Release> released;
  std::vector<std::string> warnings;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (image_set_.insert(stamp).second) {
      images_.push_back(stamp);
      if (images_.size() > kRecentImages) {
        image_set_.erase(images_.front());
        images_.pop_front();
      }
    }
    // The held messages of this frame go on (one per input); those behind the images never will.
    for (auto it = held_.begin(); it != held_.end();) {
      const bool mine = it->first == stamp, late = behindImages(it->first);
      if (!mine && !late) {
        ++it;
        continue;
      }
      Input& input = inputs_[it->second.input];
      --input.held;
      if (mine && input.passed.insert(stamp).second) {
        released.push_back(std::move(it->second.release));
      } else {
        drop(it->second.input, it->first, it->second.publisher,
             mine ? "a second message for one frame" : "no image of its stamp arrived", &warnings);
      }
      it = held_.erase(it);
    }
    // Stamps passed on are remembered as long as their images are.
    const ros::Time oldest = *image_set_.begin();
    for (Input& input : inputs_)
      while (!input.passed.empty() && *input.passed.begin() < oldest) input.passed.erase(input.passed.begin());
  }
  for (const std::string& text : warnings) warn_(text);
  return released;
}

FrameStampGate::Verdict FrameStampGate::offer(size_t index, const ros::Time& stamp, const std::string& publisher,
                                              Release release) {
  std::vector<std::string> warnings;
  Verdict verdict = Verdict::kHold;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Input& input = inputs_.at(index);
    bool held_already = false;
    for (auto range = held_.equal_range(stamp); range.first != range.second; ++range.first)
      held_already = held_already || range.first->second.input == index;
    if (input.passed.count(stamp) || held_already) {
      drop(index, stamp, publisher, "a second message for one frame", &warnings);
      verdict = Verdict::kDrop;
    } else if (image_set_.count(stamp)) {
      input.passed.insert(stamp);
      verdict = Verdict::kPass;
    } else if (behindImages(stamp)) {
      drop(index, stamp, publisher, "no image has its stamp", &warnings);
      verdict = Verdict::kDrop;
    } else {
      held_.emplace(stamp, Held{index, publisher, std::move(release)});
      if (++input.held > held_per_input_) {
        // The farthest ahead goes: a frame's own message is the nearest to the images.
        auto farthest = held_.end();
        for (auto it = held_.begin(); it != held_.end(); ++it)
          if (it->second.input == index) farthest = it;
        // No other message of this input was held at this stamp: the farthest may be the new one.
        if (farthest->first == stamp) verdict = Verdict::kDrop;
        drop(index, farthest->first, farthest->second.publisher, "stamped ahead of every image", &warnings);
        held_.erase(farthest);
        --input.held;
      }
    }
  }
  for (const std::string& text : warnings) warn_(text);
  return verdict;
}

uint64_t FrameStampGate::dropped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return dropped_;
}

void FrameStampGate::reset() {
  std::lock_guard<std::mutex> lock(mutex_);
  images_.clear();
  image_set_.clear();
  held_.clear();
  for (Input& input : inputs_) {
    const double warned_at = input.warned_at;  // the throttle survives a resubscription
    input = Input();
    input.warned_at = warned_at;
  }
}

}  // namespace embedded_calibration_stereo
