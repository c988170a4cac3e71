#include "embedded_calibration_stereo/core/depth/stereo_device_template.h"

#include <algorithm>
#include <stdexcept>

namespace embedded_calibration_stereo::core {

namespace {

// Adds `image - scene` (scene may be empty: the frame itself) to `sum`.
void accumulate(const cv::Mat& image, const cv::Mat& scene, cv::Mat* sum) {
  cv::Mat device;
  image.convertTo(device, CV_64F);
  if (!scene.empty()) {
    cv::Mat scene64;
    scene.convertTo(scene64, CV_64F);
    device -= scene64;  // noise may make it negative: kept, so the mean stays unbiased
  }
  if (sum->empty()) {
    *sum = device;
  } else {
    *sum += device;
  }
}

DeviceTemplate templateFrom(const cv::Mat& sum, int frames, uint32_t epoch) {
  DeviceTemplate templ;
  sum.convertTo(templ.device, CV_32F, 1.0 / frames);
  templ.calibration_epoch = epoch;
  templ.frames_averaged = frames;
  return templ;  // default alpha curve (alpha 1): paper_global_alpha without a taught curve
}

}  // namespace

SceneRoute routeFrame(bool light_on, bool settled, const StereoSeparator* separator, uint32_t frame_epoch,
                      bool epoch_must_match) {
  if (!light_on) return SceneRoute::kLightOff;
  if (!settled) return SceneRoute::kLightChanging;
  if (!separator) return SceneRoute::kNoTemplate;
  if (epoch_must_match && separator->epoch() != frame_epoch) return SceneRoute::kOtherEpoch;
  return SceneRoute::kSeparate;
}

void StereoTemplateTeach::start() { restart(0); }

bool StereoTemplateTeach::startFor(uint32_t epoch) {
  if (active_ && epoch_ == epoch) return false;
  restart(epoch);
  return true;
}

void StereoTemplateTeach::restart(uint32_t epoch) {
  active_ = true;
  epoch_ = epoch;
  count_ = 0;
  left_sum_.release();
  right_sum_.release();
}

StereoTemplateTeach::Step StereoTemplateTeach::add(const cv::Mat& left, const cv::Mat& right, const cv::Mat& left_scene,
                                                   const cv::Mat& right_scene, uint32_t epoch) {
  Step step;
  if (count_ == 0) epoch_ = epoch;
  // The device image moved with the calibration: frames of another epoch start over.
  if (epoch != epoch_) step.restarted = startFor(epoch);
  try {
    accumulate(left, left_scene, &left_sum_);
    accumulate(right, right_scene, &right_sum_);
    if (++count_ < frames_) return step;
    active_ = false;
    step.taught = std::make_shared<const StereoSeparator>(options_, templateFrom(left_sum_, count_, epoch),
                                                          templateFrom(right_sum_, count_, epoch));
  } catch (const cv::Exception& e) {  // frames of another size or type than the teach's first
    active_ = false;
    throw std::invalid_argument(std::string("device frames do not match: ") + e.what());
  } catch (...) {
    active_ = false;
    throw;
  }
  return step;
}

std::vector<cv::Mat> middleFrames(const WindowFrames& frames, int per_end) {
  const int n = static_cast<int>(frames.light_on.size());
  if (n <= 2 * per_end) return frames.light_on;
  std::vector<cv::Mat> middle;
  const int first = per_end, count = n - 2 * per_end, step = std::max(1, count / 3);
  for (int i = first; i < first + count && middle.size() < 3; i += step) middle.push_back(frames.light_on[i]);
  return middle;
}

DeviceLearnerOptions separatorLearnerOptions() {
  DeviceLearnerOptions options = windowLearnerOptions();
  options.flow_finest_scale = 2;
  return options;
}

StereoLearnResult learnStereoDevice(const WindowFrames& left, const WindowFrames& right, bool whole, int per_end,
                                    const DeviceLearnerOptions& options, const SeparatorOptions& separator_options,
                                    const std::shared_ptr<const StereoSeparator>& in_use, uint32_t epoch) {
  StereoLearnResult result;
  const WindowFrames* frames[2] = {&left, &right};
  try {
    LearnedDevice learned[2];
    std::string errors[2];
    // One camera at a time, its pairs in parallel (learning both at once doubles the peak memory).
    for (int c = 0; c < 2; ++c) try {
        learned[c] = learnWindowDevice(whole ? windowEnds(*frames[c], per_end) : *frames[c], options);
        learned[c].device_template.calibration_epoch = epoch;
      } catch (const std::exception& e) {
        errors[c] = (c ? "right: " : "left: ") + std::string(e.what());
      }
    result.error = errors[0].empty() ? errors[1] : errors[0];
    if (!result.error.empty()) return result;
    result.left = std::move(learned[0]);
    result.right = std::move(learned[1]);
    result.separator = std::make_shared<const StereoSeparator>(separator_options, result.left.device_template,
                                                               result.right.device_template);
    if (!in_use) return result;
    result.residual_new = result.residual_in_use = 0.0;
    for (int c = 0; c < 2; ++c) {
      const std::vector<cv::Mat> middle = middleFrames(*frames[c], per_end);
      result.residual_new += separationResidual(c ? result.separator->right : result.separator->left, middle);
      result.residual_in_use += separationResidual(c ? in_use->right : in_use->left, middle);
    }
  } catch (const std::exception& e) {
    result.error = e.what();
  }
  return result;
}

bool DeviceLearningPlan::learnUnderWay(int light_on_frames, bool light_off_before) const {
  return !has_template_ && light_off_before && light_on_frames == 2 * per_end_;
}

bool DeviceLearningPlan::adopt(const StereoLearnResult& result) const {
  if (!result.error.empty() || !result.separator) return false;
  return !(has_template_ && result.residual_in_use >= 0.0 && result.residual_new > result.residual_in_use);
}

}  // namespace embedded_calibration_stereo::core
