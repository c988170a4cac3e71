#pragma once
// Which input holds a synchronised stream back: the LightController pairs an external driver's
// images and camera_infos by stamp, and when no stereo frame comes out it names the inputs that
// did not arrive (docs/nodelets.md#lightcontroller, "frames held back").
//
// Threading: plain values; used by one thread at a time.
#include <cstdint>
#include <string>
#include <vector>

namespace embedded_calibration_stereo::core {

class InputArrivalWatch {
 public:
  /// `inputs`: each input as named after "no " (e.g. "image on /driver/left/image_raw");
  /// `unpaired`: what is wrong when every input arrives but none pair.
  InputArrivalWatch(std::vector<std::string> inputs, std::string unpaired);

  /// A message of input `index` arrived.
  void arrived(size_t index) { ++arrived_[index]; }
  /// A matched set went out of the synchroniser.
  void frameIn() { ++frames_in_; }
  /// The matched sets so far.
  uint64_t framesIn() const { return frames_in_; }

  /// Once a period: "" while matched sets come in, or while nothing arrives at all (the driver
  /// has not started); otherwise "no <input>, no <input>" for the inputs silent over the
  /// period, or `unpaired` when all of them arrived.
  std::string tick();

 private:
  std::vector<std::string> inputs_;
  std::string unpaired_;
  std::vector<uint64_t> arrived_, arrived_at_tick_;
  uint64_t frames_in_ = 0, frames_in_at_tick_ = 0;
};

}  // namespace embedded_calibration_stereo::core
