// rostest: the Separator nodelet (separator_sim.test). The driver and the Separator are loaded
// into THIS process (nodelet::Loader), so that the test's subscribers are in the same process as
// the publishers: roscpp then hands them the published shared pointer itself (intraprocess, no
// serialisation), and pointer identity of image_raw and image_scene can be checked.
#include <gtest/gtest.h>
#include <nodelet/loader.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/SetCameraInfo.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>

#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "depth_test_utils.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using test_support::Collector;
using test_support::waitUntil;
using sensor_msgs::Image;

namespace {

constexpr int kTeachFrames = 4;
std::unique_ptr<nodelet::Loader> loader;  // created in main, after ros::init
test_support::TempDir calibration_dir("ecs_separator_sim");

void setParams(const std::string& name, const test_support::InProcessManager::Params& params) {
  for (const auto& p : params) ros::param::set(name + "/" + p.first, p.second);
}

// The simulated driver and a Separator teaching from ground truth, in namespace /sim.
bool loadSimPipeline() {
  static bool loaded = false;
  if (loaded) return true;
  setParams("/sim/camera_driver", {{"backend", "sim"},
                                   {"sim_config", std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml"},
                                   {"fps", 10.0},
                                   {"settle_frames", 2},
                                   {"calibration_period_s", 0.0},
                                   {"left_camera_info_url", "file://" + calibration_dir.path + "/left.yaml"},
                                   {"right_camera_info_url", "file://" + calibration_dir.path + "/right.yaml"}});
  setParams("/sim/separator", {{"teach_from_ground_truth", true}, {"teach_frames", kTeachFrames}});
  loaded = loader->load("/sim/camera_driver", "embedded_calibration_stereo/CameraDriver", ros::M_string(), {}) &&
           loader->load("/sim/separator", "embedded_calibration_stereo/Separator", ros::M_string(), {});
  return loaded;
}


double psnr(const cv::Mat& a, const cv::Mat& b) {
  const double mse = cv::norm(a, b, cv::NORM_L2SQR) / double(a.total() * a.channels());
  return 10.0 * std::log10(255.0 * 255.0 / std::max(mse, 1e-12));
}

cv::Mat view(const Image& m) {
  return cv::Mat(m.height, m.width, m.encoding == "mono8" ? CV_8UC1 : CV_8UC3, const_cast<uint8_t*>(m.data.data()),
                 m.step);
}

// One stereo frame as a driver sends it: the same mono8 image left and right, then its
// calibration_mode (with the images' stamp).
void publishMonoFrame(ros::Publisher& left_pub, ros::Publisher& right_pub, ros::Publisher& mode_pub,
                      const cv::Mat& image, const CalibrationMode::Ptr& mode) {
  for (auto* pub : {&left_pub, &right_pub}) {
    auto msg = boost::make_shared<Image>();
    msg->header.stamp = mode->header.stamp;
    msg->encoding = "mono8";
    msg->width = image.cols;
    msg->height = image.rows;
    msg->step = image.cols;
    msg->data.assign(image.datastart, image.dataend);
    pub->publish(msg);
  }
  mode_pub.publish(mode);
}

using Pairs = std::vector<std::pair<Image::ConstPtr, Image::ConstPtr>>;  // (raw, scene)

// The separated frames among `scenes`: image_scene of a light-on settled stamp that is not the raw
// object, with a truth image.
Pairs separatedFrames(const std::vector<Image::ConstPtr>& scenes, const std::vector<Image::ConstPtr>& raws,
                      const std::vector<Image::ConstPtr>& truths, const std::vector<CalibrationMode::ConstPtr>& modes) {
  Pairs out;
  for (const auto& s : scenes) {
    const auto source = test_support::findByStamp(raws, s->header.stamp);
    const auto mode = test_support::findByStamp(modes, s->header.stamp);
    if (source && mode && mode->light_on && mode->settled && source.get() != s.get() &&
        test_support::findByStamp(truths, s->header.stamp))
      out.emplace_back(source, s);
  }
  return out;
}

// What a camera's image_scene messages were, for a failure message.
std::string sceneCensus(const std::vector<Image::ConstPtr>& scenes, const std::vector<Image::ConstPtr>& raws,
                        const std::vector<Image::ConstPtr>& truths, const std::vector<CalibrationMode::ConstPtr>& modes) {
  int total = 0, lit = 0, raw_object = 0, no_raw = 0, no_truth = 0;
  for (const auto& s : scenes) {
    ++total;
    const auto mode = test_support::findByStamp(modes, s->header.stamp);
    if (!mode || !mode->light_on || !mode->settled) continue;
    ++lit;
    const auto source = test_support::findByStamp(raws, s->header.stamp);
    no_raw += !source;
    raw_object += source && source.get() == s.get();
    no_truth += !test_support::findByStamp(truths, s->header.stamp);
  }
  return std::to_string(total) + " messages, " + std::to_string(lit) + " of settled light-on stamps: " +
         std::to_string(raw_object) + " the raw image itself, " + std::to_string(no_raw) + " without a raw image, " +
         std::to_string(no_truth) + " without a truth image";
}

// The separated frames of one camera against the truth: headers and sizes kept, PSNR >= 35 dB,
// closer to the truth than any raw light-on frame.
void expectSeparatedScene(const char* side, const Pairs& frames, const std::vector<Image::ConstPtr>& truths) {
  double worst = 1e9, sum = 0, worst_raw = 0;
  for (const auto& f : frames) {
    const Image& r = *f.first;
    const Image& s = *f.second;
    EXPECT_EQ(s.header.stamp, r.header.stamp);
    EXPECT_EQ(s.header.frame_id, r.header.frame_id);
    EXPECT_EQ(s.header.seq, r.header.seq);
    EXPECT_EQ(s.encoding, r.encoding);
    ASSERT_EQ(s.width, r.width);
    ASSERT_EQ(s.height, r.height);
    const auto t = test_support::findByStamp(truths, s.header.stamp);
    const double p = psnr(view(s), view(*t));
    worst = std::min(worst, p);
    sum += p;
    worst_raw = std::max(worst_raw, psnr(view(r), view(*t)));
  }
  std::printf("%s image_scene vs ground truth over %zu separated frames: PSNR mean %.1f dB, worst %.1f dB "
              "(raw light-on frames: at best %.1f dB)\n",
              side, frames.size(), sum / frames.size(), worst, worst_raw);
  EXPECT_GE(worst, 35.0) << side;
  EXPECT_LT(worst_raw, worst) << "the raw frames are as close to the scene: nothing was separated";
}

}  // namespace

// Light off: image_scene is the very message published on image_raw (same object address).
TEST(SeparatorSim, DepthModeRepublishesTheRawPointers) {
  ros::NodeHandle nh("/sim");
  Collector<Image> raw(nh, "left/image_raw", 200), scene(nh, "left/image_scene", 200);
  Collector<Image> right_raw(nh, "right/image_raw", 200), right_scene(nh, "right/image_scene", 200);
  ASSERT_TRUE(loadSimPipeline());
  int checked = 0;
  ASSERT_TRUE(scene.waitFor(
      [&](const std::vector<Image::ConstPtr>& m) {
        checked = 0;
        const auto raws = raw.snapshot();
        for (const auto& s : m) checked += test_support::findByStamp(raws, s->header.stamp) != nullptr;
        return checked >= 5;
      },
      20.0))
      << "fewer than 5 image_scene frames with their image_raw";
  ASSERT_TRUE(right_scene.waitForCount(5, 5.0));
  const auto raws = raw.snapshot(), right_raws = right_raw.snapshot();
  int identical = 0, right_identical = 0;
  for (const auto& s : scene.snapshot()) {
    const auto r = test_support::findByStamp(raws, s->header.stamp);
    if (!r) continue;
    EXPECT_EQ(s.get(), r.get()) << "left image_scene at " << s->header.stamp << " is a copy";
    identical += s.get() == r.get();
  }
  for (const auto& s : right_scene.snapshot()) {
    const auto r = test_support::findByStamp(right_raws, s->header.stamp);
    if (r) right_identical += s.get() == r.get();
  }
  std::printf("depth mode: %d left and %d right image_scene messages are the image_raw objects themselves\n",
              identical, right_identical);
  EXPECT_GE(identical, 5);
  EXPECT_GE(right_identical, 3);
}

// Light on: after teaching from ground truth, image_scene is a new message with the raw header
// whose pixels match the simulator's scene-only image of the same stamp.
TEST(SeparatorSim, CalibrationModePublishesTheSeparatedScene) {
  ros::NodeHandle nh("/sim");
  Collector<Image> raw(nh, "left/image_raw", 300), scene(nh, "left/image_scene", 300);
  Collector<Image> truth(nh, "ground_truth/left/image_scene", 300);
  Collector<Image> right_raw(nh, "right/image_raw", 300), right_scene(nh, "right/image_scene", 300);
  Collector<Image> right_truth(nh, "ground_truth/right/image_scene", 300);
  Collector<CalibrationMode> modes(nh, "calibration_mode", 300);
  ASSERT_TRUE(loadSimPipeline());
  ASSERT_TRUE(modes.waitForCount(2, 20.0));
  std_srvs::SetBool light;
  light.request.data = true;
  ASSERT_TRUE(ros::service::call("/sim/set_light", light));
  ASSERT_TRUE(light.response.success) << light.response.message;

  const auto separated = [&](Collector<Image>& raws, Collector<Image>& truths, const std::vector<Image::ConstPtr>& m) {
    return separatedFrames(m, raws.snapshot(), truths.snapshot(), modes.snapshot());
  };
  ASSERT_TRUE(scene.waitFor([&](const std::vector<Image::ConstPtr>& m) { return separated(raw, truth, m).size() >= 5; },
                            40.0))
      << "fewer than 5 separated light-on frames";
  // The right camera is taught on its own: under a loaded machine it can follow the left by
  // several seconds (a wait, not a sleep: a passing run does not take longer).
  ASSERT_TRUE(right_scene.waitFor(
      [&](const std::vector<Image::ConstPtr>& m) { return separated(right_raw, right_truth, m).size() >= 3; }, 30.0))
      << "fewer than 3 separated right light-on frames within 30 s of the left's 5: "
      << sceneCensus(right_scene.snapshot(), right_raw.snapshot(), right_truth.snapshot(), modes.snapshot());
  light.request.data = false;
  EXPECT_TRUE(ros::service::call("/sim/set_light", light));

  // Light-on settled frames before the template existed went out raw (depth never stops).
  int raw_light_on = 0;
  for (const auto& s : scene.snapshot()) {
    const auto mode = test_support::findByStamp(modes.snapshot(), s->header.stamp);
    const auto source = test_support::findByStamp(raw.snapshot(), s->header.stamp);
    raw_light_on += mode && mode->light_on && source && source.get() == s.get();
  }
  EXPECT_GE(raw_light_on, kTeachFrames) << "light-on frames during the teach were not republished raw";

  expectSeparatedScene("left", separated(raw, truth, scene.snapshot()), truth.snapshot());
  expectSeparatedScene("right", separated(right_raw, right_truth, right_scene.snapshot()), right_truth.snapshot());
}

// After a calibration change (left/set_camera_info: epoch + 1) the template of the old epoch is
// not used: the Separator re-teaches from ground truth and separates frames of the new epoch.
// Runs after the calibration-mode test (light switched on again here).
TEST(SeparatorSim, ReteachesAfterACalibrationEpochChange) {
  ros::NodeHandle nh("/sim");
  Collector<Image> raw(nh, "left/image_raw", 300), scene(nh, "left/image_scene", 300);
  Collector<Image> truth(nh, "ground_truth/left/image_scene", 300);
  Collector<CalibrationMode> modes(nh, "calibration_mode", 300);
  Collector<sensor_msgs::CameraInfo> info(nh, "left/camera_info", 10);
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 1000);
  ASSERT_TRUE(loadSimPipeline());
  ASSERT_TRUE(info.waitForCount(1, 20.0));
  ASSERT_TRUE(modes.waitForCount(1, 20.0));  // as camera_info: a new subscriber connects slowly on a loaded machine
  const uint32_t old_epoch = modes.snapshot().back()->calibration_epoch;
  sensor_msgs::SetCameraInfo set_info;
  set_info.request.camera_info = *info.snapshot().back();
  set_info.request.camera_info.K[0] += 1.0;
  ASSERT_TRUE(ros::service::call("/sim/left/set_camera_info", set_info));
  ASSERT_TRUE(set_info.response.success) << set_info.response.status_message;
  std_srvs::SetBool light;
  light.request.data = true;
  ASSERT_TRUE(ros::service::call("/sim/set_light", light));
  // A separated frame (not the raw object) of a newer epoch, with its ground truth.
  Image::ConstPtr separated, separated_truth;
  ASSERT_TRUE(scene.waitFor(
      [&](const std::vector<Image::ConstPtr>& m) {
        const auto r = raw.snapshot(), t = truth.snapshot();
        const auto md = modes.snapshot();
        for (const auto& s : m) {
          const auto mode = test_support::findByStamp(md, s->header.stamp);
          const auto source = test_support::findByStamp(r, s->header.stamp);
          separated_truth = test_support::findByStamp(t, s->header.stamp);
          if (mode && source && separated_truth && mode->calibration_epoch > old_epoch && source.get() != s.get()) {
            separated = s;
            return true;
          }
        }
        return false;
      },
      40.0))
      << "no separated frame of the new calibration epoch";
  light.request.data = false;
  EXPECT_TRUE(ros::service::call("/sim/set_light", light));
  std::string found;
  EXPECT_TRUE(test_support::waitForLog(log, {"Separator: device image taught", "epoch " + std::to_string(old_epoch + 1)},
                                   5.0, &found));
  const double p = psnr(view(*separated), view(*separated_truth));
  std::printf("after the epoch change: '%s'; PSNR %.1f dB\n", found.c_str(), p);
  EXPECT_GE(p, 35.0);
}

