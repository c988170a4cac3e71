// The sim backend: renders the simulated rig at the light level set by the sim light backend.
#include "embedded_calibration_stereo/ros/frame_source.h"

namespace embedded_calibration_stereo {
namespace {

class SimFrameSource : public FrameSource {
 public:
  SimFrameSource(std::shared_ptr<ecs::SimRig> sim, SharedLightLevel light_level)
      : sim_(std::move(sim)), light_level_(std::move(light_level)) {}

  bool grab(double time_s, StereoFrame* frame, std::string*) override {
    const double level = light_level_ ? light_level_->load() : 0.0;
    // The frame counter seeds the noise: a replay of the same run renders the same images.
    auto truth = std::make_shared<ecs::SimFrame>(sim_->render(time_s, level, ++frame_count_));
    frame->left = truth->left;
    frame->right = truth->right;
    frame->encoding = sim_->config().encoding;
    frame->light_on.reset();
    frame->truth = std::move(truth);
    return true;
  }

  std::optional<ecs::StereoRig> nominalRig() const override { return sim_->config().rig; }
  cv::Size imageSize() const override {
    return cv::Size(sim_->config().rig.left.width, sim_->config().rig.left.height);
  }

 private:
  std::shared_ptr<ecs::SimRig> sim_;
  SharedLightLevel light_level_;
  uint64_t frame_count_ = 0;
};

}  // namespace

std::unique_ptr<FrameSource> makeSimFrameSource(std::shared_ptr<ecs::SimRig> sim,
                                                SharedLightLevel light_level) {
  return std::make_unique<SimFrameSource>(std::move(sim), std::move(light_level));
}

}  // namespace embedded_calibration_stereo
