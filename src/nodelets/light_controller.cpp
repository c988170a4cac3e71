// LightController nodelet: runs the head's calibration light when the cameras are driven by
// another ROS driver (any camera_info_manager-based driver, image_publisher, a vendor's node).
// It owns the light backend (serial, gpio, sim, none), the schedule and set_light, and turns the
// external driver's frames into the head's stereo stream: for each stereo frame of the driver,
// matched by stamp (ExactTime, or ApproximateTime for two independent drivers), it publishes
// left|right/image_raw, left|right/camera_info and one calibration_mode message, all with the left
// image's stamp, so the rest of the graph runs unchanged (ExactTime everywhere). The light
// follows the schedule: calibration bursts every calibration_period_s (calibration_trigger
// periodic) or when calibration/health leaves GOOD (on_demand, with min_calibration_interval_s
// and calibration_period_s as a safety net), verification flashes every verification_period_s
// and after every new calibration; or set_light.
//
// The driver's latency between a light command and the exposure is unknown, so each frame's
// light state and settled flag come from the images themselves (core LightLevelTracker: the
// brightness step of the device's taught board regions, or of the whole image); the commanded
// state is only checked against them (the light watch). The whole image is confirmed from the
// start; regions taught later (the tracker's prior file) take over once their own confirmation
// has seen a switch, so a change of regions never guesses the state. Deciding a frame needs the
// next one: frames leave one frame late.
//
// calibration_epoch counts the changes of the driver's camera_info (one per camera), as our
// CameraDriver counts its accepted set_camera_info calls. Calibrations are stored by the driver
// itself (calibration_store "driver": the calibrator calls the driver's set_camera_info) or, for
// drivers that read a calibration file but cannot store one (image_publisher), by this nodelet
// (calibration_store "file": it serves left|right/set_camera_info, writes both cameras' files as
// one pair and asks both drivers to reload theirs through their dynamic_reconfigure parameter
// camera_info_url).
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <dynamic_reconfigure/Reconfigure.h>
#include <image_transport/image_transport.h>
#include <image_transport/subscriber_filter.h>
#include <message_filters/subscriber.h>
#include <message_filters/sync_policies/approximate_time.h>
#include <message_filters/sync_policies/exact_time.h>
#include <message_filters/synchronizer.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/SetCameraInfo.h>
#include <std_msgs/Float64.h>
#include <std_srvs/SetBool.h>
#include <sys/stat.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <memory>
#include <optional>

#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/core/calibration/light_confirmation.h"
#include "embedded_calibration_stereo/core/calibration/light_schedule.h"
#include "embedded_calibration_stereo/core/geometry/config_error.h"
#include "embedded_calibration_stereo/ros/camera_calibration.h"
#include "embedded_calibration_stereo/ros/driver_params.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/lazy_synced_input.h"
#include "embedded_calibration_stereo/ros/light_backend.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"
#include "embedded_calibration_stereo/ros/tracker_teaching.h"

