// rostest (light_controller_inputs.test): the LightController (sim light) in the head's graph of
// launch/external_driver.launch, fed by this test node playing an external driver: it renders
// the simulated head (zoomed 3 %, so that the calibration in force no longer fits), applies the
// light level the LightController publishes TWO frames late, switches it in the middle of an
// exposure (that frame is half lit), and stamps the right camera 5 ms after the left.
//  A. recalibrate: every settled frame carries the light its images were rendered with, never
//     a half-lit one; the calibrator solves but set_camera_info is absent (the driver serves
//     none): it says so and does not commit;
//  B. no device in view while the light is on: the LightController reports the light as not
//     working (diagnostics ERROR and a throttled error); a recalibration answers false, "no
//     boards seen"; with the light off again the report clears;
//  C. uncalibrated camera_info: a warning naming the topic, frames keep flowing;
//  D. no right camera_info: frames are held back with an error naming the topic, and flow again
//     once it is back;
//  E. on demand: a burst while calibration/health wants one, none while it does not;
//  F. unreadable images: a malformed left image (its data shorter than its size says), then an
//     empty left image and a right image of an encoding the light cannot be confirmed on, at
//     once: each is dropped with an error naming its topic (both cameras', not the first one's
//     alone), and frames flow again once the images are good;
//  G. images of another size than the board regions were taught on: a warning naming each
//     camera's topic and both sizes; frames keep flowing.
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/Float64.h>
#include <std_srvs/SetBool.h>

#include <algorithm>
#include <atomic>
#include <deque>
#include <map>
#include <mutex>
#include <thread>

#include "child_launch.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/ros/conversions.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationHealth;
using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::Recalibrate;
using test_support::Collector;

namespace {

constexpr double kFps = 15.0;
constexpr int kDelayFrames = 2;

// The stand-in external driver.
class FakeDriver {
 public:
  enum class Info { kCalibrated, kUncalibrated, kRightMissing };
  enum class Images { kGood, kLeftMalformed, kLeftEmptyRightWrongEncoding, kHalfSize };

  explicit FakeDriver(ros::NodeHandle& nh) {
    core::SimRigConfig config = core::loadSimRigConfig(std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml");
    std::tie(left_info_, right_info_) = embedded_calibration_stereo::toStereoCameraInfo(config.rig);
    noise_sigma_ = config.noise_sigma;
    config.noise_sigma = 0.0;
    core::SimRig sim(config);
    core::DriftRequest zoom;
    zoom.focal_scale = 1.03;
    sim.setDrift(zoom, 0.0);
    const core::SimFrame off = sim.render(0.0, 0.0, 1), on = sim.render(0.0, 1.0, 1);
    off.left.convertTo(off_[0], CV_32F);
    off.right.convertTo(off_[1], CV_32F);
    on.left.convertTo(on_[0], CV_32F);
    on.right.convertTo(on_[1], CV_32F);
    left_pub_ = nh.advertise<sensor_msgs::Image>("left_driver/image_raw", 2);
    right_pub_ = nh.advertise<sensor_msgs::Image>("right_driver/image_raw", 2);
    left_info_pub_ = nh.advertise<sensor_msgs::CameraInfo>("left_driver/camera_info", 2);
    right_info_pub_ = nh.advertise<sensor_msgs::CameraInfo>("right_driver/camera_info", 2);
    level_sub_ = nh.subscribe<std_msgs::Float64>("sim/light_level", 5, [this](const std_msgs::Float64::ConstPtr& m) {
      commanded_ = m->data;
    });
    thread_ = std::thread([this] { run(); });
  }
  ~FakeDriver() {
    running_ = false;
    thread_.join();
    level_sub_.shutdown();
  }

  std::atomic<bool> device_visible{true};
  std::atomic<Info> info{Info::kCalibrated};
  std::atomic<Images> images{Images::kGood};

  // Fraction of the exposure with the light on, for the frame of this (left) stamp; -1 unknown.
  double truthAt(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = truth_.find(stamp);
    return it == truth_.end() ? -1.0 : it->second;
  }

 private:
  void run() {
    ros::WallRate rate(kFps);
    std::deque<double> delay(kDelayFrames, 0.0);
    double level = 0.0;
    uint64_t k = 0;
    while (running_ && ros::ok()) {
      delay.push_back(commanded_.load());
      const double target = device_visible ? delay.front() : 0.0;
      delay.pop_front();
      // The light changes in the middle of this exposure: half of it lit at the old level.
      const double exposed = target != level ? 0.5 * (level + target) : target;
      level = target;
      const ros::Time stamp = ros::Time::now();
      {
        std::lock_guard<std::mutex> lock(mutex_);
        truth_[stamp] = exposed;
      }
      publish(0, stamp, exposed, k);
      publish(1, stamp + ros::Duration(0.005), exposed, k);
      ++k;
      rate.sleep();
    }
  }

  void publish(int c, const ros::Time& stamp, double p, uint64_t k) {
    cv::Mat noise(off_[c].size(), CV_32F), image;
    cv::RNG rng(2 * k + c + 1);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, noise_sigma_);
    cv::Mat((1.0 - p) * off_[c] + p * on_[c] + noise).convertTo(image, CV_8U);
    std_msgs::Header header;
    header.stamp = stamp;
    header.frame_id = "stereo_left_optical_frame";
    (c == 0 ? left_pub_ : right_pub_).publish(imageMessage(c, header, image));
    const Info mode = info.load();
    if (mode == Info::kRightMissing && c == 1) return;
    sensor_msgs::CameraInfo camera = c == 0 ? left_info_ : right_info_;
    if (mode == Info::kUncalibrated) {
      sensor_msgs::CameraInfo blank;
      blank.width = camera.width;
      blank.height = camera.height;
      camera = blank;
    }
    camera.header = header;
    (c == 0 ? left_info_pub_ : right_info_pub_).publish(camera);
  }

