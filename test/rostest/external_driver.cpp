// rostest (external_driver.test): the head run by a camera driver we did not write.
//
// The test renders 18 s of the simulated head into two lossless videos (render_sim_video: light
// windows whose switches fall inside exposures, so some frames are partly lit; the scene covered
// during the first light window; a 5 % zoom at 9.5 s), starts launch/external_driver.launch
// (LightController with no light backend, calibration_store file) and loads two of Debian's
// image_publisher nodelets into its manager, one per video. image_publisher reads its
// calibration from camera_info_url but cannot store one (its camera_info_manager lives only
// inside its reconfigure callback), so the LightController writes each committed calibration to
// that file and makes image_publisher reload it through its dynamic_reconfigure camera_info_url.
//
// Every image the graph receives is identified by its hash in the tool's frames.csv (the videos
// decode bit-exactly), which gives its true exposure. Checked:
//  - every settled calibration_mode has both images fully lit or fully dark, as it says, and the
//    partly lit frames did reach the LightController (marked unsettled);
//  - the tracker's observations come from fully lit frames only;
//  - the Separator, taught on covered-scene frames through its teach service, recovers the true
//    scene from later light-on frames;
//  - after the zoom the calibrator commits a calibration that image_publisher then publishes, close
//    to the truth, and calibration_mode's epoch moves on by two;
//  - rectifier and disparity deliver disparities;
//  - a recalibration with nothing drifted answers success, "calibration in force confirmed", and
//    one without boards answers false with the reason.
#include <gtest/gtest.h>
#include <nodelet/NodeletLoad.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/Trigger.h>
#include <stereo_msgs/DisparityImage.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <mutex>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <unordered_map>

#include "child_launch.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/ros/calibration_file.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::Recalibrate;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;

namespace {

constexpr double kFps = 15.0;
// Video timeline (s). Switches at x.5 s or x.02 s fall inside a 0.6-period exposure.
const char* kLight = "1.5:5.5,7.02:8.5,11.02:12.5,14.5:16.02";
const char* kCover = "1.0:4.0";
const double kZoomAt = 9.5, kZoom = 1.05, kSeconds = 18.0;
const double kSecondWindow[2] = {7.02, 8.5};  // uncovered, before the zoom: separation is judged here

struct FrameTruth {
  double time_s = 0, light = 0, focal_scale = 1;
  bool covered = false;
};

struct Truth {
  std::vector<FrameTruth> frames;
  std::unordered_map<uint64_t, int> index[2];  // image hash -> frame, per camera
};

Truth readFrames(const std::string& path) {
  Truth truth;
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::stringstream row(line);
    std::string field[7];
    for (auto& f : field) std::getline(row, f, ',');
    FrameTruth f;
    const int k = std::stoi(field[0]);
    f.time_s = std::stod(field[1]);
    f.light = std::stod(field[4]);
    f.covered = field[5] == "1";
    f.focal_scale = std::stod(field[6]);
    truth.index[0][std::stoull(field[2], nullptr, 16)] = k;
    truth.index[1][std::stoull(field[3], nullptr, 16)] = k;
    truth.frames.push_back(f);
  }
  return truth;
}

uint64_t fnv1a(const std::vector<uint8_t>& data) {
  uint64_t hash = 1469598103934665603ull;
  for (uint8_t byte : data) {
    hash ^= byte;
    hash *= 1099511628211ull;
  }
  return hash;
}

double meanAbsDiff(const sensor_msgs::Image& msg, const cv::Mat& reference) {
  const cv::Mat bgr(msg.height, msg.width, CV_8UC3, const_cast<uint8_t*>(msg.data.data()), msg.step);
  cv::Mat grey, diff;
  cv::cvtColor(bgr, grey, cv::COLOR_BGR2GRAY);
  cv::absdiff(grey, reference, diff);
  return cv::mean(diff)[0];
}