namespace embedded_calibration_stereo {

namespace {

using sensor_msgs::CameraInfo;
using sensor_msgs::CameraInfoConstPtr;
using sensor_msgs::Image;
using sensor_msgs::ImageConstPtr;

struct LightControllerParams {
  std::string light_backend = "none";  // none | serial | gpio | sim
  SerialLightParams serial;
  GpioLightParams gpio;
  ecs::LightScheduleConfig schedule;  // calibration_period_s, calibration_frames, settle_frames
  bool approximate_sync = true;
  double max_interval_s = 0.0;  // ApproximateTime's limit on a set's stamp spread; 0 = none
  int queue_size = 5;
  std::string prior_file;
  double region_margin_squares = 1.5;
  ecs::LightConfirmationOptions confirmation;
  int max_delay_frames = 3;
  std::string calibration_store = "driver";  // driver | file
  std::string left_camera_name = "stereo_left", right_camera_name = "stereo_right";
  std::string left_camera_info_url, right_camera_info_url;
  std::string left_reload_service, right_reload_service;  // the driver's .../set_parameters
};

std::string readBytes(const ParameterReader& read, const std::string& name, const std::string& fallback) {
  std::string decoded, error;
  if (!unescapeBytes(read.get(name, fallback), &decoded, &error)) throw ecs::ConfigError(name, error);
  return decoded;
}


// Every parameter is read and checked here, once, at start.
LightControllerParams loadParams(const ros::NodeHandle& pnh) {
  const ParameterReader read(pnh);
  LightControllerParams p;
  p.light_backend = read.choice("light_backend", p.light_backend, {"serial", "gpio", "sim", "none"});
  if (p.light_backend == "serial") {
    p.serial.port = read.required<std::string>("serial_port");
    if (p.serial.port.empty()) throw ecs::ConfigError("serial_port", "missing");
    p.serial.baud = read.get("serial_baud", p.serial.baud);
    p.serial.on_bytes = readBytes(read, "serial_on", "ON\\n");
    p.serial.off_bytes = readBytes(read, "serial_off", "OFF\\n");
  } else if (p.light_backend == "gpio") {
    p.gpio.chip = read.get("gpio_chip", p.gpio.chip);
    p.gpio.line = read.get("gpio_line", p.gpio.line);
    p.gpio.active_low = read.get("gpio_active_low", p.gpio.active_low);
    if (p.gpio.line < 0) throw ecs::ConfigError("gpio_line", "missing or negative line offset");
  }
  p.schedule.period_s = read.get("calibration_period_s", 0.0);
  p.schedule.calibration_frames = read.get("calibration_frames", p.schedule.calibration_frames);
  // Frames the light is held on beyond calibration_frames: the driver's delay and the unsettled
  // frames on both sides of each switch.
  p.schedule.settle_frames = read.get("settle_frames", 5);
  readHealthSchedule(read, &p.schedule);
  ecs::throwIfProblem(p.schedule.problem());

  p.approximate_sync = read.get("approximate_sync", p.approximate_sync);
  p.max_interval_s = read.atLeast("max_interval_s", p.max_interval_s, 0.0);
  p.queue_size = read.atLeast("queue_size", p.queue_size, 1);
  p.prior_file = read.get("prior_file", defaultPatternPriorFile());
  p.region_margin_squares = read.atLeast("region_margin_squares", p.region_margin_squares, 0.0);
  p.confirmation.min_step = read.get("min_step", p.confirmation.min_step);
  p.confirmation.switch_fraction = read.get("switch_fraction", p.confirmation.switch_fraction);
  p.confirmation.plateau_fraction = read.get("plateau_fraction", p.confirmation.plateau_fraction);
  ecs::throwIfProblem(p.confirmation.problem());
  p.max_delay_frames = read.atLeast("max_delay_frames", p.max_delay_frames, 0);

  p.calibration_store = read.choice("calibration_store", p.calibration_store, {"driver", "file"});
  if (p.calibration_store == "file") {
    p.left_camera_name = read.get("left_camera_name", p.left_camera_name);
    p.right_camera_name = read.get("right_camera_name", p.right_camera_name);
    p.left_camera_info_url = read.get("left_camera_info_url", "");
    p.right_camera_info_url = read.get("right_camera_info_url", "");
    p.left_reload_service = read.get("left_reload_service", "");
    p.right_reload_service = read.get("right_reload_service", "");
    if (p.left_camera_info_url.empty()) throw ecs::ConfigError("left_camera_info_url", "missing (calibration_store file)");
    if (p.right_camera_info_url.empty()) throw ecs::ConfigError("right_camera_info_url", "missing (calibration_store file)");
  }
  return p;
}

// The calibration fields of a CameraInfo (not its header).
bool sameCalibration(const CameraInfo& a, const CameraInfo& b) {
  return a.width == b.width && a.height == b.height && a.distortion_model == b.distortion_model && a.D == b.D &&
         a.K == b.K && a.R == b.R && a.P == b.P;
}

bool uncalibrated(const CameraInfo& info) { return info.K[0] == 0.0 || info.P[0] == 0.0; }

// One stereo frame of the driver, waiting for the next one to be decided.
struct PendingFrame {
  ImageConstPtr left, right;
  CameraInfoConstPtr left_info, right_info;
  uint32_t epoch = 0;
};

}  // namespace

// Threads: everything runs on the nodelet's single-threaded callback queue (frame callbacks,
// set_light, set_camera_info, calibration/health, the diagnostics timer), so the state below
// needs no lock. The light
// backend is driven from the frame callback only.
class LightControllerNodelet : public GuardedNodelet {
 public:
  LightControllerNodelet() : GuardedNodelet("LightController") {}
  ~LightControllerNodelet() override = default;

