// The CameraDriver nodelet (docs/nodelets.md#cameradriver).
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/package.h>
#include <ros/ros.h>
#include <sensor_msgs/SetCameraInfo.h>
#include <std_srvs/SetBool.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>

#include "embedded_calibration_stereo/CalibrationHealth.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/VerifiedCalibration.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/core/driver/frame_pacer.h"
#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/core/calibration/verified_marking.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/ros/camera_calibration.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/driver_params.h"
#include "embedded_calibration_stereo/ros/frame_source.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/light_backend.h"
#include "embedded_calibration_stereo/ros/sim_ground_truth.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

// Publishes stereo frames from a backend (sim, files, v4l2) with both CameraInfos and one
// calibration_mode per frame, all with one stamp; switches the light on its schedule
// (core::LightSchedule) or on request; stores the calibrations sent to set_camera_info
// (StereoCalibration). What it publishes, serves and refuses: docs/nodelets.md#cameradriver.
// Threads:
//  - the capture thread (started at the end of onInit, joined in the destructor) owns source_,
//    light_, the publishers' use and the diagnostics, and takes mutex_ for the shared state
//    once per frame;
//  - the manager's callback threads run the services (set_light, set_camera_info, sim/set_drift)
//    and the calibration/health subscriber, and touch only schedule_ under mutex_, calibration_
//    (thread-safe: the capture thread reads the pair in force and its epoch from one snapshot,
//    never waiting for a disk write), verified_ (the health's callback only) and sim_
//    (thread-safe drift, through ground_truth_).
class CameraDriverNodelet : public GuardedNodelet {
 public:
  CameraDriverNodelet() : GuardedNodelet("CameraDriver") {}
  ~CameraDriverNodelet() override { stopCapture(); }

 private:
  void releaseAfterFailedStart() override {
    releaseServices();
  }

  // nodelet::Loader destroys a failed nodelet's callback queues before the nodelet itself;
  // a service still advertised then would unregister from a freed queue. Drop them now.
  void releaseServices() {
    stopCapture();
    for (ros::ServiceServer* server : {&left_set_info_srv_, &right_set_info_srv_, &set_light_srv_}) server->shutdown();
    if (ground_truth_) ground_truth_->shutdown();
    health_sub_.shutdown();
  }

  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const std::string package_path = ros::package::getPath("embedded_calibration_stereo");
    params_ = loadDriverParams(pnh, package_path.empty() ? "" : package_path + "/config/sim_rig.yaml");

    auto light_level = std::make_shared<std::atomic<double>>(0.0);
    auto light_command = std::make_shared<std::atomic<uint64_t>>(0);  // for the sim's light response
    if (params_.backend == "sim") {
      try {
        sim_ = std::make_shared<core::SimRig>(core::loadSimRigConfig(params_.sim_config));
      } catch (const std::exception& e) {
        throw core::ConfigError("sim_config", "'" + params_.sim_config + "': " + e.what());
      }
      source_ = makeSimFrameSource(sim_, light_level, light_command, params_.fps);
    } else if (params_.backend == "files") {
      source_ = makeFilesFrameSource(params_.files);
    } else {
      source_ = makeV4l2FrameSource(params_.v4l2);
    }
    light_ = makeLightBackend(params_.light, light_level, light_command);
    schedule_ = std::make_unique<core::LightSchedule>(params_.schedule);
    loadCalibrations();