// What the graph published, by stamp; filled on the spinner threads.
class Recorder {
 public:
  Recorder(ros::NodeHandle& nh, const Truth& truth, cv::Mat scene) : truth_(truth), scene_(std::move(scene)) {
    subs_.push_back(nh.subscribe<sensor_msgs::Image>("left/image_raw", 30, [this](const auto& m) { image(0, m); }));
    subs_.push_back(nh.subscribe<sensor_msgs::Image>("right/image_raw", 30, [this](const auto& m) { image(1, m); }));
    subs_.push_back(nh.subscribe<sensor_msgs::Image>("left/image_scene", 30, [this](const sensor_msgs::ImageConstPtr& m) {
      const double error = meanAbsDiff(*m, scene_);
      std::lock_guard<std::mutex> lock(mutex_);
      scene_error_[m->header.stamp] = error;
    }));
    subs_.push_back(nh.subscribe<stereo_msgs::DisparityImage>("disparity", 10, [this](const auto& m) {
      const cv::Mat d(m->image.height, m->image.width, CV_32F, const_cast<uint8_t*>(m->image.data.data()), m->image.step);
      const double valid = cv::countNonZero(d >= m->min_disparity) / static_cast<double>(d.total());
      std::lock_guard<std::mutex> lock(mutex_);
      disparity_valid_.push_back(valid);
    }));
  }
  ~Recorder() {
    for (auto& s : subs_) s.shutdown();
  }

  // Frame index of each camera's image of this stamp (-1: not received, -2: unknown image).
  std::pair<int, int> frames(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto get = [&](int c) {
      const auto it = frame_[c].find(stamp);
      return it == frame_[c].end() ? -1 : it->second;
    };
    return {get(0), get(1)};
  }
  std::map<ros::Time, double> rawErrors() {
    std::lock_guard<std::mutex> lock(mutex_);
    return raw_error_;
  }
  std::map<ros::Time, double> sceneErrors() {
    std::lock_guard<std::mutex> lock(mutex_);
    return scene_error_;
  }
  std::vector<double> disparityValid() {
    std::lock_guard<std::mutex> lock(mutex_);
    return disparity_valid_;
  }

 private:
  void image(int camera, const sensor_msgs::ImageConstPtr& m) {
    const auto it = truth_.index[camera].find(fnv1a(m->data));
    const int k = it == truth_.index[camera].end() ? -2 : it->second;
    double error = -1;
    if (camera == 0 && m->encoding == "bgr8") error = meanAbsDiff(*m, scene_);
    std::lock_guard<std::mutex> lock(mutex_);
    frame_[camera][m->header.stamp] = k;
    if (error >= 0) raw_error_[m->header.stamp] = error;
  }

  const Truth& truth_;
  const cv::Mat scene_;
  std::vector<ros::Subscriber> subs_;
  std::mutex mutex_;
  std::map<ros::Time, int> frame_[2];
  std::map<ros::Time, double> raw_error_, scene_error_;
  std::vector<double> disparity_valid_;
};