// The hardware teach path: `teach` averages the next light-on settled frames (here the device
// alone, as with the scene covered); later light-on frames (scene + device) come out as the scene.
TEST(SeparatorTeachService, TeachesFromCoveredSceneFrames) {
  ros::NodeHandle nh("/hw");
  Collector<Image> scene(nh, "left/image_scene", 50);
  ros::Publisher left_pub = nh.advertise<Image>("left/image_raw", 5);
  ros::Publisher right_pub = nh.advertise<Image>("right/image_raw", 5);
  ros::Publisher mode_pub = nh.advertise<CalibrationMode>("calibration_mode", 5);
  ros::param::set("/hw/separator/teach_frames", 3);
  ros::param::set("/hw/separator/device_template", std::string("teach"));  // the factory step
  ASSERT_TRUE(loader->load("/hw/separator", "embedded_calibration_stereo/Separator", ros::M_string(), {}));
  ASSERT_TRUE(waitUntil(
      [&] { return left_pub.getNumSubscribers() && right_pub.getNumSubscribers() && mode_pub.getNumSubscribers(); },
      10.0));
  std_srvs::Trigger teach;
  ASSERT_TRUE(ros::service::call("/hw/separator/teach", teach));
  EXPECT_TRUE(teach.response.success) << teach.response.message;

  // Device: a 8 px checkerboard of 0 / 90 over 128x96; scene: a random texture in 20..150.
  cv::Mat device(96, 128, CV_8UC1), scene_image(96, 128, CV_8UC1);
  for (int v = 0; v < device.rows; ++v)
    for (int u = 0; u < device.cols; ++u) device.at<uint8_t>(v, u) = ((u / 8 + v / 8) % 2) * 90;
  cv::RNG rng(3);
  rng.fill(scene_image, cv::RNG::UNIFORM, 20, 151);
  uint32_t sec = 200;
  const auto publish = [&](const cv::Mat& image) {
    const ros::Time stamp(++sec, 0);
    auto mode = boost::make_shared<CalibrationMode>();
    mode->header.stamp = stamp;
    mode->light_on = mode->settled = true;
    publishMonoFrame(left_pub, right_pub, mode_pub, image, mode);
    return stamp;
  };
  const auto published = [&](const ros::Time& stamp) {
    return scene.waitFor([&](const std::vector<Image::ConstPtr>& m) { return test_support::findByStamp(m, stamp) != nullptr; },
                         10.0);
  };
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(published(publish(device))) << "teach frame " << i << " not republished";
  const cv::Mat mixed = scene_image + device;
  const ros::Time stamp = publish(mixed);
  ASSERT_TRUE(published(stamp));
  const auto out = test_support::findByStamp(scene.snapshot(), stamp);
  const double p = psnr(view(*out), scene_image), p_raw = psnr(mixed, scene_image);
  std::printf("teach service: separated PSNR %.1f dB vs the scene (raw %.1f dB)\n", p, p_raw);
  EXPECT_GE(p, 35.0);
  loader->unload("/hw/separator");
}

