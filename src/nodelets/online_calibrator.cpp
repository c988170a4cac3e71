// OnlineCalibrator nodelet: solves each calibration window (light-on frames' board observations,
// or the tracker's whole-burst window observations), gates it against the calibration in force
// and commits it through the driver; serves calibration/recalibrate. It reads the parameters and
// wires topics, timers and the service to OnlineCalibration (the windows, the calibration in
// force, the worker), which runs the core's decisions. docs/nodelets.md, "OnlineCalibrator".
#include <diagnostic_updater/diagnostic_updater.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/callback_queue.h>
#include <ros/package.h>
#include <ros/ros.h>
#include <std_srvs/SetBool.h>

#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/ros/caller_probe.h"
#include "embedded_calibration_stereo/ros/guarded_nodelet.h"
#include "embedded_calibration_stereo/ros/online_calibration.h"
#include "embedded_calibration_stereo/ros/service_call.h"
#include "embedded_calibration_stereo/ros/stamp_guard.h"

namespace embedded_calibration_stereo {

// Threads:
//  - the manager's single-threaded queue runs the subscribers and the diagnostics, window age and
//    commit retry timers (the last only queues a job for the worker);
//  - calibration/recalibrate runs on this nodelet's own service queue and its two spinner
//    threads: a call blocks while the window fills and the worker solves (up to timeout_s), and
//    on the manager's shared pool it would hold one of its threads that long (the tracker and
//    the depth nodelets then fell behind); the second thread answers a call arriving meanwhile
//    ("busy") instead of queueing it; the running call probes its caller (CallerProbe) and the
//    driver's services (callService) without holding the calibration's mutex;
//  - OnlineCalibration's worker thread (started in initialise, joined in the destructor) alone
//    runs the solves and commits.
// OnlineCalibration guards what these share; guard_ (created before the subscribers) locks itself.
class OnlineCalibratorNodelet : public GuardedNodelet {
 public:
  OnlineCalibratorNodelet() : GuardedNodelet("OnlineCalibrator") {}
  ~OnlineCalibratorNodelet() override {
    if (calibration_) calibration_->stop();  // a recalibrate call in progress sees it and returns
    if (service_spinner_) service_spinner_->stop();
    recalibrate_srv_.shutdown();
  }

 private:
  void releaseAfterFailedStart() override {
    // The manager frees a failed nodelet's callback queues first: unregister everything now.
    if (calibration_) calibration_->stop();
    if (service_spinner_) service_spinner_->stop();
    recalibrate_srv_.shutdown();
    diagnostics_timer_.stop();
    window_timer_.stop();
    commit_retry_timer_.stop();
    const std::vector<ros::Subscriber*> subscribers = {&observations_sub_, &window_observations_sub_, &mode_sub_,
                                                       &left_info_sub_,   &right_info_sub_,          &health_sub_};
    for (ros::Subscriber* sub : subscribers) sub->shutdown();
  }

