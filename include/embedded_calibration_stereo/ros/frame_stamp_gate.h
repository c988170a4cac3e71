#pragma once
// Which per-frame messages (calibration_mode) may join a synchroniser: only those of a frame whose
// images exist. A synchroniser keeps a bounded queue of incomplete sets and evicts the oldest
// when it is full: a stream of calibration_mode messages at stamps no image has (stamped ahead
// within the stamp tolerance, stamped with the clock, duplicated) would fill it and push out
// every live frame before its last message arrived. The gate holds such a message until an image
// of its stamp is seen, passes at most one message per input and stamp, and lets a held message
// go (with a throttled warning naming its publisher) once images of later stamps have arrived or
// when nearer ones need its place. A flood then costs only its own messages.
//
// Use: offer(...) for every per-frame message, image(stamp) for every image let into the
// synchroniser (it returns the held messages of that stamp, to be passed on after it).
//
// Threads: every method may be called from any thread (one internal mutex).
#include <ros/time.h>

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <vector>

namespace embedded_calibration_stereo {

class FrameStampGate {
 public:
  using Warn = std::function<void(const std::string&)>;  // one warning line
  using Clock = std::function<double()>;                 // monotonic seconds
  enum class Verdict { kPass, kHold, kDrop };

  // `topics`: the resolved names of the per-frame inputs, by index; `owner`: who drops (the
  // nodelet's name); `held_per_input`: how many messages ahead of the images one input may hold.
  // A message stays held until two later images came: messages at stamps no image has cost a
  // frame's own message its place only when more than held_per_input arrive within two frame
  // periods (the default holds a 200 Hz stream at 15 fps).
  FrameStampGate(std::vector<std::string> topics, std::string owner, size_t held_per_input = kHeldPerInput,
                 Warn warn = nullptr, Clock clock = nullptr);

  // A message to pass on later (it captures the message).
  using Release = std::function<void()>;

  // An image of `stamp` joins the synchroniser. Returns the held messages of that stamp, to be
  // passed on after the image (outside any lock of the caller's); held messages of stamps older
  // than the two latest images' are dropped (their frame never came).
  std::vector<Release> image(const ros::Time& stamp);

  // A message of input `input` stamped `stamp`, from `publisher`. kPass: pass it on now. kHold:
  // kept as `release`, returned by image() when its frame comes. kDrop: a second message of the
  // input for one stamp, one older than the images with no image of its stamp, or the farthest
  // ahead of more than held_per_input.
  Verdict offer(size_t input, const ros::Time& stamp, const std::string& publisher, Release release);

  uint64_t dropped() const;
  void reset();

  static constexpr size_t kHeldPerInput = 32;
  static constexpr size_t kRecentImages = 64;  // image stamps remembered (about 2 s at 30 fps)
  static constexpr double kWarnPeriodS = 5.0;

 private:
  struct Held {
    size_t input;
    std::string publisher;
    Release release;
  };
  struct Input {
    std::set<ros::Time> passed;  // stamps passed on (bounded as the recent images)
    size_t held = 0;
    double warned_at = -1;
    uint64_t dropped_since_warning = 0;
  };
  void drop(size_t input, const ros::Time& stamp, const std::string& publisher, const char* why,
            std::vector<std::string>* warnings);  // mutex_ held
  bool behindImages(const ros::Time& stamp) const;  // mutex_ held: older than the two latest images

  const std::vector<std::string> topics_;
  const std::string owner_;
  const size_t held_per_input_;
  const Warn warn_;
  const Clock clock_;
  mutable std::mutex mutex_;  // guards everything below
  std::deque<ros::Time> images_;  // recent image stamps, in arrival order
  std::set<ros::Time> image_set_;
  std::multimap<ros::Time, Held> held_;
  std::vector<Input> inputs_;
  uint64_t dropped_ = 0;
};

}  // namespace embedded_calibration_stereo