namespace {

// The Separator of SeparatorLearn fed crafted frames in /learn: a static device pattern (a
// checkerboard) over a lens-blurred random texture that slides 2 px right and 1 px down per
// frame, 30 fps stamps, light bursts as a driver sends them.
class LearnRig {
 public:
  struct Out {
    double psnr = 0;   // image_scene against the true scene
    bool raw = false;  // image_scene is the raw frame, byte for byte
  };

  explicit LearnRig(ros::NodeHandle& nh)
      : scene(nh, "left/image_scene", 50),
        log(nh, "/rosout", 1000),
        device(size, CV_8UC1),
        left_pub_(nh.advertise<Image>("left/image_raw", 5)),
        right_pub_(nh.advertise<Image>("right/image_raw", 5)),
        mode_pub_(nh.advertise<CalibrationMode>("calibration_mode", 5)),
        canvas_(size.height + 200, size.width + 400, CV_8UC1) {
    for (int v = 0; v < device.rows; ++v)
      for (int u = 0; u < device.cols; ++u) device.at<uint8_t>(v, u) = ((u / 8 + v / 8) % 2) * 90;
    cv::RNG rng(5);
    rng.fill(canvas_, cv::RNG::UNIFORM, 20, 151);
    // A lens-blurred texture the flow can follow, stretched back to full contrast (grey 20..150).
    cv::GaussianBlur(canvas_, canvas_, cv::Size(0, 0), 2.5);
    cv::normalize(canvas_, canvas_, 20, 150, cv::NORM_MINMAX);
  }