// 1. The videos and their truth, rendered into `dir`.
void renderVideos(const std::string& dir, Truth* truth, cv::Mat* scene) {
  char command[2048];
  std::snprintf(command, sizeof(command),
                "'%s' --config '%s/config/sim_rig.yaml' --out '%s' --seconds %g --fps %g --light %s --cover %s "
                "--zoom %g:%g",
                ECS_RENDER_SIM_VIDEO, ECS_SOURCE_DIR, dir.c_str(), kSeconds, kFps, kLight, kCover, kZoomAt, kZoom);
  const auto render_start = ros::WallTime::now();
  ASSERT_EQ(std::system(command), 0) << command;
  std::printf("videos rendered in %.1f s\n", (ros::WallTime::now() - render_start).toSec());
  *truth = readFrames(dir + "/frames.csv");
  ASSERT_EQ(truth->frames.size(), static_cast<size_t>(std::lround(kSeconds * kFps)));
  *scene = cv::imread(dir + "/left_scene.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(scene->empty());
  int partly_lit = 0;
  for (const FrameTruth& f : truth->frames) partly_lit += f.light > 0 && f.light < 1;
  ASSERT_GE(partly_lit, 5) << "the timeline should switch the light during exposures";
}

// 3. The driver we did not write: two image_publisher nodelets in the head's manager, loaded
//    back to back so that their frames start together.
void loadImagePublishers(const std::string& dir, const std::string& left_url, const std::string& right_url,
                         test_support::ChildLaunch& head) {
  const std::string load = "/stereo/stereo_manager/load_nodelet";
  ASSERT_TRUE(ros::service::waitForService(load, ros::Duration(30.0))) << head.logTail();
  ASSERT_TRUE(ros::service::waitForService("/stereo/set_light", ros::Duration(30.0))) << head.logTail();
  for (const std::string side : {"left", "right"}) {
    const std::string name = "/stereo/" + side + "_camera";
    ros::param::set(name + "/filename", dir + "/" + side + ".avi");
    ros::param::set(name + "/publish_rate", kFps);
    ros::param::set(name + "/camera_info_url", side == "left" ? left_url : right_url);
    ros::param::set(name + "/frame_id", std::string("stereo_left_optical_frame"));
  }
  for (const std::string side : {"left", "right"}) {
    nodelet::NodeletLoad srv;
    srv.request.name = "/stereo/" + side + "_camera";
    srv.request.type = "image_publisher/image_publisher";
    ASSERT_TRUE(ros::service::call(load, srv) && srv.response.success) << side << "\n" << head.logTail();
  }
}

// 5. After the zoom a calibration is committed and image_publisher publishes it; calibration_mode's
//    epoch follows the commits.
void expectCommitPublished(const std::string& dir, Collector<CalibrationStatus>& statuses,
                           Collector<sensor_msgs::CameraInfo>& left_infos, Collector<CalibrationMode>& modes,
                           test_support::ChildLaunch& head) {
  ASSERT_TRUE(statuses.waitFor(
      [](const std::vector<CalibrationStatus::ConstPtr>& s) {
        for (const auto& status : s)
          if (status->accepted) return true;
        return false;
      },
      40.0))
      << head.logTail(60);
  sensor_msgs::CameraInfo truth_left;
  std::string name, error;
  ASSERT_TRUE(embedded_calibration_stereo::readCalibrationFile(dir + "/truth_left.yaml", &name, &truth_left, &error))
      << error;
  ASSERT_TRUE(left_infos.waitFor(
      [&](const std::vector<sensor_msgs::CameraInfo::ConstPtr>& infos) {
        return !infos.empty() && std::abs(infos.back()->K[0] / truth_left.K[0] - 1.0) < 0.01;
      },
      10.0))
      << "image_publisher does not publish the committed calibration";
  const sensor_msgs::CameraInfo committed = *left_infos.snapshot().back();
  std::printf("committed fx %.3f, truth %.3f (%.4f %%); cx %.3f, truth %.3f\n", committed.K[0], truth_left.K[0],
              100 * (committed.K[0] / truth_left.K[0] - 1), committed.K[2], truth_left.K[2]);
  EXPECT_LT(std::abs(committed.K[0] / truth_left.K[0] - 1.0), 0.002);
  EXPECT_LT(std::abs(committed.K[4] / truth_left.K[4] - 1.0), 0.002);
  EXPECT_LT(std::abs(committed.K[2] - truth_left.K[2]), 1.5);
  EXPECT_LT(std::abs(committed.K[5] - truth_left.K[5]), 1.5);
  // Each commit changes both camera_infos: the epoch moves on by two per accepted status.
  const auto accepted = [&] {
    int n = 0;
    for (const auto& status : statuses.snapshot()) n += status->accepted;
    return n;
  };
  ASSERT_TRUE(modes.waitFor(
      [&](const auto& m) { return !m.empty() && m.back()->calibration_epoch == 2u * accepted(); }, 5.0))
      << "calibration_mode's epoch " << modes.snapshot().back()->calibration_epoch << " after " << accepted()
      << " commits\n" << head.logTail(60);
}

// 8. Every settled frame was fully lit or fully dark, as calibration_mode said.
void expectSettledFramesTrue(const std::vector<CalibrationMode::ConstPtr>& modes, Recorder& recorder,
                             const Truth& truth) {
  int settled = 0, settled_on = 0, unsettled_partial = 0, unknown = 0;
  for (const auto& mode : modes) {
    const auto [l, r] = recorder.frames(mode->header.stamp);
    if (l == -1 || r == -1) continue;  // images not received by this test (its queues are finite)
    if (l == -2 || r == -2) {
      ++unknown;
      continue;
    }
    const FrameTruth &fl = truth.frames[l], &fr = truth.frames[r];
    const bool partial = (fl.light > 0 && fl.light < 1) || (fr.light > 0 && fr.light < 1);
    if (!mode->settled) {
      unsettled_partial += partial;
      continue;
    }
    ++settled;
    settled_on += mode->light_on;
    EXPECT_FALSE(partial) << "frames " << l << "/" << r << " were exposed while the light switched, but settled";
    EXPECT_EQ(fl.light, fr.light) << "frames " << l << "/" << r;
    EXPECT_EQ(mode->light_on, fl.light == 1.0) << "frames " << l << "/" << r;
  }
  std::printf("calibration_mode: %d settled frames checked (%d light-on), %d partly lit frames marked unsettled\n",
              settled, settled_on, unsettled_partial);
  EXPECT_EQ(unknown, 0) << "images not in the videos";
  // The test's own subscriptions may drop images under load: a good share of the run, both states.
  EXPECT_GE(settled, 80);
  EXPECT_GE(settled_on, 20);
  EXPECT_GE(settled - settled_on, 40);
  EXPECT_GE(unsettled_partial, 3) << "the partly lit frames must reach the LightController";
}

// 9. Observations only from fully lit frames.
void expectObservationsLit(const std::vector<StereoPatternObservation::ConstPtr>& observations, Recorder& recorder,
                           const Truth& truth) {
  int observed = 0;
  for (const auto& o : observations) {
    const auto [l, r] = recorder.frames(o->header.stamp);
    if (l < 0 || r < 0) continue;
    ++observed;
    EXPECT_EQ(truth.frames[l].light, 1.0) << "observation from frame " << l;
    EXPECT_EQ(truth.frames[r].light, 1.0) << "observation from frame " << r;
  }
  EXPECT_GE(observed, 20);
}

// 10. Separation of the second light window against the true scene.
void expectSeparated(const std::vector<CalibrationMode::ConstPtr>& modes, Recorder& recorder, const Truth& truth) {
  const auto raw = recorder.rawErrors();
  const auto separated = recorder.sceneErrors();
  int judged = 0;
  for (const auto& mode : modes) {
    const auto [l, r] = recorder.frames(mode->header.stamp);
    if (!mode->settled || !mode->light_on || l < 0) continue;
    const double t = truth.frames[l].time_s;
    if (t < kSecondWindow[0] || t > kSecondWindow[1]) continue;
    const auto s = separated.find(mode->header.stamp), e = raw.find(mode->header.stamp);
    if (s == separated.end() || e == raw.end()) continue;
    if (judged++ == 0) std::printf("separated scene: mean |error| %.2f grey levels (raw frame %.2f)\n", s->second, e->second);
    EXPECT_LT(s->second, 0.2 * e->second) << "frame " << l;
  }
  EXPECT_GE(judged, 5);
}

// 6. Nothing drifted since: the next window confirms the calibration in force. 7. A real failure:
//    no boards while the videos' light is off.
void expectConfirmedThenNoBoards(Collector<CalibrationMode>& modes, Recorder& recorder, const Truth& truth) {
  Recalibrate recalibrate;
  ASSERT_TRUE(test_support::recalibrate(5, 8.0, "with nothing drifted", &recalibrate));
  EXPECT_TRUE(recalibrate.response.success) << recalibrate.response.message;
  EXPECT_NE(recalibrate.response.message.find("calibration in force confirmed"), std::string::npos)
      << recalibrate.response.message;

  // 7. A real failure: no boards while the videos' light is off.
  const size_t seen = modes.snapshot().size();
  ASSERT_TRUE(modes.waitFor(
      [&](const std::vector<CalibrationMode::ConstPtr>& m) {
        for (size_t i = seen; i < m.size(); ++i) {
          const auto [l, r] = recorder.frames(m[i]->header.stamp);
          if (m[i]->settled && !m[i]->light_on && l >= 0 && truth.frames[l].time_s > 16.2) return true;
        }
        return false;
      },
      10.0));
  Recalibrate no_boards;
  no_boards.request.frames = 5;
  no_boards.request.timeout_s = 1.0;
  ASSERT_TRUE(test_support::callService("/stereo/calibration/recalibrate", &no_boards));
  EXPECT_FALSE(no_boards.response.success);
  EXPECT_NE(no_boards.response.message.find("no boards seen"), std::string::npos) << no_boards.response.message;
}

}  // namespace