  // Camera c's image as the fault of the moment makes it.
  sensor_msgs::ImagePtr imageMessage(int c, const std_msgs::Header& header, const cv::Mat& image) const {
    const Images fault = images.load();
    if (fault == Images::kHalfSize) {
      cv::Mat half;
      cv::resize(image, half, cv::Size(), 0.5, 0.5, cv::INTER_AREA);
      return cv_bridge::CvImage(header, "mono8", half).toImageMsg();
    }
    sensor_msgs::ImagePtr msg = cv_bridge::CvImage(header, "mono8", image).toImageMsg();
    if (fault == Images::kLeftMalformed && c == 0) msg->data.resize(msg->data.size() / 2);
    if (fault == Images::kLeftEmptyRightWrongEncoding && c == 0) {
      msg->width = msg->height = msg->step = 0;
      msg->data.clear();
    }
    if (fault == Images::kLeftEmptyRightWrongEncoding && c == 1) {
      msg->encoding = "16UC1";  // as if a depth camera's stream were remapped here
      msg->width /= 2;          // readable: step is width x 2 bytes
    }
    return msg;
  }

  cv::Mat off_[2], on_[2];
  double noise_sigma_ = 1.0;
  sensor_msgs::CameraInfo left_info_, right_info_;
  ros::Publisher left_pub_, right_pub_, left_info_pub_, right_info_pub_;
  ros::Subscriber level_sub_;
  std::atomic<double> commanded_{0.0};
  std::atomic<bool> running_{true};
  std::mutex mutex_;
  std::map<ros::Time, double> truth_;
  std::thread thread_;
};

// Waits for a light_controller status of /diagnostics whose level and message match.
bool waitForDiagnostic(Collector<diagnostic_msgs::DiagnosticArray>& diagnostics, size_t from, int level,
                       const std::string& needle, double timeout_s, std::string* seen) {
  return diagnostics.waitFor(
      [&](const std::vector<diagnostic_msgs::DiagnosticArray::ConstPtr>& arrays) {
        for (size_t i = from; i < arrays.size(); ++i)
          for (const auto& status : arrays[i]->status) {
            if (status.name.find("light_controller") == std::string::npos) continue;
            *seen = status.message;
            if (status.level == level && status.message.find(needle) != std::string::npos) return true;
          }
        return false;
      },
      timeout_s);
}

using diagnostic_msgs::DiagnosticStatus;

// What the sections share: the stand-in driver, the head's log, diagnostics and calibration_mode.
struct Rig {
  ros::NodeHandle& nh;
  FakeDriver& driver;
  Collector<rosgraph_msgs::Log>& log;
  Collector<diagnostic_msgs::DiagnosticArray>& diagnostics;
  Collector<CalibrationMode>& modes;
  test_support::ChildLaunch& head;