  bool subscribed() const {
    return left_pub_.getNumSubscribers() && right_pub_.getNumSubscribers() && mode_pub_.getNumSubscribers();
  }

  cv::Mat sceneAt(int f) const {
    return canvas_(cv::Rect((2 * f) % 400, f % 200, size.width, size.height)).clone();
  }

  // Publishes the next frame (the device at `light` level), waits for its image_scene.
  Out publish(bool on, bool settled, double light) {
    const cv::Mat scene_image = sceneAt(frame);
    cv::Mat image;
    cv::addWeighted(scene_image, 1.0, device, light, 0.0, image);
    const ros::Time stamp = stampOf(frame);
    ++frame;
    auto mode = boost::make_shared<CalibrationMode>();
    mode->header.stamp = stamp;
    mode->light_on = on;
    mode->settled = settled;
    mode->calibration_epoch = epoch;
    publishMonoFrame(left_pub_, right_pub_, mode_pub_, image, mode);
    Image::ConstPtr out;
    EXPECT_TRUE(scene.waitFor(
        [&](const std::vector<Image::ConstPtr>& m) { return (out = test_support::findByStamp(m, stamp)) != nullptr; },
        10.0))
        << "frame " << frame - 1 << " not republished";
    if (!out) return Out{};
    return Out{psnr(view(*out), scene_image), cv::norm(view(*out), image, cv::NORM_INF) == 0.0};
  }