TEST(ExternalDriver, ImagePublisherRunsTheHead) {
  ros::NodeHandle nh;
  test_support::TempDir dir("ecs_external_driver");
  ASSERT_FALSE(dir.path.empty());

  // 1. The videos and their truth.
  Truth truth;
  cv::Mat scene;
  renderVideos(dir.path, &truth, &scene);
  if (HasFatalFailure()) return;

  // 2. The head's graph without our driver.
  const std::string left_url = "file://" + dir.path + "/left.yaml", right_url = "file://" + dir.path + "/right.yaml";
  test_support::ChildLaunch head({"embedded_calibration_stereo", "external_driver.launch", "light_backend:=none",
                              "calibration_period_s:=0", "driver_left_image:=left_camera/image_raw",
                              "driver_left_info:=left_camera/camera_info", "driver_right_image:=right_camera/image_raw",
                              "driver_right_info:=right_camera/camera_info", "calibration_store:=file",
                              "left_camera_info_url:=" + left_url, "right_camera_info_url:=" + right_url,
                              "left_reload_service:=/stereo/left_camera/set_parameters",
                              "right_reload_service:=/stereo/right_camera/set_parameters",
                              "prior_file:=" + dir.path + "/prior.yaml",
                              // The first window already commits (epoch 2) before the judged window,
                              // which comes before the zoom: the taught device image still holds.
                              "device_template:=teach", "reteach_on_epoch_change:=false"},
                             dir.path + "/head.log");
  ASSERT_TRUE(head.started());

  Collector<CalibrationMode> modes(nh, "calibration_mode", 1000);
  Collector<StereoPatternObservation> observations(nh, "calibration/observations", 1000);
  Collector<CalibrationStatus> statuses(nh, "calibration/status", 50);
  Collector<sensor_msgs::CameraInfo> left_infos(nh, "left/camera_info", 1000);
  Recorder recorder(nh, truth, scene);

  loadImagePublishers(dir.path, left_url, right_url, head);
  if (HasFatalFailure()) return;

  // 4. Teach the Separator on the covered scene with the light on.
  ASSERT_TRUE(modes.waitFor(
      [&](const std::vector<CalibrationMode::ConstPtr>& m) {
        for (const auto& mode : m) {
          if (!mode->settled || !mode->light_on) continue;
          const auto [l, r] = recorder.frames(mode->header.stamp);
          if (l >= 0 && truth.frames[l].covered) return true;
        }
        return false;
      },
      30.0))
      << "no settled light-on frame of the covered scene\n" << head.logTail();
  std_srvs::Trigger teach;
  ASSERT_TRUE(test_support::callService("/stereo/separator/teach", &teach) && teach.response.success) << teach.response.message;

  expectCommitPublished(dir.path, statuses, left_infos, modes, head);
  if (HasFatalFailure()) return;

  expectConfirmedThenNoBoards(modes, recorder, truth);
  if (HasFatalFailure()) return;
  head.stop(20.0);

  expectSettledFramesTrue(modes.snapshot(), recorder, truth);
  expectObservationsLit(observations.snapshot(), recorder, truth);
  expectSeparated(modes.snapshot(), recorder, truth);

  // 11. Depth kept coming.
  const std::vector<double> valid = recorder.disparityValid();
  EXPECT_GE(valid.size(), 60u);
  int good = 0;
  for (double v : valid) good += v > 0.5;
  EXPECT_GE(good, static_cast<int>(valid.size() * 0.8)) << "disparities with more than half the pixels valid";
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "external_driver_test");
  ros::AsyncSpinner spinner(4);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  spinner.stop();
  ros::shutdown();
  return result;
}
