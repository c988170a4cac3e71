// The LightController nodelet (docs/nodelets.md#lightcontroller).
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/SetCameraInfo.h>
#include <std_msgs/Float64.h>
#include <std_srvs/SetBool.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <memory>
#include <optional>

#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/core/light/light_confirmation.h"
#include "embedded_calibration_stereo/core/light/light_regions.h"
#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/driver_calibration_watch.h"
#include "embedded_calibration_stereo/ros/external_stereo_input.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/light_backend.h"
#include "embedded_calibration_stereo/ros/light_controller_params.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/reloading_calibration_store.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"
#include "embedded_calibration_stereo/ros/tracker_teaching.h"

namespace embedded_calibration_stereo {

namespace {

using sensor_msgs::CameraInfo;
using sensor_msgs::CameraInfoConstPtr;
using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

// One stereo frame of the driver, waiting for the next one to be decided.
struct PendingFrame {
  ImageConstPtr left, right;
  CameraInfoConstPtr left_info, right_info;
  uint32_t epoch = 0;
};

}  // namespace

// Runs the head's light when the cameras are driven by another ROS driver, and turns that
// driver's frames into the head's stereo stream: each stereo frame, paired by stamp, goes out
// with the left image's stamp and one calibration_mode whose light state is confirmed from the
// images (core::DeviceLightConfirmer), one frame late. The schedule is core::LightSchedule; with
// calibration_store file it serves set_camera_info (ReloadingCalibrationStore). The whole
// story, parameters and limits: docs/nodelets.md#lightcontroller and docs/external_driver.md.
// Threads: everything runs on the nodelet's single-threaded callback queue (frame callbacks,
// set_light, set_camera_info, calibration/health, the diagnostics timer), so the state below
// needs no lock. The light backend is driven from the frame callback only.
class LightControllerNodelet : public GuardedNodelet {
 public:
  LightControllerNodelet() : GuardedNodelet("LightController") {}
  ~LightControllerNodelet() override = default;

 private:
  void releaseAfterFailedStart() override {
    for (ros::ServiceServer* server : {&set_light_srv_, &left_set_info_srv_, &right_set_info_srv_})
      server->shutdown();
    health_sub_.shutdown();
  }

  // In stages, in the order they have always run: the light before set_light can command it,
  // the regions before the driver's inputs. No callback runs before this returns (the nodelet's
  // single-threaded queue); when a stage throws, onInit shuts down what was advertised.
  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    params_ = loadLightControllerParams(ParameterReader(pnh), defaultPatternPriorFile());
    makeLight(nh);
    schedule_ = std::make_unique<core::LightSchedule>(params_.schedule);
    confirmer_ = std::make_unique<core::DeviceLightConfirmer>(params_.confirmation);
    watch_ = std::make_unique<core::LightCommandWatch>(params_.max_delay_frames);
    if (params_.calibration_store == "file") advertiseSetCameraInfo(nh);
    regions_file_ = std::make_unique<core::BoardRegionsFile>(params_.prior_file, params_.region_margin_squares);
    loadRegions();
    advertiseOutputs(nh);
    input_ = std::make_unique<ExternalStereoInput>(
        nh, pnh, *it_, ExternalStereoInput::Options{params_.approximate_sync, params_.max_interval_s, params_.queue_size},
        [this](const auto& l, const auto& li, const auto& r, const auto& ri) { frameCb(l, li, r, ri); },
        [this](const std::string& text) { NODELET_WARN("%s", text.c_str()); },
        [this](const std::string& problem) {
          ++dropped_;
          reportDropped(problem);
        });
    startDiagnostics(nh, pnh);
    NODELET_INFO("LightController: light %s, %s sync of %s and %s, light confirmed in %s, calibrations stored by %s",
                 params_.light.backend.c_str(), params_.approximate_sync ? "approximate" : "exact",
                 input_->topic(0).c_str(), input_->topic(2).c_str(), regionsText().c_str(),
                 params_.calibration_store == "file" ? "this nodelet (files, driver reloads)" : "the driver");
  }

  // The light backend the parameters name.
  void makeLight(ros::NodeHandle& nh) {
    if (params_.light.backend == "sim") {
      sim_level_ = std::make_shared<std::atomic<double>>(0.0);
      // A simulated camera driver reads the level from here (it has no light of its own).
      sim_level_pub_ = nh.advertise<std_msgs::Float64>("sim/light_level", 1, true);
    }
    light_ = makeLightBackend(params_.light, sim_level_);
  }