  static ros::Time stampOf(int f) { return ros::Time(300, 0) + ros::Duration(f / 30.0); }

  // Settled light-off frames, then the two unsettled frames of the switch on.
  void lightOn() {
    for (int i = 0; i < 3; ++i) publish(false, true, 0.0);
    publish(true, false, 0.33);
    publish(true, false, 0.67);
  }
  // The two unsettled frames of the switch off, then a settled light-off frame.
  void lightOff() {
    publish(false, false, 0.67);
    publish(false, false, 0.33);
    publish(false, true, 0.0);
  }

  // Light-off frames until the log has `needle` (a learning run is taken at a frame's arrival).
  bool waitLearned(const std::string& needle, std::string* found) {
    for (int i = 0; i < 100; ++i) {
      if (test_support::waitForLog(log, {"Separator", needle}, 0.05, found)) return true;
      publish(false, true, 0.0);
    }
    return false;
  }

  // Scores a burst's light-on frames (8 settled); returns the worst PSNR, counting raw frames.
  double burst(int* raw_count) {
    lightOn();
    double worst = 1e9;
    for (int i = 0; i < 8; ++i) {
      const Out out = publish(true, true, 1.0);
      worst = std::min(worst, out.psnr);
      *raw_count += out.raw;
    }
    lightOff();
    return worst;
  }