  // The sections, in order (the file comment says what each checks).
  void recalibrateWithTheLightLate();
  void noDeviceInView();
  void uncalibratedCameraInfo();
  void rightCameraInfoMissing();
  void onDemand();
  void unreadableImages();
  void imagesOfAnotherSize();
};

void Rig::recalibrateWithTheLightLate() {
  // A. A recalibration with the light two frames late; set_camera_info absent.
  Recalibrate recalibrate;
  ASSERT_TRUE(test_support::recalibrate(5, 15.0, "without set_camera_info", &recalibrate, 20.0));
  EXPECT_FALSE(recalibrate.response.success);
  EXPECT_NE(recalibrate.response.message.find("not committed"), std::string::npos) << recalibrate.response.message;
  EXPECT_NE(recalibrate.response.message.find("left_driver/set_camera_info is not available"), std::string::npos)
      << recalibrate.response.message;
  int settled_on = 0, settled_off = 0, half_lit = 0;
  for (const auto& mode : modes.snapshot()) {
    const double p = driver.truthAt(mode->header.stamp);
    ASSERT_GE(p, 0.0) << "a calibration_mode stamp the driver never published";
    if (p > 0 && p < 1) {
      ++half_lit;
      EXPECT_FALSE(mode->settled) << "a half-lit frame was marked settled";
      continue;
    }
    if (!mode->settled) continue;
    EXPECT_EQ(mode->light_on, p == 1.0);
    ++(mode->light_on ? settled_on : settled_off);
  }
  std::printf("light two frames late: %d settled on, %d settled off, %d half-lit frames unsettled\n", settled_on,
              settled_off, half_lit);
  EXPECT_GE(settled_on, 5);
  EXPECT_GE(half_lit, 2) << "the switches must have produced half-lit frames";
}

void Rig::noDeviceInView() {
  // B. No device in view with the light on.
  driver.device_visible = false;
  size_t from = diagnostics.snapshot().size();
  std_srvs::SetBool on;
  on.request.data = true;
  ASSERT_TRUE(test_support::callService("/stereo/set_light", &on, 20.0) && on.response.success);
  std::string seen;
  EXPECT_TRUE(waitForDiagnostic(diagnostics, from, DiagnosticStatus::ERROR, "light not working", 8.0, &seen))
      << "last light_controller status: " << seen;
  EXPECT_TRUE(test_support::waitForLog(log, {"LightController", "the light is not working"}, 5.0));
  Recalibrate no_boards;
  no_boards.request.frames = 5;
  no_boards.request.timeout_s = 1.5;
  ASSERT_TRUE(test_support::callService("/stereo/calibration/recalibrate", &no_boards, 20.0));
  EXPECT_FALSE(no_boards.response.success);
  EXPECT_NE(no_boards.response.message.find("no boards seen"), std::string::npos) << no_boards.response.message;
  // The recalibration switched the light off again: the images agree, the report clears.
  from = diagnostics.snapshot().size();
  EXPECT_TRUE(waitForDiagnostic(diagnostics, from, DiagnosticStatus::OK, "confirming the light", 8.0, &seen))
      << "last light_controller status: " << seen;
  driver.device_visible = true;
}

void Rig::uncalibratedCameraInfo() {
  std::string seen;
  // C. Uncalibrated camera_info: a warning, frames keep flowing.
  driver.info = FakeDriver::Info::kUncalibrated;
  size_t from = diagnostics.snapshot().size();
  EXPECT_TRUE(waitForDiagnostic(diagnostics, from, DiagnosticStatus::WARN, "uncalibrated", 8.0, &seen))
      << "last light_controller status: " << seen;
  // One warning per topic: the other camera's must not hide it.
  EXPECT_TRUE(test_support::waitForLog(log, {"/stereo/left_driver/camera_info is uncalibrated"}, 5.0));
  EXPECT_TRUE(test_support::waitForLog(log, {"/stereo/right_driver/camera_info is uncalibrated"}, 5.0));
  size_t count = modes.snapshot().size();
  EXPECT_TRUE(modes.waitForCount(count + 10, 5.0)) << "frames stopped with an uncalibrated camera_info";
}

void Rig::rightCameraInfoMissing() {
  std::string seen;
  // D. No right camera_info: frames held back, with the topic named; back when it is back.
  driver.info = FakeDriver::Info::kRightMissing;
  size_t from = diagnostics.snapshot().size();
  EXPECT_TRUE(waitForDiagnostic(diagnostics, from, DiagnosticStatus::ERROR,
                                "no camera_info on /stereo/right_driver/camera_info", 8.0, &seen))
      << "last light_controller status: " << seen;
  EXPECT_TRUE(test_support::waitForLog(log, {"frames held back", "/stereo/right_driver/camera_info"}, 5.0));
  size_t count = modes.snapshot().size();
  ros::WallDuration(1.0).sleep();  // a quiet second (the control below shows the pipe works)
  EXPECT_LE(modes.snapshot().size(), count + 1) << "frames went out without the right camera_info";
  driver.info = FakeDriver::Info::kCalibrated;
  EXPECT_TRUE(modes.waitForCount(count + 10, 5.0)) << "frames did not resume with the camera_info back";
}

void Rig::onDemand() {
  // E. On demand: a calibration burst (settled light-on frames confirmed from the images; a
  //    verification flash would give one, and there are none here) while calibration/health
  //    wants one; none while it does not, frames flowing all the while.
  std::mutex health_mutex;
  CalibrationHealth health;
  health.state = CalibrationHealth::DEGRADED;
  health.calibration_wanted = true;
  ros::Publisher health_pub = nh.advertise<CalibrationHealth>("calibration/health", 1);
  ros::WallTimer health_timer = nh.createWallTimer(ros::WallDuration(0.1), [&](const ros::WallTimerEvent&) {
    std::lock_guard<std::mutex> lock(health_mutex);
    health_pub.publish(health);
  });
  const auto longest_lit_run = [](const std::vector<CalibrationMode::ConstPtr>& m, size_t from) {
    int run = 0, longest = 0;
    for (size_t i = from; i < m.size(); ++i) {
      run = m[i]->light_on && m[i]->settled ? run + 1 : 0;
      longest = std::max(longest, run);
    }
    return longest;
  };
  size_t before = modes.snapshot().size();
  EXPECT_TRUE(modes.waitFor([&](const auto& m) { return longest_lit_run(m, before) >= 5; }, 10.0))
      << "no calibration burst while calibration/health wants one (" << health_pub.getNumSubscribers()
      << " subscribers of " << health_pub.getTopic() << ", longest settled lit run "
      << longest_lit_run(modes.snapshot(), before) << ")\n" << head.logTail();
  {
    std::lock_guard<std::mutex> lock(health_mutex);
    health.state = CalibrationHealth::GOOD;
    health.calibration_wanted = false;
  }
  // After the burst in progress, 60 frames without light.
  ASSERT_TRUE(modes.waitFor(
      [](const auto& m) { return !m.empty() && !m.back()->light_on && m.back()->settled; }, 5.0));
  before = modes.snapshot().size();
  ASSERT_TRUE(modes.waitForCount(before + 60, 10.0)) << "frames stopped";
  const auto quiet = modes.snapshot();
  int lit = 0;
  for (size_t i = before; i < quiet.size(); ++i) lit += quiet[i]->light_on ? 1 : 0;
  EXPECT_EQ(lit, 0) << "the light went on while calibration/health wanted no calibration";
  health_timer.stop();
}

void Rig::unreadableImages() {
  // F. Unreadable images: dropped, each with an error naming its topic; frames resume after.
  //    A malformed left image is dropped before pairing; an empty left image and a right image
  //    of another encoding, in the same frame, are both named.
  driver.images = FakeDriver::Images::kLeftMalformed;
  EXPECT_TRUE(test_support::waitForLog(
      log, {"cannot read the image on /stereo/left_driver/image_raw", "fewer than height x step", "frame dropped"}, 5.0))
      << "a malformed image was dropped without a word";
  size_t count = modes.snapshot().size();
  ros::WallDuration(1.0).sleep();  // a quiet second (the control below shows the pipe works)
  EXPECT_LE(modes.snapshot().size(), count + 1) << "frames went out with a malformed image";
  driver.images = FakeDriver::Images::kLeftEmptyRightWrongEncoding;
  EXPECT_TRUE(test_support::waitForLog(log, {"/stereo/left_driver/image_raw delivered an empty image"}, 5.0));
  EXPECT_TRUE(test_support::waitForLog(log, {"/stereo/right_driver/image_raw has encoding '16UC1'", "frame dropped"},
                                       5.0))
      << "the left camera's error hid the right camera's";
  driver.images = FakeDriver::Images::kGood;
  count = modes.snapshot().size();
  EXPECT_TRUE(modes.waitForCount(count + 10, 5.0)) << "frames did not resume with good images";
}

void Rig::imagesOfAnotherSize() {
  // G. Images of another size than the board regions were taught on: a warning per camera.
  ASSERT_TRUE(test_support::waitForLog(log, {"LightController: taught board regions read from"}, 1.0))
      << "the board regions were never taught in this test: nothing to check their size against";
  driver.images = FakeDriver::Images::kHalfSize;
  EXPECT_TRUE(test_support::waitForLog(log, {"/stereo/left_driver/image_raw is 376x240", "taught on 752x480"}, 5.0));
  EXPECT_TRUE(test_support::waitForLog(log, {"/stereo/right_driver/image_raw is 376x240", "taught on 752x480"}, 5.0));
  size_t count = modes.snapshot().size();
  EXPECT_TRUE(modes.waitForCount(count + 10, 5.0)) << "frames stopped with images of another size";
  driver.images = FakeDriver::Images::kGood;
}

}  // namespace