 private:
  using ExactPolicy = message_filters::sync_policies::ExactTime<Image, CameraInfo, Image, CameraInfo>;
  using ApproximatePolicy = message_filters::sync_policies::ApproximateTime<Image, CameraInfo, Image, CameraInfo>;

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
    params_ = loadParams(pnh);
    makeLight(nh);
    schedule_ = std::make_unique<ecs::LightSchedule>(params_.schedule);
    whole_ = std::make_unique<ecs::StereoLightConfirmer>(params_.confirmation);
    watch_ = std::make_unique<ecs::LightCommandWatch>(params_.max_delay_frames);
    if (params_.calibration_store == "file") advertiseSetCameraInfo(nh);
    loadRegions(true);
    advertiseOutputs(nh);
    subscribeDriver(nh, pnh);
    synchroniseDriver();
    startDiagnostics(nh, pnh);
    NODELET_INFO("LightController: light %s, %s sync of %s and %s, light confirmed in %s, calibrations stored by %s",
                 params_.light_backend.c_str(), params_.approximate_sync ? "approximate" : "exact",
                 left_sub_.getTopic().c_str(), right_sub_.getTopic().c_str(), regionsText().c_str(),
                 params_.calibration_store == "file" ? "this nodelet (files, driver reloads)" : "the driver");
  }

  // The light backend the parameters name.
  void makeLight(ros::NodeHandle& nh) {
    if (params_.light_backend == "serial") {
      light_ = makeSerialLight(params_.serial);
    } else if (params_.light_backend == "gpio") {
      light_ = makeGpioLight(params_.gpio);
    } else if (params_.light_backend == "sim") {
      sim_level_ = std::make_shared<std::atomic<double>>(0.0);
      light_ = makeSimLight(sim_level_);
      // A simulated camera driver reads the level from here (it has no light of its own).
      sim_level_pub_ = nh.advertise<std_msgs::Float64>("sim/light_level", 1, true);
    } else {
      light_ = makeNoLight();
    }
  }

  // calibration_store "file": this nodelet serves both cameras' set_camera_info. The pair store
  // is made at the first set_camera_info, when the driver's image size is known.
  void advertiseSetCameraInfo(ros::NodeHandle& nh) {
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
    if (params_.schedule.trigger == ecs::CalibrationTrigger::kOnDemand)
      health_sub_ = nh.subscribe<CalibrationHealth>("calibration/health", 2, [this](const auto& health) {
        // On demand: a calibration burst while the health nodelet wants one (the calibration is
        // known not to hold and the calibrator has not found it to be the best it can do).
        schedule_->demand(health->calibration_wanted);
      });
  }

  // The driver's four topics, counted as they arrive and filtered before the synchroniser.
  void subscribeDriver(ros::NodeHandle& nh, ros::NodeHandle& pnh) {
    const image_transport::TransportHints hints("raw", ros::TransportHints(), pnh);
    left_sub_.subscribe(*it_, "driver/left/image_raw", params_.queue_size, hints);
    right_sub_.subscribe(*it_, "driver/right/image_raw", params_.queue_size, hints);
    left_info_sub_.subscribe(nh, "driver/left/camera_info", params_.queue_size);
    right_info_sub_.subscribe(nh, "driver/right/camera_info", params_.queue_size);
    // Arrivals per topic, to name the missing one when no frame can be matched.
    left_sub_.registerCallback([this](const ImageConstPtr&) { ++arrived_[0]; });
    left_info_sub_.registerCallback([this](const CameraInfoConstPtr&) { ++arrived_[1]; });
    right_sub_.registerCallback([this](const ImageConstPtr&) { ++arrived_[2]; });
    right_info_sub_.registerCallback([this](const CameraInfoConstPtr&) { ++arrived_[3]; });
    admitDriverInputs(pnh);
  }