  const cv::Size size{256, 192};
  Collector<Image> scene;
  Collector<rosgraph_msgs::Log> log;
  // What the next frames are made of (the test moves the device and the epoch).
  cv::Mat device;  // the device pattern
  int frame = 0;   // the next frame's index
  uint32_t epoch = 0;

 private:
  ros::Publisher left_pub_, right_pub_, mode_pub_;
  cv::Mat canvas_;  // the scene's texture; frame f shows the window sceneAt(f)
};

}  // namespace

// device_template learn on crafted frames: a static device pattern (a checkerboard) over a scene
// that slides 2 px right and 1 px down per frame (a moving head), light bursts as the driver
// sends them (settled light-off frames, two unsettled, settled light-on ones, two unsettled, light
// off again), 30 fps stamps. Nothing but the frames goes in:
//  - the first burst (12 settled light-on frames): its first 8 are learned while it goes on, and
//    its later frames are separated;
//  - after it, its ends are learned and the next burst's light-on frames (8 settled, as each
//    later burst) are separated;
//  - a new calibration epoch with the device image moved (a zoom or a knock): the light-on frames
//    are still separated (the template in use, never the raw frame) until the next burst's ends
//    are learned, after which they are separated with the moved device again.
TEST(SeparatorLearn, LearnsTheDeviceImageFromTheFirstBurstOnWithAMovingScene) {
  ros::NodeHandle nh("/learn");
  LearnRig rig(nh);
  // learn is the default device_template: no parameter set
  ASSERT_TRUE(loader->load("/learn/separator", "embedded_calibration_stereo/Separator", ros::M_string(), {}));
  ASSERT_TRUE(waitUntil([&] { return rig.subscribed(); }, 10.0));
  std_srvs::Trigger teach;
  ASSERT_TRUE(ros::service::call("/learn/separator/teach", teach));
  EXPECT_FALSE(teach.response.success) << "learn mode has no teach: " << teach.response.message;
  {
    cv::Scalar mean, sd;
    cv::meanStdDev(rig.sceneAt(0), mean, sd);
    std::printf("learn: scene texture sd %.1f grey levels, moving 2 px right and 1 px up per frame; raw light-on "
                "frames %.1f dB\n", sd[0], psnr(rig.device, cv::Mat::zeros(rig.size, CV_8UC1)));
  }

  // The first burst: learned from its first 8 light-on frames while it goes on.
  rig.lightOn();
  for (int i = 0; i < 8; ++i) EXPECT_TRUE(rig.publish(true, true, 1.0).raw) << "no template yet: the raw frame";
  std::string found;
  bool early = false;
  double worst_early = 1e9;
  int separated_in_first = 0;
  for (int i = 8; i < 12; ++i) {
    early = early || test_support::waitForLog(rig.log, {"Separator", "from the first 8 light-on frames"}, 2.0, &found);
    const LearnRig::Out out = rig.publish(true, true, 1.0);
    if (!out.raw) {
      ++separated_in_first;
      worst_early = std::min(worst_early, out.psnr);
    }
  }
  EXPECT_TRUE(early) << "no device image learned from the first frames of the first burst";
  std::printf("learn, within the first burst: '%s'; %d of its last 4 light-on frames separated, worst %.1f dB\n",
              found.c_str(), separated_in_first, worst_early);
  EXPECT_GE(separated_in_first, 3);
  EXPECT_GE(worst_early, 20.0) << "one-sided pairs on a faint texture: well above the raw frames, short of later bursts";
  rig.lightOff();
  EXPECT_TRUE(rig.waitLearned("from the 12 light-on frames", &found)) << "the first burst's ends not learned";

  int raw = 0;
  const double after_first = rig.burst(&raw);
  std::printf("learn, after the first burst: '%s'; next burst separated, worst %.1f dB\n", found.c_str(), after_first);
  EXPECT_GE(after_first, 35.0);
  EXPECT_EQ(raw, 0);

  // A new calibration epoch with the device image moved: separated with the template in use
  // (worse: the device moved), never raw; that burst's ends are learned; then separated again.
  ++rig.epoch;
  cv::Mat moved;
  cv::warpAffine(rig.device, moved, cv::Matx23f(1.03f, 0, -2, 0, 1.03f, -1), rig.size, cv::INTER_NEAREST);
  rig.device = moved;
  const double moved_old = rig.burst(&raw);
  EXPECT_EQ(raw, 0) << "a new epoch: the template in use, never raw frames";
  char stamp_needle[80];  // the burst's last light-on frame: the three light-off frames came after it
  std::snprintf(stamp_needle, sizeof(stamp_needle), "light-on frames of the burst ending at %.3f s",
                LearnRig::stampOf(rig.frame - 4).toSec());
  EXPECT_TRUE(rig.waitLearned(stamp_needle, &found)) << "the moved device's burst not learned (" << stamp_needle << ")";
  const double moved_new = rig.burst(&raw);
  std::printf("learn, device moved: the previous template %.1f dB; after its burst '%s': %.1f dB\n", moved_old,
              found.c_str(), moved_new);
  EXPECT_GE(moved_new, 35.0);
  EXPECT_GT(moved_new, moved_old + 3.0);
  loader->unload("/learn/separator");
}