    image_transport::ImageTransport it(nh);
    left_pub_ = it.advertiseCamera("left/image_raw", 2);
    right_pub_ = it.advertiseCamera("right/image_raw", 2);
    mode_pub_ = nh.advertise<CalibrationMode>("calibration_mode", 2);
    left_set_info_srv_ = nh.advertiseService<sensor_msgs::SetCameraInfo::Request, sensor_msgs::SetCameraInfo::Response>(
        "left/set_camera_info", [this](auto& req, auto& res) { return setCameraInfo(true, req, res); });
    right_set_info_srv_ = nh.advertiseService<sensor_msgs::SetCameraInfo::Request, sensor_msgs::SetCameraInfo::Response>(
        "right/set_camera_info", [this](auto& req, auto& res) { return setCameraInfo(false, req, res); });
    set_light_srv_ = nh.advertiseService("set_light", &CameraDriverNodelet::setLight, this);
    // The health's verdicts: on demand, when to calibrate; always, which calibration was verified
    // GOOD (kept on disk, and latched on calibration/verified for a rollback after a restart).
    verified_pub_ = nh.advertise<VerifiedCalibration>("calibration/verified", 1, true);
    publishVerified();
    health_sub_ = nh.subscribe("calibration/health", 2, &CameraDriverNodelet::onHealth, this);
    // A staged calibration of one camera alone, unmatched within pair_timeout_s, is committed
    // here, off the capture thread (it writes to disk).
    monocular_timer_ = nh.createWallTimer(ros::WallDuration(0.5), [this](const ros::WallTimerEvent&) {
      for (const StereoCalibration::SetResult& result : calibration_->applyStagedMonocular()) {
        if (result.success)
          NODELET_INFO("CameraDriver: %s, epoch %u", result.message.c_str(), calibration_->inForce().epoch);
        else
          NODELET_ERROR("CameraDriver: %s", result.message.c_str());
      }
    });
    if (sim_) ground_truth_ = std::make_unique<SimGroundTruth>(nh, it, sim_, params_.left_frame_id);
    NODELET_INFO("CameraDriver: backend %s, light %s, %.1f fps", params_.backend.c_str(),
                 params_.light.backend.c_str(), params_.fps);
    diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
    diagnostics_->setHardwareID(params_.backend == "v4l2" ? params_.v4l2.left_device : params_.backend);
    diagnostics_->add("camera_driver", this, &CameraDriverNodelet::diagnose);
    running_ = true;
    capture_thread_ = std::thread(&CameraDriverNodelet::captureLoop, this);
  }

  // Loads the calibration pair; without a file, the nominal cameras of device_config (the
  // drawing, never the simulator's truth) or, without them, an uncalibrated message carrying only
  // the image size, are used in memory until the first set_camera_info. A rejected file does not
  // stop the driver: it runs on the previous generation or the nominal calibration with an ERROR
  // (log and diagnostics).
  void loadCalibrations() {
    const cv::Size size = source_->imageSize();
    const std::optional<core::StereoRig> nominal =
        params_.device_config.empty() ? std::nullopt : core::loadNominalRig(params_.device_config, "device_config");
    const auto [left_fallback, right_fallback] = fallbackCameraInfos(nominal, size.width, size.height);
    calibration_ = std::make_unique<StereoCalibration>(
        StereoCalibration::Camera{params_.left_camera_name, params_.left_camera_info_url, "left_camera_info_url"},
        StereoCalibration::Camera{params_.right_camera_name, params_.right_camera_info_url, "right_camera_info_url"},
        static_cast<uint32_t>(size.width), static_cast<uint32_t>(size.height), params_.pair_timeout_s, nominal);
    const std::string source = calibration_->load(left_fallback, right_fallback);
    const std::string problem = calibration_->problem();
    if (problem.empty())
      NODELET_INFO("CameraDriver: calibration from %s", source.c_str());
    else
      NODELET_ERROR("CameraDriver: %s", problem.c_str());
  }

  void stopCapture() {
    {
      std::lock_guard<std::mutex> lock(stop_mutex_);
      running_ = false;
    }
    stop_cv_.notify_all();
    if (capture_thread_.joinable()) capture_thread_.join();
  }

  // Paced by the steady clock: a late frame does not make the next ones burst to catch up.
  void captureLoop() {
    using Clock = std::chrono::steady_clock;
    const auto start = Clock::now();
    core::FramePacer pacer(params_.fps, start);
    while (true) {
      try {
        captureOne(std::chrono::duration<double>(Clock::now() - start).count());
      } catch (const std::exception& e) {  // e.g. a decoder or cv_bridge error: skip the frame
        NODELET_ERROR_THROTTLE(5.0, "CameraDriver: frame dropped: %s", e.what());
      }
      const auto next = pacer.next(Clock::now());
      std::unique_lock<std::mutex> lock(stop_mutex_);
      if (stop_cv_.wait_until(lock, next, [this] { return !running_; })) break;
    }
  }

  void captureOne(double time_s) {
    const ros::Time stamp = ros::Time::now();
    const bool recorded_light = source_->recordsLightState();
    core::LightState light;
    if (!recorded_light) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        light = schedule_->step(time_s);
      }
      std::string error;
      if (!light_->apply(light, &error)) NODELET_ERROR_THROTTLE(5.0, "CameraDriver: light: %s", error.c_str());
    }
    const std::string discarded = calibration_->expireStaged();
    if (!discarded.empty()) NODELET_ERROR("CameraDriver: %s", discarded.c_str());
    StereoFrame frame;
    std::string error;
    if (!source_->grab(time_s, &frame, &error)) {
      NODELET_WARN_THROTTLE(5.0, "CameraDriver: no frame from backend %s: %s", params_.backend.c_str(), error.c_str());
      last_error_ = error;
      diagnostics_->update();
      return;
    }
    CalibrationModePtr mode = boost::make_shared<CalibrationMode>();
    if (recorded_light) {
      std::lock_guard<std::mutex> lock(mutex_);
      light = schedule_->follow(frame.light_on.value_or(false));
    }
    // Both CameraInfos and the epoch from one snapshot: a published pair is never mixed.
    StereoCalibration::InForce in_force = calibration_->inForce();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      schedule_->calibrationInForce(in_force.epoch);  // a new one is checked against the boards at once
    }
    auto left_info = boost::make_shared<sensor_msgs::CameraInfo>(std::move(in_force.left));
    auto right_info = boost::make_shared<sensor_msgs::CameraInfo>(std::move(in_force.right));
    mode->calibration_epoch = in_force.epoch;
    std_msgs::Header left_header, right_header;
    left_header.stamp = right_header.stamp = stamp;
    left_header.frame_id = params_.left_frame_id;
    right_header.frame_id = params_.right_in_left_frame ? params_.left_frame_id : params_.right_frame_id;
    left_info->header = left_header;
    right_info->header = right_header;
    mode->header = left_header;
    mode->light_on = light.light_on;
    mode->settled = light.settled;
    // Messages are never modified after publishing: subscribers in the manager share them.
    left_pub_.publish(cv_bridge::CvImage(left_header, frame.encoding, frame.left).toImageMsg(), left_info);
    right_pub_.publish(cv_bridge::CvImage(right_header, frame.encoding, frame.right).toImageMsg(), right_info);
    mode_pub_.publish(mode);
    if (frame.truth) ground_truth_->publish(*frame.truth, left_header, right_header);
    ++frames_published_;
    last_light_on_ = light.light_on;
    last_error_.clear();
    diagnostics_->update();
  }

  // Runs on the capture thread (inside diagnostics_->update()).
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    const auto now = std::chrono::steady_clock::now();
    const double span = std::chrono::duration<double>(now - diagnosed_at_).count();
    const double rate = diagnosed_at_.time_since_epoch().count() == 0 ? 0.0 : frames_published_ / span;
    diagnosed_at_ = now;
    frames_published_ = 0;
    const uint32_t epoch = calibration_->inForce().epoch;
    const std::string calibration_problem = calibration_->problem();
    const core::StatusSummary summary = core::driverSummary(last_error_, calibration_problem, rate, params_.fps);
    status.summary(toDiagnosticLevel(summary.level), summary.text);
    status.add("frame rate (fps)", rate);
    status.add("configured fps", params_.fps);
    status.add("light on", last_light_on_);
    status.add("calibration trigger",
               params_.schedule.trigger == core::CalibrationTrigger::kOnDemand ? "on_demand" : "periodic");
    {
      std::lock_guard<std::mutex> lock(mutex_);
      status.add("calibration demanded (health not good)", schedule_->demanded());
    }
    status.add("calibration epoch", epoch);
    status.add("calibration", calibration_->source());
    status.add("calibration problem", calibration_problem.empty() ? "none" : calibration_problem);
    const std::string staged = calibration_->stagedText();
    status.add("calibration staged", staged.empty() ? "none" : staged);
  }

  bool setCameraInfo(bool left, sensor_msgs::SetCameraInfo::Request& req, sensor_msgs::SetCameraInfo::Response& res) {
    const char* side = left ? "left" : "right";
    const StereoCalibration::SetResult result = calibration_->set(left, req.camera_info);
    res.success = result.success;
    res.status_message = result.message;
    if (!result.discarded.empty()) NODELET_ERROR("CameraDriver: %s", result.discarded.c_str());
    if (!result.success) {
      // Throttled per message: a caller in a loop must not flood the log (each call is answered).
      if (refusals_.shouldReport(result.message))
        NODELET_ERROR("CameraDriver: %s set_camera_info refused, calibration unchanged: %s", side,
                      result.message.c_str());
    } else
      NODELET_INFO("CameraDriver: %s calibration %s, epoch %u", side, result.message.c_str(),
                   calibration_->inForce().epoch);
    return true;
  }

  bool setLight(std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
    if (source_->recordsLightState()) {
      res.success = false;
      res.message = "the files backend replays the light states of files_light_csv";
      return true;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    schedule_->request(req.data);
    res.success = true;
    res.message = req.data ? "light on from the next frame" : "light off from the next frame";
    return true;
  }

  // On demand: a calibration burst while the health nodelet wants one (the calibration is known
  // not to hold and the calibrator has not found it to be the best it can do).
  void onHealth(const CalibrationHealthConstPtr& health) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      schedule_->demand(health->calibration_wanted);  // on demand only
    }
    if (!verified_.due(health->state == CalibrationHealth::GOOD, health->verification_age_s, health->epoch)) return;
    bool marked = false;
    const std::string error = calibration_->markVerified(health->epoch, &marked);
    if (!error.empty()) {
      NODELET_ERROR_THROTTLE(10.0, "CameraDriver: verified calibration not marked: %s", error.c_str());
      return;
    }
    verified_.done(health->epoch);
    if (!marked) return;
    NODELET_INFO("CameraDriver: calibration of epoch %u verified GOOD, kept as such in '%s'", health->epoch,
                 calibration_->store().directory().c_str());
    publishVerified();
  }

  // The newest calibration verified GOOD on disk, latched; nothing while there is none.
  void publishVerified() {
    const std::optional<StereoCalibration::Verified> verified = calibration_->newestVerified();
    if (!verified) return;
    auto msg = boost::make_shared<VerifiedCalibration>();
    msg->header.stamp = ros::Time::now();
    msg->generation = verified->generation;
    msg->left = verified->left;
    msg->right = verified->right;
    verified_pub_.publish(msg);
  }

  DriverParams params_;
  std::shared_ptr<core::SimRig> sim_;
  std::unique_ptr<FrameSource> source_;
  std::unique_ptr<LightBackend> light_;
  std::unique_ptr<StereoCalibration> calibration_;  // created in onInit, thread-safe

  std::mutex mutex_;  // guards schedule_
  std::unique_ptr<core::LightSchedule> schedule_;

  image_transport::CameraPublisher left_pub_, right_pub_;
  ros::Publisher mode_pub_, verified_pub_;
  ErrorThrottle refusals_{5.0};  // set_camera_info refusals, per message (thread-safe)
  core::VerifiedMarking verified_;  // the health's callback only
  ros::ServiceServer left_set_info_srv_, right_set_info_srv_, set_light_srv_;
  ros::Subscriber health_sub_;  // the health's verdicts (on demand: when to calibrate; always: verified)
  ros::WallTimer monocular_timer_;  // commits a staged calibration of one camera alone

  // Capture thread only.
  std::unique_ptr<SimGroundTruth> ground_truth_;  // sim backend only (its service: any thread)
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  int frames_published_ = 0;
  bool last_light_on_ = false;
  std::string last_error_;
  std::chrono::steady_clock::time_point diagnosed_at_;

  std::mutex stop_mutex_;
  std::condition_variable stop_cv_;
  bool running_ = false;  // guarded by stop_mutex_
  std::thread capture_thread_;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::CameraDriverNodelet, nodelet::Nodelet)
