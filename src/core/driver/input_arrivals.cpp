#include "embedded_calibration_stereo/core/driver/input_arrivals.h"

#include <utility>

namespace embedded_calibration_stereo::core {

InputArrivalWatch::InputArrivalWatch(std::vector<std::string> inputs, std::string unpaired)
    : inputs_(std::move(inputs)),
      unpaired_(std::move(unpaired)),
      arrived_(inputs_.size(), 0),
      arrived_at_tick_(inputs_.size(), 0) {}

std::string InputArrivalWatch::tick() {
  const bool frames = frames_in_ != frames_in_at_tick_;
  frames_in_at_tick_ = frames_in_;
  bool any = false;
  for (size_t i = 0; i < inputs_.size(); ++i) any = any || arrived_[i] != arrived_at_tick_[i];
  std::string missing;
  if (!frames && any) {
    for (size_t i = 0; i < inputs_.size(); ++i)
      if (arrived_[i] == arrived_at_tick_[i]) missing += (missing.empty() ? "no " : ", no ") + inputs_[i];
    if (missing.empty()) missing = unpaired_;
  }
  arrived_at_tick_ = arrived_;
  return missing;
}

}  // namespace embedded_calibration_stereo::core