// Crafted frames on a Separator without driver: mismatched sizes and encodings, and an
// unsupported encoding, are refused with an error naming the topic and produce no output; a
// valid frame afterwards still goes through (no crash, no stuck state).
TEST(SeparatorBadInput, MismatchedFramesAreReportedAndDropped) {
  ros::NodeHandle nh("/bad");
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 1000);
  Collector<Image> scene(nh, "left/image_scene", 50);
  ros::Publisher left_pub = nh.advertise<Image>("left/image_raw", 5);
  ros::Publisher right_pub = nh.advertise<Image>("right/image_raw", 5);
  ros::Publisher mode_pub = nh.advertise<CalibrationMode>("calibration_mode", 5);
  ASSERT_TRUE(loader->load("/bad/separator", "embedded_calibration_stereo/Separator", ros::M_string(), {}));
  ASSERT_TRUE(waitUntil(
      [&] { return left_pub.getNumSubscribers() && right_pub.getNumSubscribers() && mode_pub.getNumSubscribers(); },
      10.0));

  uint32_t sec = 100;
  const auto publish = [&](const std::string& left_encoding, int left_width, const std::string& right_encoding,
                           int right_width) {
    const ros::Time stamp(++sec, 0);
    for (int side = 0; side < 2; ++side) {
      auto image = boost::make_shared<Image>();
      image->header.stamp = stamp;
      image->header.frame_id = "cam";
      image->encoding = side == 0 ? left_encoding : right_encoding;
      image->width = side == 0 ? left_width : right_width;
      image->height = 60;
      image->step = image->width * (image->encoding == "bgr8" ? 3 : image->encoding == "32FC1" ? 4 : 1);
      image->data.assign(size_t(image->step) * image->height, 50);
      (side == 0 ? left_pub : right_pub).publish(image);
    }
    auto mode = boost::make_shared<CalibrationMode>();
    mode->header.stamp = stamp;
    mode->light_on = false;
    mode->settled = true;
    mode_pub.publish(mode);
    return stamp;
  };
  std::vector<ros::Time> bad;
  std::string found;
  bad.push_back(publish("mono8", 80, "mono8", 40));
  EXPECT_TRUE(test_support::waitForLog(log, {"Separator", "/bad/", "image_raw", "size"}, 10.0, &found))
      << "no error naming the topic for a size mismatch";
  std::printf("size mismatch: %s\n", found.c_str());
  bad.push_back(publish("mono8", 80, "bgr8", 80));
  EXPECT_TRUE(test_support::waitForLog(log, {"Separator", "/bad/", "image_raw", "bgr8"}, 10.0, &found))
      << "no error naming the topic for an encoding mismatch";
  std::printf("encoding mismatch: %s\n", found.c_str());
  bad.push_back(publish("32FC1", 80, "32FC1", 80));
  EXPECT_TRUE(test_support::waitForLog(log, {"Separator", "/bad/", "image_raw", "32FC1"}, 10.0, &found))
      << "no error naming the topic for an unsupported encoding";
  std::printf("unsupported encoding: %s\n", found.c_str());

  const ros::Time good = publish("mono8", 80, "mono8", 80);
  ASSERT_TRUE(scene.waitFor([&](const std::vector<Image::ConstPtr>& m) { return test_support::findByStamp(m, good) != nullptr; },
                            10.0))
      << "a valid frame after the bad ones did not go through";
  for (const auto& stamp : bad) EXPECT_FALSE(test_support::findByStamp(scene.snapshot(), stamp)) << "bad frame published";
  loader->unload("/bad/separator");
}