  // calibration_store "file": this nodelet serves both cameras' set_camera_info.
  void advertiseSetCameraInfo(ros::NodeHandle& nh) {
    using Store = ReloadingCalibrationStore;
    store_ = std::make_unique<Store>(
        Store::Side{{params_.left_camera_name, params_.left_camera_info_url, "left_camera_info_url"},
                    params_.left_reload_service},
        Store::Side{{params_.right_camera_name, params_.right_camera_info_url, "right_camera_info_url"},
                    params_.right_reload_service},
        kPairTimeoutS, [this](Store::Severity severity, const std::string& text) {
          if (severity == Store::Severity::kInfo) NODELET_INFO("%s", text.c_str());
          if (severity == Store::Severity::kWarn) NODELET_WARN("%s", text.c_str());
          if (severity == Store::Severity::kError) NODELET_ERROR("%s", text.c_str());
        });
    left_set_info_srv_ = nh.advertiseService<sensor_msgs::SetCameraInfo::Request, sensor_msgs::SetCameraInfo::Response>(
        "left/set_camera_info", [this](auto& req, auto& res) { return setCameraInfo(true, req, res); });
    right_set_info_srv_ = nh.advertiseService<sensor_msgs::SetCameraInfo::Request, sensor_msgs::SetCameraInfo::Response>(
        "right/set_camera_info", [this](auto& req, auto& res) { return setCameraInfo(false, req, res); });
  }

  // The head's stereo stream, set_light and, on demand, the health that asks for calibrations.
  void advertiseOutputs(ros::NodeHandle& nh) {
    it_ = std::make_unique<image_transport::ImageTransport>(nh);
    left_pub_ = it_->advertiseCamera("left/image_raw", 2);
    right_pub_ = it_->advertiseCamera("right/image_raw", 2);
    mode_pub_ = nh.advertise<CalibrationMode>("calibration_mode", 2);
    set_light_srv_ = nh.advertiseService("set_light", &LightControllerNodelet::setLight, this);
    if (params_.schedule.trigger == core::CalibrationTrigger::kOnDemand)
      health_sub_ = nh.subscribe<CalibrationHealth>("calibration/health", 2, [this](const auto& health) {
        // On demand: a calibration burst while the health nodelet wants one (the calibration is
        // known not to hold and the calibrator has not found it to be the best it can do).
        schedule_->demand(health->calibration_wanted);
      });
  }