  void initialise() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const std::string package_path = ros::package::getPath("embedded_calibration_stereo");
    params_ = loadCalibratorParams(pnh, package_path.empty() ? "" : package_path + "/config/sim_rig.yaml");
    const core::DeviceDescription device = core::loadDeviceDescription(params_.device_config, "device_config");
    status_pub_ = nh.advertise<CalibrationStatus>("calibration/status", 1, /*latch=*/true);
    calibration_ = std::make_unique<OnlineCalibration>(
        getName(), params_, std::make_unique<CalibrationSession>(nh, params_, device.device, device.nominal),
        OnlineCalibration::Topics{nh.resolveName("calibration/observations"),
                                  nh.resolveName("calibration/window_observations"), nh.resolveName("calibration_mode")},
        [this](const CalibrationStatus& status) { status_pub_.publish(status); });
    guard_ = std::make_unique<StampGuard>(
        std::vector<std::string>{nh.resolveName("calibration_mode"), nh.resolveName("calibration/observations"),
                                 nh.resolveName("left/camera_info"), nh.resolveName("right/camera_info")},
        params_.stamp_tolerance_s, "OnlineCalibrator",
        [this](const std::string& text) { NODELET_WARN("%s", text.c_str()); });
    subscribe(nh);
    diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
    diagnostics_->setHardwareID("online_calibrator");
    diagnostics_->add("online_calibrator", [this](diagnostic_updater::DiagnosticStatusWrapper& status) {
      calibration_->diagnose(status, guard_->dropped());
    });
    diagnostics_timer_ =
        nh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) { diagnostics_->update(); });
    window_timer_ = nh.createWallTimer(ros::WallDuration(0.25),
                                       [this](const ros::WallTimerEvent&) { calibration_->endIdleWindow(); });
    if (params_.commit_retry_s > 0)
      commit_retry_timer_ = nh.createWallTimer(ros::WallDuration(params_.commit_retry_s),
                                               [this](const ros::WallTimerEvent&) { calibration_->scheduleCommitAgain(); });
    calibration_->start();
    ros::NodeHandle service_nh(nh);
    service_nh.setCallbackQueue(&service_queue_);
    recalibrate_srv_ = service_nh.advertiseService("calibration/recalibrate", &OnlineCalibratorNodelet::recalibrate, this);
    service_spinner_ = std::make_unique<ros::AsyncSpinner>(2, &service_queue_);  // see the class comment
    service_spinner_->start();
    const std::string automatic =
        !params_.auto_calibrate       ? "solving on request only"
        : params_.window_observations ? "solving every window observation on " + window_observations_sub_.getTopic()
                                      : std::string("solving every light-on window");
    NODELET_INFO("OnlineCalibrator: device from %s (%zu virtual boards), observations on %s, %s, commit to %s",
                 params_.device_config.c_str(), calibration_->session().boards().size(),
                 observations_sub_.getTopic().c_str(), automatic.c_str(),
                 params_.commit == CommitTarget::kDriver ? "the driver" : "none (tf_static only)");
  }

  // Inputs with stamps far from the others' are dropped (stamp_guard.h) before they reach the
  // calibration; a window observation arrives seconds after its burst and is not held to them.
  void subscribe(ros::NodeHandle& nh) {
    observations_sub_ = nh.subscribe<StereoPatternObservation>(
        "calibration/observations", 10, [this](const StereoPatternObservationConstPtr& msg) {
          if (guard_->admit(kObservationInput, msg->header.stamp)) calibration_->onObservation(*msg);
        });
    if (params_.window_observations)
      window_observations_sub_ = nh.subscribe("calibration/window_observations", 10,
                                              &OnlineCalibratorNodelet::onWindowObservation, this);
    mode_sub_ = nh.subscribe<CalibrationMode>("calibration_mode", 10, [this](const CalibrationModeConstPtr& mode) {
      if (guard_->admit(kModeInput, mode->header.stamp)) calibration_->onMode(*mode);
    });
    left_info_sub_ = nh.subscribe<sensor_msgs::CameraInfo>(
        "left/camera_info", 1, [this](const sensor_msgs::CameraInfoConstPtr& m) { storeInfo(true, m); });
    right_info_sub_ = nh.subscribe<sensor_msgs::CameraInfo>(
        "right/camera_info", 1, [this](const sensor_msgs::CameraInfoConstPtr& m) { storeInfo(false, m); });
    health_sub_ = nh.subscribe<CalibrationHealth>(
        "calibration/health", 10, [this](const CalibrationHealthConstPtr& h) { calibration_->onHealth(*h); });
    set_light_client_ = nh.serviceClient<std_srvs::SetBool>("set_light");  // exists() only: calls are bounded
  }

  // Not held to the other inputs' stamps: it arrives seconds after its burst.
  void onWindowObservation(const ros::MessageEvent<StereoPatternObservation const>& event) {
    calibration_->onWindowObservation(*event.getMessage(), event.getPublisherName());
  }

  void storeInfo(bool left, const sensor_msgs::CameraInfoConstPtr& info) {
    if (!guard_->admit(left ? kLeftInfoInput : kRightInfoInput, info->header.stamp)) return;
    calibration_->onCameraInfo(left, info, (left ? left_info_sub_ : right_info_sub_).getTopic(),
                               (left ? right_info_sub_ : left_info_sub_).getTopic());
  }

  // Service thread (see the class comment). Bounded: every driver service call, the window
  // (timeout_s), the solve; a caller that goes away ends it early; the light goes off on every
  // way out.
  bool recalibrate(ros::ServiceEvent<Recalibrate::Request, Recalibrate::Response>& event) {
    const Recalibrate::Request& req = event.getRequest();
    Recalibrate::Response& res = event.getResponse();
    const std::string caller = event.getCallerName();
    const BoundedRequest bounded = boundRecalibrateRequest(req.frames, req.timeout_s, params_);
    if (!bounded.refusal.empty()) {
      NODELET_WARN("OnlineCalibrator: recalibrate from %s %s", caller.c_str(), bounded.refusal.c_str());
      return answer(&res, false, bounded.refusal);
    }
    if (!bounded.note.empty())
      NODELET_WARN("OnlineCalibrator: recalibrate from %s: %s", caller.c_str(), bounded.note.c_str());
    const size_t frames = bounded.frames;
    const double timeout_s = bounded.timeout_s;
    // Every answer says what was limited.
    const auto noted = [&bounded](std::string message) {
      return bounded.note.empty() ? message : message + " (" + bounded.note + ")";
    };
    if (const std::string busy = calibration_->claimRequest(caller, frames); !busy.empty())
      return answer(&res, false, busy);
    struct InFlight {  // cleared on every return
      OnlineCalibration* calibration;
      ~InFlight() { calibration->requestDone(); }
    } in_flight{calibration_.get()};
    const CallerProbe probe(caller);
    std::string error;
    if (!setLight(true, &error)) {
      // The driver may have switched the light on all the same (an answer lost in a timeout, or
      // success=false after acting): switch it off, unless the service is not there at all.
      std::string message = "cannot switch the light on: " + error;
      std::string off_error;
      if (set_light_client_.exists() && !setLight(false, &off_error))
        message += "; switching it off failed too: " + off_error;
      NODELET_ERROR("OnlineCalibrator: recalibrate: %s", message.c_str());
      return answer(&res, false, noted(message + "; nothing solved or committed"));
    }
    std::vector<core::StereoObservation> window;
    const std::string abandoned = calibration_->collectRequestWindow(frames, timeout_s, probe, &window);
    // From here on the light goes off whatever happened: an early end, a shutdown, a timeout.
    if (!setLight(false, &error)) {
      // The head is not back in its normal state (the boards may still be over the scene):
      // nothing is committed on its behalf.
      const std::string message = (abandoned.empty() ? "" : abandoned + "; ") + "cannot switch the light off: " +
                                  error + "; nothing solved or committed";
      NODELET_ERROR("OnlineCalibrator: recalibrate: %s", message.c_str());
      return answer(&res, false, noted(message));
    }
    if (!abandoned.empty()) {
      const std::string message = abandoned + ": light switched off, nothing solved or committed";
      NODELET_WARN("OnlineCalibrator: recalibrate: %s", message.c_str());
      return answer(&res, false, noted(message));
    }
    if (window.size() < frames) {
      char text[160];
      if (window.empty())
        snprintf(text, sizeof(text), "timeout: no boards seen in %.1f s with the light on", timeout_s);
      else
        snprintf(text, sizeof(text), "timeout: only %zu of %zu frames with boards in %.1f s", window.size(),
                 frames, timeout_s);
      return answer(&res, false, noted(text));
    }
    const bool window_observation = params_.window_observations && calibration_->takeTheBurstsWindowObservation(&window);
    res.status = calibration_->solveRequest(std::move(window), req.dry_run, window_observation);
    // A solve that fits no better than the calibration in force confirms it: nothing to change.
    res.success = core::requestSucceeded(static_cast<core::CalibrationOutcome>(res.status.outcome));
    res.message = noted(recalibrateMessage(res.status));
    return true;
  }

  bool answer(Recalibrate::Response* res, bool success, const std::string& message) {
    res->success = success;
    res->message = message;
    res->status = statusWithoutSolve(message, calibration_->epoch());
    return true;
  }

  // Bounded: service_timeout_s for set_light to appear, as much for its answer.
  bool setLight(bool on, std::string* error) {
    std_srvs::SetBool srv;
    srv.request.data = on;
    if (!callService(getNodeHandle(), "set_light", &srv, params_.service_timeout_s, error)) return false;
    if (!srv.response.success) {
      *error = set_light_client_.getService() + " refused: " + srv.response.message;
      return false;
    }
    return true;
  }

  // guard_'s inputs.
  static constexpr size_t kModeInput = 0, kObservationInput = 1, kLeftInfoInput = 2, kRightInfoInput = 3;

  CalibratorParams params_;
  std::unique_ptr<OnlineCalibration> calibration_;  // thread-safe
  ros::Publisher status_pub_;
  ros::Subscriber observations_sub_, window_observations_sub_, mode_sub_, left_info_sub_, right_info_sub_, health_sub_;
  ros::ServiceServer recalibrate_srv_;
  ros::CallbackQueue service_queue_;  // calibration/recalibrate only (see the class comment)
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;
  ros::ServiceClient set_light_client_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::WallTimer diagnostics_timer_, window_timer_, commit_retry_timer_;
  std::unique_ptr<StampGuard> guard_;
};

}  // namespace embedded_calibration_stereo

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo::OnlineCalibratorNodelet, nodelet::Nodelet)
