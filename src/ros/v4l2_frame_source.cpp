// The v4l2 backend: two V4L2 devices, or one side-by-side device whose frames are split into
// a left and a right half, through cv::VideoCapture.
#include <sys/stat.h>

#include <opencv2/videoio.hpp>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/frame_source.h"

namespace embedded_calibration_stereo {
namespace {

class V4l2FrameSource : public FrameSource {
 public:
  explicit V4l2FrameSource(const V4l2SourceParams& params) : params_(params) {
    if (params_.width <= 0) throw core::ConfigError("v4l2_width", "must be > 0");
    if (params_.height <= 0) throw core::ConfigError("v4l2_height", "must be > 0");
    if (!(params_.fps > 0)) throw core::ConfigError("fps", "must be > 0");
    if (params_.encoding != "mono8" && params_.encoding != "bgr8")
      throw core::ConfigError("encoding", "must be mono8 or bgr8 (got '" + params_.encoding + "')");
    side_by_side_ = params_.right_device.empty();
    open(&left_, "v4l2_left_device", params_.left_device, side_by_side_ ? 2 * params_.width : params_.width);
    if (!side_by_side_) open(&right_, "v4l2_right_device", params_.right_device, params_.width);
  }

  bool grab(double, StereoFrame* frame, std::string* error) override {
    // grab() both before retrieve() so that the two exposures are as close as possible.
    if (!left_.grab() || (!side_by_side_ && !right_.grab())) {
      if (error) *error = "V4L2 grab failed";
      return false;
    }
    cv::Mat left, right;
    if (!left_.retrieve(left) || (!side_by_side_ && !right_.retrieve(right))) {
      if (error) *error = "V4L2 retrieve failed";
      return false;
    }
    if (side_by_side_) {
      const int half = left.cols / 2;
      right = left(cv::Rect(half, 0, half, left.rows)).clone();
      left = left(cv::Rect(0, 0, half, left.rows)).clone();
    }
    if (left.size() != right.size()) {
      if (error) *error = "left and right frames differ in size";
      return false;
    }
    frame->left = convertToEncoding(left, params_.encoding);
    frame->right = convertToEncoding(right, params_.encoding);
    frame->encoding = params_.encoding;
    frame->light_on.reset();
    return true;
  }

  cv::Size imageSize() const override { return cv::Size(params_.width, params_.height); }

 private:
  void open(cv::VideoCapture* capture, const char* parameter, const std::string& device, int width) {
    struct stat st;
    if (device.empty()) throw core::ConfigError(parameter, "missing");
    if (stat(device.c_str(), &st) != 0) throw core::ConfigError(parameter, "device does not exist: '" + device + "'");
    if (!capture->open(device, cv::CAP_V4L2))
      throw core::ConfigError(parameter, "cannot open V4L2 device '" + device + "'");
    capture->set(cv::CAP_PROP_FRAME_WIDTH, width);
    capture->set(cv::CAP_PROP_FRAME_HEIGHT, params_.height);
    capture->set(cv::CAP_PROP_FPS, params_.fps);
    const int got_w = static_cast<int>(capture->get(cv::CAP_PROP_FRAME_WIDTH));
    const int got_h = static_cast<int>(capture->get(cv::CAP_PROP_FRAME_HEIGHT));
    if (got_w != width || got_h != params_.height)
      throw core::ConfigError(parameter, "'" + device + "' does not support " + std::to_string(width) + "x" +
                                            std::to_string(params_.height) + " (got " + std::to_string(got_w) +
                                            "x" + std::to_string(got_h) + "); check v4l2_width/v4l2_height");
  }

  V4l2SourceParams params_;
  bool side_by_side_ = false;
  cv::VideoCapture left_, right_;
};

}  // namespace

std::unique_ptr<FrameSource> makeV4l2FrameSource(const V4l2SourceParams& params) {
  return std::make_unique<V4l2FrameSource>(params);
}

}  // namespace embedded_calibration_stereo