  // The diagnostics, the once-a-second tick (regions re-read, missing inputs named, diagnostics
  // updated) and the origin of the schedule's clock.
  void startDiagnostics(ros::NodeHandle& nh, ros::NodeHandle& pnh) {
    diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
    diagnostics_->setHardwareID(params_.light.backend == "serial" ? params_.light.serial.port : params_.light.backend);
    diagnostics_->add("light_controller", this, &LightControllerNodelet::diagnose);
    timer_ = nh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) { tick(); });
    started_ = std::chrono::steady_clock::now();
  }

  std::string regionsText() const {
    if (confirmer_->regionsInUse()) return "the taught board regions of " + params_.prior_file;
    if (confirmer_->hasRegions()) return "the whole image (the taught regions take over at the next switch)";
    return "the whole image";
  }

  // (Re)reads the tracker's prior when the file appeared or changed; the new regions get a
  // confirmation of their own, which knows the light's state from its first switch on.
  void loadRegions() {
    if (!regions_file_->refresh()) return;
    confirmer_->setRegions(regions_file_->mask(0), regions_file_->mask(1));
    if (regions_file_->taught())
      NODELET_INFO("LightController: taught board regions read from %s; they confirm the light from the next switch on",
                   params_.prior_file.c_str());
    if (!regions_file_->problem().empty())
      NODELET_WARN("LightController: prior file '%s' unusable (%s); confirming the light over the whole image",
                   params_.prior_file.c_str(), regions_file_->problem().c_str());
  }

  // A mask of another size than the image (prior of another camera mode) is not used.
  void warnIfRegionsDoNotFit(int camera, const cv::Mat& image, const std::string& topic) {
    if (confirmer_->fits(camera, image.size())) return;
    const cv::Mat& mask = regions_file_->mask(camera);
    if (!input_warnings_.shouldReport(topic + " size")) return;  // per topic: both cameras are named
    NODELET_WARN("LightController: %s is %dx%d but the prior file '%s' was taught on %dx%d images; confirming the "
                 "light over the whole image",
                 topic.c_str(), image.cols, image.rows, params_.prior_file.c_str(), mask.cols, mask.rows);
  }

  // Throttled per message, as the other nodelets' (ErrorThrottle): one camera's bad image must not
  // hide the other's.
  void reportDropped(const std::string& message) {
    if (errors_.shouldReport(message)) NODELET_ERROR("LightController: %s; frame dropped", message.c_str());
  }

  bool readImage(const ImageConstPtr& msg, const std::string& topic, cv_bridge::CvImageConstPtr* out) {
    if (msg->encoding != "mono8" && msg->encoding != "bgr8" && msg->encoding != "rgb8") {
      reportDropped(topic + " has encoding '" + msg->encoding + "' (expected mono8, bgr8 or rgb8)");
      return false;
    }
    try {
      *out = cv_bridge::toCvShare(msg);
    } catch (const cv_bridge::Exception& e) {
      reportDropped("cannot read " + topic + ": " + e.what());
      return false;
    }
    if ((*out)->image.empty()) {
      reportDropped(topic + " delivered an empty image");
      return false;
    }
    return true;
  }

  void frameCb(const ImageConstPtr& left, const CameraInfoConstPtr& left_info, const ImageConstPtr& right,
               const CameraInfoConstPtr& right_info) {
    cv_bridge::CvImageConstPtr left_cv, right_cv;
    // Both read, so that a bad left image does not hide a bad right one.
    const bool left_read = readImage(left, input_->topic(0), &left_cv);
    const bool right_read = readImage(right, input_->topic(2), &right_cv);
    if (!left_read || !right_read) {
      ++dropped_;
      return;
    }
    const double spread = std::abs((right->header.stamp - left->header.stamp).toSec());
    max_spread_s_ = std::max(max_spread_s_, spread);
    checkCalibration(*left_info, input_->topic(1), 0);
    checkCalibration(*right_info, input_->topic(3), 1);
    schedule_->calibrationInForce(calibration_.epoch());  // a new one is checked against the boards at once

    // The light for the next frames (the driver's delay decides which frame shows it).
    const double time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
    const core::LightState commanded = schedule_->step(time_s);
    std::string error;
    if (!light_->apply(commanded, &error)) {
      light_error_ = error;
      NODELET_ERROR_THROTTLE(5.0, "LightController: light: %s", error.c_str());
    } else {
      light_error_.clear();
    }
    commanded_on_ = commanded.light_on;
    if (sim_level_ && sim_level_->load() != published_level_) {
      published_level_ = sim_level_->load();
      std_msgs::Float64 level_msg;
      level_msg.data = published_level_;
      sim_level_pub_.publish(level_msg);
    }

    warnIfRegionsDoNotFit(0, left_cv->image, input_->topic(0));
    warnIfRegionsDoNotFit(1, right_cv->image, input_->topic(2));
    const std::optional<core::ConfirmedLight> decided = confirmer_->push(left_cv->image, right_cv->image);
    if (params_.light.backend != "none") {
      watch_->update(commanded.light_on, decided);
      if (!watch_->fault().empty())
        NODELET_ERROR_THROTTLE(5.0, "LightController: the light is not working: %s (light %s)", watch_->fault().c_str(),
                               params_.light.backend.c_str());
    }
    if (pending_ && decided) publish(*pending_, *decided);
    pending_ = PendingFrame{left, right, left_info, right_info, calibration_.epoch()};
  }

  // Counts calibration changes (the epoch) and reports uncalibrated camera_info.
  void checkCalibration(const CameraInfo& info, const std::string& topic, int side) {
    if (calibration_.update(side, info))
      NODELET_INFO("LightController: new calibration on %s, calibration epoch %u", topic.c_str(), calibration_.epoch());
    // Throttled per topic: the other camera's warning must not hide this one's.
    if (calibration_.uncalibrated(side) && input_warnings_.shouldReport(topic + " uncalibrated"))
      NODELET_WARN("LightController: %s is uncalibrated (K or P all zero): the calibrator starts from scratch and "
                   "depth waits for a committed calibration",
                   topic.c_str());
  }

  void publish(const PendingFrame& frame, const core::ConfirmedLight& light) {
    const ros::Time stamp = frame.left->header.stamp;
    // The left image goes out as it came (zero-copy); the right one and the CameraInfos carry the
    // left stamp, so that every consumer matches the frame exactly.
    ImageConstPtr right = frame.right;
    if (right->header.stamp != stamp) {
      auto restamped = boost::make_shared<Image>(*right);
      restamped->header.stamp = stamp;
      right = restamped;
    }
    const auto restamp = [&](const CameraInfoConstPtr& info) {
      auto out = boost::make_shared<CameraInfo>(*info);
      out->header.stamp = stamp;
      return out;
    };
    auto mode = boost::make_shared<CalibrationMode>();
    mode->header = frame.left->header;
    mode->light_on = light.light_on;
    mode->settled = light.settled;
    mode->calibration_epoch = frame.epoch;
    left_pub_.publish(frame.left, restamp(frame.left_info));
    right_pub_.publish(right, restamp(frame.right_info));
    mode_pub_.publish(mode);
    ++frames_out_;
    last_light_ = light;
    if (light.settled) ++(light.light_on ? settled_on_ : settled_off_);
  }

  bool setLight(std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
    schedule_->request(req.data);
    res.success = true;
    if (params_.light.backend == "none")
      res.message = std::string("no light backend: switch the light ") + (req.data ? "on" : "off") +
                    " by other means; calibration_mode follows what the images show";
    else
      res.message = req.data ? "light on from the next frame" : "light off from the next frame";
    return true;
  }

  // calibration_store "file": validate, write the driver's calibration file, ask it to reload.
  bool setCameraInfo(bool left, sensor_msgs::SetCameraInfo::Request& req, sensor_msgs::SetCameraInfo::Response& res) {
    store_->set(left, req.camera_info, calibration_.latest(), &res);
    return true;
  }

  // Once a second: regions taught meanwhile, missing inputs, diagnostics.
  void tick() {
    loadRegions();
    missing_ = input_->arrivals().tick();
    if (!missing_.empty())
      NODELET_ERROR_THROTTLE(5.0, "LightController: frames held back: %s (each image needs its camera_info, of "
                                  "the same stamp; the driver publishes it from its camera_info_url)",
                             missing_.c_str());
    diagnostics_->update();
    max_spread_s_ = 0.0;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    core::LightControllerState state;
    state.backend_error = light_error_;
    state.fault = params_.light.backend != "none" ? watch_->fault() : "";
    state.held_back = missing_;
    state.uncalibrated = calibration_.uncalibrated(0) || calibration_.uncalibrated(1);
    state.frames_out = frames_out_;
    const core::StatusSummary summary = core::lightControllerSummary(state);
    status.summary(toDiagnosticLevel(summary.level), summary.text);
    status.add("light backend", params_.light.backend);
    status.add("calibration trigger",
               params_.schedule.trigger == core::CalibrationTrigger::kOnDemand ? "on_demand" : "periodic");
    status.add("calibration demanded (health not good)", schedule_->demanded());
    status.add("light commanded on", commanded_on_);
    status.add("light confirmed on", last_light_.light_on);
    status.add("settled", last_light_.settled);
    const core::StereoLightConfirmer& used = confirmer_->inUse();
    status.add("light step left (grey levels)", used.left().step());
    status.add("light step right (grey levels)", used.right().step());
    status.add("confirmed in", regionsText());
    status.add("calibration epoch", calibration_.epoch());
    status.add("frames in", input_->arrivals().framesIn());
    status.add("frames out", frames_out_);
    status.add("settled light-on frames", settled_on_);
    status.add("settled light-off frames", settled_off_);
    status.add("dropped frames", dropped_);
    status.add("max left/right stamp difference (ms)", 1000.0 * max_spread_s_);
    status.add("left camera_info", calibration_.uncalibrated(0) ? "uncalibrated" : "calibrated");
    status.add("right camera_info", calibration_.uncalibrated(1) ? "uncalibrated" : "calibrated");
  }

  LightControllerParams params_;
  std::unique_ptr<LightBackend> light_;
  SharedLightLevel sim_level_;
  double published_level_ = -1.0;
  std::unique_ptr<core::LightSchedule> schedule_;
  std::unique_ptr<core::DeviceLightConfirmer> confirmer_;  // the whole image, or the taught regions
  std::unique_ptr<core::BoardRegionsFile> regions_file_;
  std::unique_ptr<core::LightCommandWatch> watch_;
  std::unique_ptr<ReloadingCalibrationStore> store_;  // calibration_store "file" only
  // How long a calibration of one camera waits for the other camera's (as the CameraDriver's default).
  static constexpr double kPairTimeoutS = 10.0;
  DriverCalibrationWatch calibration_;  // the driver's camera_info: epoch, uncalibrated
  ErrorThrottle input_warnings_{10.0};  // per topic and problem (an image size, an uncalibrated camera_info)
  ErrorThrottle errors_{5.0};           // dropped frames, per message

  std::unique_ptr<image_transport::ImageTransport> it_;
  std::unique_ptr<ExternalStereoInput> input_;  // the driver's four topics, paired by stamp
  image_transport::CameraPublisher left_pub_, right_pub_;
  ros::Publisher mode_pub_, sim_level_pub_;
  ros::Subscriber health_sub_;  // calibration_trigger on_demand only
  ros::ServiceServer set_light_srv_, left_set_info_srv_, right_set_info_srv_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::WallTimer timer_;
  std::chrono::steady_clock::time_point started_;

  std::optional<PendingFrame> pending_;
  bool commanded_on_ = false;
  core::ConfirmedLight last_light_;
  std::string light_error_, missing_;
  uint64_t frames_out_ = 0, dropped_ = 0, settled_on_ = 0, settled_off_ = 0;
  double max_spread_s_ = 0.0;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::LightControllerNodelet, nodelet::Nodelet)