// An unknown method or a teach_frames below 1 refuses to load (FATAL naming the parameter).
TEST(SeparatorBadInput, BadParametersRefuseToLoad) {
  ros::param::set("/badparam/separator/method", std::string("global"));
  EXPECT_FALSE(loader->load("/badparam/separator", "embedded_calibration_stereo/Separator", ros::M_string(), {}));
  ros::param::del("/badparam/separator/method");
  ros::param::set("/badparam/separator/teach_frames", 0);
  EXPECT_FALSE(loader->load("/badparam/separator", "embedded_calibration_stereo/Separator", ros::M_string(), {}));
  ros::param::del("/badparam/separator/teach_frames");
  ros::param::set("/badparam/separator/device_template", std::string("learn"));
  ros::param::set("/badparam/separator/teach_from_ground_truth", true);  // contradicts learn
  EXPECT_FALSE(loader->load("/badparam/separator", "embedded_calibration_stereo/Separator", ros::M_string(), {}));
  ros::param::del("/badparam/separator/teach_from_ground_truth");
  ros::param::set("/badparam/separator/device_template", std::string("covered"));
  EXPECT_FALSE(loader->load("/badparam/separator", "embedded_calibration_stereo/Separator", ros::M_string(), {}));
  ros::param::del("/badparam/separator/device_template");
  EXPECT_TRUE(loader->load("/badparam/separator", "embedded_calibration_stereo/Separator", ros::M_string(), {}))
      << "control: the defaults load";
  loader->unload("/badparam/separator");
}

// A subscription that only holds its topic (see main).
template <class M>
ros::Subscriber hold(ros::NodeHandle& nh, const std::string& topic) {
  return nh.subscribe<M>(topic, 1, boost::function<void(const typename M::ConstPtr&)>([](const typename M::ConstPtr&) {}));
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "separator_sim_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  loader = std::make_unique<nodelet::Loader>(false);
  // Each test subscribes anew to topics of /sim that an earlier test (or the Separator's lazy
  // inputs) just unsubscribed from. roscpp can attach a subscription made right after the last
  // one to the same topic was shut down to the subscription being dropped, which then never
  // delivers (seen as a collector that receives nothing for 20-40 s). One subscription per topic
  // held for the whole run keeps those subscriptions from being dropped.
  ros::NodeHandle sim("/sim");
  std::vector<ros::Subscriber> held;
  for (const char* topic : {"left/image_raw", "right/image_raw", "left/image_scene", "right/image_scene",
                            "ground_truth/left/image_scene", "ground_truth/right/image_scene"})
    held.push_back(hold<Image>(sim, topic));
  held.push_back(hold<CalibrationMode>(sim, "calibration_mode"));
  held.push_back(hold<sensor_msgs::CameraInfo>(sim, "left/camera_info"));
  held.push_back(hold<rosgraph_msgs::Log>(sim, "/rosout"));
  const int result = RUN_ALL_TESTS();
  held.clear();
  loader.reset();  // unload the nodelets while ROS is still up
  return result;
}