TEST(LightControllerInputs, DelayedLightAndBadInputs) {
  ros::NodeHandle nh;
  test_support::TempDir dir("ecs_light_inputs");
  ASSERT_FALSE(dir.path.empty());
  Collector<rosgraph_msgs::Log> log(nh, "/rosout", 5000);
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics(nh, "/diagnostics", 2000);
  Collector<CalibrationMode> modes(nh, "calibration_mode", 5000);
  // On demand with no calibration/health publisher but the test's (section E): the light
  // follows set_light only until then, as with the periodic trigger and no period.
  test_support::ChildLaunch head({"embedded_calibration_stereo", "external_driver.launch", "light_backend:=sim",
                              "calibration_period_s:=0", "calibration_trigger:=on_demand", "health:=false",
                              // bursts of a fixed 10 frames, as the sections' counts assume
                              "calibration_frames:=10",
                              "prior_file:=" + dir.path + "/prior.yaml"},
                             dir.path + "/head.log");
  ASSERT_TRUE(head.started());
  ASSERT_TRUE(ros::service::waitForService("/stereo/set_light", ros::Duration(30.0))) << head.logTail();
  FakeDriver driver(nh);
  ASSERT_TRUE(modes.waitForCount(10, 20.0)) << "no calibration_mode from the LightController\n" << head.logTail();

  Rig rig{nh, driver, log, diagnostics, modes, head};
  rig.recalibrateWithTheLightLate();
  if (::testing::Test::HasFatalFailure()) return;
  rig.noDeviceInView();
  if (::testing::Test::HasFatalFailure()) return;
  rig.uncalibratedCameraInfo();
  if (::testing::Test::HasFatalFailure()) return;
  rig.rightCameraInfoMissing();
  if (::testing::Test::HasFatalFailure()) return;
  rig.onDemand();
  if (::testing::Test::HasFatalFailure()) return;
  rig.unreadableImages();
  if (::testing::Test::HasFatalFailure()) return;
  rig.imagesOfAnotherSize();
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "light_controller_inputs_test");
  ros::AsyncSpinner spinner(4);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  spinner.stop();
  ros::shutdown();
  return result;
}