  // Stamps far from the other inputs' (and unreadable images) never reach the synchroniser,
  // whose queue they would fill (stamp_guard.h, as every synchronised input of the head).
  void admitDriverInputs(ros::NodeHandle& pnh) {
    guard_ = std::make_unique<StampGuard>(
        std::vector<std::string>{left_sub_.getTopic(), left_info_sub_.getTopic(), right_sub_.getTopic(),
                                 right_info_sub_.getTopic()},
        readStampTolerance(pnh), "LightController", [this](const std::string& text) { NODELET_WARN("%s", text.c_str()); });
    const auto admit_image = [this](size_t index) {
      return [this, index](const ros::MessageEvent<Image const>& event) {
        const Image& image = *event.getMessage();
        return malformedImage(image).empty() && guard_->admit(index, image.header.stamp);
      };
    };
    const auto admit_info = [this](size_t index) {
      return [this, index](const ros::MessageEvent<CameraInfo const>& event) {
        return guard_->admit(index, event.getMessage()->header.stamp);
      };
    };
    left_admit_ = std::make_unique<AdmissionFilter<Image>>(left_sub_, admit_image(0));
    left_info_admit_ = std::make_unique<AdmissionFilter<CameraInfo>>(left_info_sub_, admit_info(1));
    right_admit_ = std::make_unique<AdmissionFilter<Image>>(right_sub_, admit_image(2));
    right_info_admit_ = std::make_unique<AdmissionFilter<CameraInfo>>(right_info_sub_, admit_info(3));
  }

  // One stereo frame per matched set of the admitted inputs: by stamp (ExactTime), or nearest
  // stamps (ApproximateTime) for two independent drivers.
  void synchroniseDriver() {
    if (params_.approximate_sync) {
      approximate_sync_ = std::make_unique<message_filters::Synchronizer<ApproximatePolicy>>(
          ApproximatePolicy(params_.queue_size), *left_admit_, *left_info_admit_, *right_admit_, *right_info_admit_);
      if (params_.max_interval_s > 0)
        approximate_sync_->setMaxIntervalDuration(ros::Duration(params_.max_interval_s));
      approximate_sync_->registerCallback(&LightControllerNodelet::frameCb, this);
    } else {
      exact_sync_ = std::make_unique<message_filters::Synchronizer<ExactPolicy>>(
          ExactPolicy(params_.queue_size), *left_admit_, *left_info_admit_, *right_admit_, *right_info_admit_);
      exact_sync_->registerCallback(&LightControllerNodelet::frameCb, this);
    }
  }

