// The sim backend: renders the simulated rig at the light level set by the sim light backend.
#include "embedded_calibration_stereo/ros/frame_source.h"

#include <stdexcept>

namespace embedded_calibration_stereo {
namespace {

class SimFrameSource : public FrameSource {
 public:
  SimFrameSource(std::shared_ptr<core::SimRig> sim, SharedLightLevel light_level, SharedLightCommand light_command,
                 double fps)
      : sim_(std::move(sim)), light_level_(std::move(light_level)), light_command_(std::move(light_command)), fps_(fps) {
    if (!(fps_ > 0.0)) throw std::invalid_argument("sim frame source: fps must be > 0");
  }

  // The wall time of the grab is not used: the scene's time is the frame index / fps, so that a
  // run renders the same frames (motion, movers, drift, the light's response) however fast the
  // machine is.
  bool grab(double, StereoFrame* frame, std::string*) override {
    core::SimRenderRequest request;
    request.time_s = static_cast<double>(frame_count_) / fps_;
    request.light_level = light_level_ ? light_level_->load() : 0.0;
    // The frame counter seeds the noise: a replay of the same run renders the same images.
    request.noise_seed = ++frame_count_;
    if (light_command_) {
      // The light backend is applied just before each grab: a new switch count means the
      // command changed for this frame.
      const uint64_t command = light_command_->load();
      if (command >> 1 != switches_seen_) {
        switches_seen_ = command >> 1;
        switch_time_s_ = request.time_s;
      }
      request.has_light_command = true;
      request.light_command.on = (command & 1) != 0;
      request.light_command.switch_time_s = switch_time_s_;
    }
    auto truth = std::make_shared<core::SimFrame>(sim_->render(request));
    frame->left = truth->left;
    frame->right = truth->right;
    frame->encoding = sim_->config().encoding;
    frame->light_on.reset();
    frame->truth = std::move(truth);
    return true;
  }

  cv::Size imageSize() const override {
    return cv::Size(sim_->config().rig.left.width, sim_->config().rig.left.height);
  }

 private:
  std::shared_ptr<core::SimRig> sim_;
  SharedLightLevel light_level_;
  SharedLightCommand light_command_;  // null: the schedule's level only
  double fps_;
  uint64_t frame_count_ = 0;  // frames rendered so far: the next frame's index
  uint64_t switches_seen_ = 0;
  double switch_time_s_ = -1e300;  // never switched: off since forever
};

}  // namespace

std::unique_ptr<FrameSource> makeSimFrameSource(std::shared_ptr<core::SimRig> sim,
                                                SharedLightLevel light_level, double fps) {
  return std::make_unique<SimFrameSource>(std::move(sim), std::move(light_level), nullptr, fps);
}

std::unique_ptr<FrameSource> makeSimFrameSource(std::shared_ptr<core::SimRig> sim, SharedLightLevel light_level,
                                                SharedLightCommand light_command, double fps) {
  return std::make_unique<SimFrameSource>(std::move(sim), std::move(light_level), std::move(light_command), fps);
}

}  // namespace embedded_calibration_stereo