  // The diagnostics, the once-a-second tick (regions re-read, missing inputs named, diagnostics
  // updated) and the origin of the schedule's clock.
  void startDiagnostics(ros::NodeHandle& nh, ros::NodeHandle& pnh) {
    diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
    diagnostics_->setHardwareID(params_.light_backend == "serial" ? params_.serial.port : params_.light_backend);
    diagnostics_->add("light_controller", this, &LightControllerNodelet::diagnose);
    timer_ = nh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) { tick(); });
    started_ = std::chrono::steady_clock::now();
  }

  bool regionsInUse() const { return regions_ && regions_->known(); }

  std::string regionsText() const {
    if (regionsInUse()) return "the taught board regions of " + params_.prior_file;
    if (regions_) return "the whole image (the taught regions take over at the next switch)";
    return "the whole image";
  }

  // (Re)reads the tracker's prior when the file appeared or changed; the new regions get a
  // confirmation of their own, which knows the light's state from its first switch on.
  void loadRegions(bool at_start) {
    struct stat info {};
    const bool exists = ::stat(params_.prior_file.c_str(), &info) == 0;
    const int64_t mtime = exists ? static_cast<int64_t>(info.st_mtim.tv_sec) * 1000000000 + info.st_mtim.tv_nsec : -1;
    if (mtime == prior_mtime_) return;
    prior_mtime_ = mtime;
    cv::Mat masks[2];
    std::string problem;
    if (exists) {
      try {
        const ecs::PatternPrior prior = ecs::readPatternPrior(params_.prior_file);
        if (prior.cameras.size() != 2) throw std::invalid_argument("expected 2 cameras, found " +
                                                                   std::to_string(prior.cameras.size()));
        for (int c = 0; c < 2; ++c) masks[c] = ecs::boardRegionMask(prior.cameras[c], params_.region_margin_squares);
        if (masks[0].empty() || masks[1].empty()) throw std::invalid_argument("a camera has no board");
      } catch (const std::exception& e) {
        problem = e.what();
        masks[0] = masks[1] = cv::Mat();
      }
    }
    masks_[0] = masks[0];
    masks_[1] = masks[1];
    regions_.reset();
    if (!masks[0].empty()) {
      regions_ = std::make_unique<ecs::StereoLightConfirmer>(params_.confirmation);
      regions_->forgetLevels();  // the state is unknown to it until it sees a switch
      NODELET_INFO("LightController: taught board regions read from %s; they confirm the light from the next switch on",
                   params_.prior_file.c_str());
    }
    if (!problem.empty())
      NODELET_WARN("LightController: prior file '%s' unusable (%s); confirming the light over the whole image",
                   params_.prior_file.c_str(), problem.c_str());
    (void)at_start;
  }

  // A mask of another size than the image (prior of another camera mode) is not used.
  double level(const cv::Mat& image, const cv::Mat& mask, const std::string& topic) {
    if (!mask.empty() && mask.size() != image.size()) {
      NODELET_WARN_THROTTLE(10.0, "LightController: %s is %dx%d but the prior file '%s' was taught on %dx%d images; "
                                  "confirming the light over the whole image",
                            topic.c_str(), image.cols, image.rows, params_.prior_file.c_str(), mask.cols, mask.rows);
      return ecs::regionLevel(image, cv::Mat());
    }
    return ecs::regionLevel(image, mask);
  }

  bool readImage(const ImageConstPtr& msg, const std::string& topic, cv_bridge::CvImageConstPtr* out) {
    if (msg->encoding != "mono8" && msg->encoding != "bgr8" && msg->encoding != "rgb8") {
      NODELET_ERROR_THROTTLE(5.0, "LightController: %s has encoding '%s' (expected mono8, bgr8 or rgb8); frame dropped",
                             topic.c_str(), msg->encoding.c_str());
      return false;
    }
    try {
      *out = cv_bridge::toCvShare(msg);
    } catch (const cv_bridge::Exception& e) {
      NODELET_ERROR_THROTTLE(5.0, "LightController: cannot read %s: %s; frame dropped", topic.c_str(), e.what());
      return false;
    }
    if ((*out)->image.empty()) {
      NODELET_ERROR_THROTTLE(5.0, "LightController: %s delivered an empty image; frame dropped", topic.c_str());
      return false;
    }
    return true;
  }

  void frameCb(const ImageConstPtr& left, const CameraInfoConstPtr& left_info, const ImageConstPtr& right,
               const CameraInfoConstPtr& right_info) {
    ++frames_in_;
    cv_bridge::CvImageConstPtr left_cv, right_cv;
    if (!readImage(left, left_sub_.getTopic(), &left_cv) || !readImage(right, right_sub_.getTopic(), &right_cv)) {
      ++dropped_;
      return;
    }
    const double spread = std::abs((right->header.stamp - left->header.stamp).toSec());
    max_spread_s_ = std::max(max_spread_s_, spread);
    checkCalibration(*left_info, left_info_sub_.getTopic(), 0);
    checkCalibration(*right_info, right_info_sub_.getTopic(), 1);

    // The light for the next frames (the driver's delay decides which frame shows it).
    const double time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
    const ecs::LightState commanded = schedule_->step(time_s);
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

    std::optional<ecs::ConfirmedLight> decided =
        whole_->push(ecs::regionLevel(left_cv->image, cv::Mat()), ecs::regionLevel(right_cv->image, cv::Mat()));
    if (regions_) {
      const auto by_regions = regions_->push(level(left_cv->image, masks_[0], left_sub_.getTopic()),
                                             level(right_cv->image, masks_[1], right_sub_.getTopic()));
      if (regions_->known() && by_regions) decided = by_regions;
    }
    if (params_.light_backend != "none") {
      watch_->update(commanded.light_on, decided);
      if (!watch_->fault().empty())
        NODELET_ERROR_THROTTLE(5.0, "LightController: the light is not working: %s (light %s)", watch_->fault().c_str(),
                               params_.light_backend.c_str());
    }
    if (pending_ && decided) publish(*pending_, *decided);
    pending_ = PendingFrame{left, right, left_info, right_info, epoch_};
  }

  // Counts calibration changes (the epoch) and reports uncalibrated camera_info.
  void checkCalibration(const CameraInfo& info, const std::string& topic, int side) {
    if (last_info_[side] && !sameCalibration(*last_info_[side], info)) {
      ++epoch_;
      schedule_->verifySoon();  // a new calibration in force is checked against the boards at once
      NODELET_INFO("LightController: new calibration on %s, calibration epoch %u", topic.c_str(), epoch_);
    }
    last_info_[side] = info;
    uncalibrated_[side] = uncalibrated(info);
    if (uncalibrated_[side])
      NODELET_WARN_THROTTLE(10.0, "LightController: %s is uncalibrated (K or P all zero): the calibrator starts from "
                                  "scratch and depth waits for a committed calibration",
                            topic.c_str());
  }

  void publish(const PendingFrame& frame, const ecs::ConfirmedLight& light) {
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
    if (params_.light_backend == "none")
      res.message = std::string("no light backend: switch the light ") + (req.data ? "on" : "off") +
                    " by other means; calibration_mode follows what the images show";
    else
      res.message = req.data ? "light on from the next frame" : "light off from the next frame";
    return true;
  }

  // calibration_store "file": validate, write the driver's calibration file, ask it to reload.
  bool setCameraInfo(bool left, sensor_msgs::SetCameraInfo::Request& req, sensor_msgs::SetCameraInfo::Response& res) {
    const char* side = left ? "left" : "right";
    const std::optional<CameraInfo>& in_force = last_info_[left ? 0 : 1];
    if (in_force && (req.camera_info.width != in_force->width || req.camera_info.height != in_force->height)) {
      res.success = false;
      res.status_message = "rejected: calibration is for " + std::to_string(req.camera_info.width) + "x" +
                           std::to_string(req.camera_info.height) + " but the driver's images are " +
                           std::to_string(in_force->width) + "x" + std::to_string(in_force->height);
      NODELET_WARN("LightController: %s set_camera_info %s", side, res.status_message.c_str());
      return true;
    }
    if (!calibration_) {
      if (!last_info_[0] || !last_info_[1]) {
        res.success = false;
        res.status_message = "rejected: no camera_info from the driver yet (the calibration's image size is unknown)";
        NODELET_WARN("LightController: %s set_camera_info %s", side, res.status_message.c_str());
        return true;
      }
      try {
        calibration_ = std::make_unique<StereoCalibration>(
            StereoCalibration::Camera{params_.left_camera_name, params_.left_camera_info_url, "left_camera_info_url"},
            StereoCalibration::Camera{params_.right_camera_name, params_.right_camera_info_url,
                                      "right_camera_info_url"},
            last_info_[0]->width, last_info_[0]->height, kPairTimeoutS);
        calibration_->load(*last_info_[0], *last_info_[1]);
      } catch (const ecs::ConfigError& e) {
        calibration_.reset();
        res.success = false;
        res.status_message = std::string("not stored: ") + e.what();
        NODELET_ERROR("LightController: %s set_camera_info: %s", side, res.status_message.c_str());
        return true;
      }
    }
    const StereoCalibration::SetResult result = calibration_->set(left, req.camera_info);
    if (!result.discarded.empty()) NODELET_ERROR("LightController: %s", result.discarded.c_str());
    res.success = result.success;
    res.status_message = result.message;
    if (!result.success) {
      if (refusals_.shouldReport(result.message))  // per message: a caller in a loop must not flood the log
        NODELET_ERROR("LightController: %s set_camera_info failed, calibration unchanged: %s", side,
                      result.message.c_str());
      return true;
    }
    if (result.message.rfind("staged:", 0) == 0) {  // waits for the other camera: nothing written yet
      NODELET_INFO("LightController: %s calibration %s", side, result.message.c_str());
      return true;
    }
    // Both files changed together: both drivers reload theirs.
    for (const bool side_left : {true, false}) {
      const std::string& service = side_left ? params_.left_reload_service : params_.right_reload_service;
      const std::string& url = side_left ? params_.left_camera_info_url : params_.right_camera_info_url;
      if (service.empty()) continue;
      dynamic_reconfigure::Reconfigure reload;
      dynamic_reconfigure::StrParameter parameter;
      parameter.name = "camera_info_url";
      parameter.value = url;
      reload.request.config.strs.push_back(parameter);
      if (!ros::service::call(service, reload)) {
        res.success = false;
        res.status_message = result.message + ", but the driver did not reload it: " + service + " is not available";
        NODELET_ERROR("LightController: %s set_camera_info: %s", side, res.status_message.c_str());
        return true;
      }
    }
    NODELET_INFO("LightController: %s calibration %s", side, res.status_message.c_str());
    return true;
  }

  // Once a second: regions taught meanwhile, missing inputs, diagnostics.
  void tick() {
    loadRegions(false);
    const uint64_t in = frames_in_ - frames_in_at_tick_;
    frames_in_at_tick_ = frames_in_;
    missing_.clear();
    if (in == 0) {
      const char* names[4] = {"image", "camera_info", "image", "camera_info"};
      const std::string topics[4] = {left_sub_.getTopic(), left_info_sub_.getTopic(), right_sub_.getTopic(),
                                     right_info_sub_.getTopic()};
      bool any = false;
      for (int i = 0; i < 4; ++i) any = any || arrived_[i] != arrived_at_tick_[i];
      for (int i = 0; i < 4; ++i)
        if (any && arrived_[i] == arrived_at_tick_[i])
          missing_ += (missing_.empty() ? "" : ", ") + std::string("no ") + names[i] + " on " + topics[i];
      if (any && missing_.empty()) missing_ = "the driver's images and camera_info arrive but do not pair by stamp";
      if (!missing_.empty())
        NODELET_ERROR_THROTTLE(5.0, "LightController: frames held back: %s (each image needs its camera_info, of "
                                    "the same stamp; the driver publishes it from its camera_info_url)",
                               missing_.c_str());
    }
    for (int i = 0; i < 4; ++i) arrived_at_tick_[i] = arrived_[i];
    diagnostics_->update();
    max_spread_s_ = 0.0;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    using diagnostic_msgs::DiagnosticStatus;
    const std::string fault = params_.light_backend != "none" ? watch_->fault() : "";
    if (!light_error_.empty()) {
      status.summary(DiagnosticStatus::ERROR, "light backend: " + light_error_);
    } else if (!fault.empty()) {
      status.summary(DiagnosticStatus::ERROR, "light not working: " + fault);
    } else if (!missing_.empty()) {
      status.summary(DiagnosticStatus::ERROR, "frames held back: " + missing_);
    } else if (uncalibrated_[0] || uncalibrated_[1]) {
      status.summary(DiagnosticStatus::WARN, "driver's camera_info uncalibrated");
    } else if (frames_out_ == 0) {
      status.summary(DiagnosticStatus::WARN, "no frame from the driver yet");
    } else {
      status.summary(DiagnosticStatus::OK, "confirming the light");
    }
    status.add("light backend", params_.light_backend);
    status.add("calibration trigger",
               params_.schedule.trigger == ecs::CalibrationTrigger::kOnDemand ? "on_demand" : "periodic");
    status.add("calibration demanded (health not good)", schedule_->demanded());
    status.add("light commanded on", commanded_on_);
    status.add("light confirmed on", last_light_.light_on);
    status.add("settled", last_light_.settled);
    const ecs::StereoLightConfirmer& used = regionsInUse() ? *regions_ : *whole_;
    status.add("light step left (grey levels)", used.left().step());
    status.add("light step right (grey levels)", used.right().step());
    status.add("confirmed in", regionsText());
    status.add("calibration epoch", epoch_);
    status.add("frames in", frames_in_);
    status.add("frames out", frames_out_);
    status.add("settled light-on frames", settled_on_);
    status.add("settled light-off frames", settled_off_);
    status.add("dropped frames", dropped_);
    status.add("max left/right stamp difference (ms)", 1000.0 * max_spread_s_);
    status.add("left camera_info", uncalibrated_[0] ? "uncalibrated" : "calibrated");
    status.add("right camera_info", uncalibrated_[1] ? "uncalibrated" : "calibrated");
  }

  LightControllerParams params_;
  std::unique_ptr<LightBackend> light_;
  SharedLightLevel sim_level_;
  double published_level_ = -1.0;
  std::unique_ptr<ecs::LightSchedule> schedule_;
  std::unique_ptr<ecs::StereoLightConfirmer> whole_;    // over the whole image, from the start
  std::unique_ptr<ecs::StereoLightConfirmer> regions_;  // over the taught regions, once taught
  std::unique_ptr<ecs::LightCommandWatch> watch_;
  // calibration_store "file": both cameras' files, committed as one pair (made at the first
  // set_camera_info; callback-queue thread only).
  std::unique_ptr<StereoCalibration> calibration_;
  ErrorThrottle refusals_{5.0};  // set_camera_info refusals, per message (thread-safe)
  // How long a calibration of one camera waits for the other camera's (as the CameraDriver's default).
  static constexpr double kPairTimeoutS = 10.0;
  cv::Mat masks_[2];
  int64_t prior_mtime_ = -2;

  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::SubscriberFilter left_sub_, right_sub_;
  message_filters::Subscriber<CameraInfo> left_info_sub_, right_info_sub_;
  std::unique_ptr<StampGuard> guard_;  // the subscribers -> the admissions -> the synchroniser
  std::unique_ptr<AdmissionFilter<Image>> left_admit_, right_admit_;
  std::unique_ptr<AdmissionFilter<CameraInfo>> left_info_admit_, right_info_admit_;
  std::unique_ptr<message_filters::Synchronizer<ExactPolicy>> exact_sync_;
  std::unique_ptr<message_filters::Synchronizer<ApproximatePolicy>> approximate_sync_;
  image_transport::CameraPublisher left_pub_, right_pub_;
  ros::Publisher mode_pub_, sim_level_pub_;
  ros::Subscriber health_sub_;  // calibration_trigger on_demand only
  ros::ServiceServer set_light_srv_, left_set_info_srv_, right_set_info_srv_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::WallTimer timer_;
  std::chrono::steady_clock::time_point started_;

  std::optional<PendingFrame> pending_;
  std::optional<CameraInfo> last_info_[2];
  bool uncalibrated_[2] = {false, false};
  uint32_t epoch_ = 0;
  bool commanded_on_ = false;
  ecs::ConfirmedLight last_light_;
  std::string light_error_, missing_;
  uint64_t frames_in_ = 0, frames_out_ = 0, dropped_ = 0, settled_on_ = 0, settled_off_ = 0;
  uint64_t frames_in_at_tick_ = 0, arrived_[4] = {0, 0, 0, 0}, arrived_at_tick_[4] = {0, 0, 0, 0};
  double max_spread_s_ = 0.0;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::LightControllerNodelet, nodelet::Nodelet)
