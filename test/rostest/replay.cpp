// rostest: a bag recorded with launch/record.launch, replayed with launch/replay.launch (no
// driver, use_sim_time), reproduces the recorded calibration epochs.
//
// Two launch phases on the rostest's master, both started by this node (ChildLaunch):
//  1. the simulated head (driver + tracker + calibrator, a light window every 4 s). The tracker
//     teaches itself at the second window; the calibrator solves from the third. Once that
//     first solve is announced and the light is off, record.launch starts, a drift (5 % zoom,
//     0.3 deg right rotation, as scripts/demo) is applied, and three more windows are solved and
//     recorded. The recorder stops first (bag closed), then the head.
//  2. replay.launch on the bag, with the prior the tracker taught in phase 1 (so the replay
//     tracks every window of the bag as the live tracker did).
// The replayed statuses are compared with the bag's, epoch by epoch: same count (no window lost
// or added), same gate decision, and every parameter within 1 reported standard deviation of the
// recorded one ("within the reported standard deviations", taken literally). Why 1 sd is not
// too tight: both runs solve the same frames of the same images, so they agree far closer than
// that (not bit-exact: the live tracker had tracked the window before the bag); a frame lost by
// a starved subscriber queue in either run moves an estimate from n frames by about sd/sqrt(n).
// Why it can fail: another calibrator configuration, another window or a truncated bag changes
// the frames or the epochs (a replay with max_frames:=6 fails on frames_used and on a
// parameter). The bag's statuses are also checked against the ones received live, and the
// replay's Disparity must keep up with the bag.
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <rosgraph_msgs/Clock.h>
#include <stereo_msgs/DisparityImage.h>
#include <tf2/LinearMath/Quaternion.h>
#include <tf2_msgs/TFMessage.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "child_launch.h"
#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/ros/calibration_session.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using test_support::ChildLaunch;
using test_support::Collector;
using test_support::waitUntil;

namespace {

constexpr double kPeriodS = 4.0;            // driver: a light window every 4 s
constexpr size_t kRecordedWindows = 3;      // solved windows in the bag
constexpr double kToleranceSd = 1.0;        // see the file comment
// Both runs solve each window alone: the bag starts after the first solve, which would have
// taught the recorded calibrator what the replay's cannot know.
const std::string kEachWindowAlone = "prior_from_earlier_windows:=false";
const std::string kRightFrame = "stereo_right_optical_frame";

std::string launchFile(const std::string& name) { return std::string(ECS_SOURCE_DIR) + "/launch/" + name; }

// True when a node whose name starts with `prefix` subscribes to every topic of `topics`.
bool subscribedBy(const std::string& prefix, const std::vector<std::string>& topics) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  if (!ros::master::execute("getSystemState", args, result, payload, false)) return false;
  size_t found = 0;
  XmlRpc::XmlRpcValue& subscribers = payload[1];
  for (int i = 0; i < subscribers.size(); ++i) {
    const std::string topic = subscribers[i][0];
    if (std::find(topics.begin(), topics.end(), topic) == topics.end()) continue;
    for (int j = 0; j < subscribers[i][1].size(); ++j)
      if (std::string(subscribers[i][1][j]).rfind(prefix, 0) == 0) {
        ++found;
        break;
      }
  }
  return found == topics.size();
}


size_t lightOnFrames(const std::vector<CalibrationMode::ConstPtr>& modes) {
  return static_cast<size_t>(std::count_if(modes.begin(), modes.end(), [](const auto& m) { return m->light_on; }));
}

struct Worst {
  double sd_units = 0.0;
  std::string what;
};

// |replayed - recorded| <= kToleranceSd * sd for one parameter; `worst` keeps the largest ratio.
void expectWithinSd(const std::string& what, double recorded, double replayed, double sd, Worst* worst) {
  const double diff = std::abs(replayed - recorded);
  // A parameter held fixed by the solver reports sd 0: then it must not move at all.
  const double bound = std::max(kToleranceSd * sd, 1e-9 * std::abs(recorded) + 1e-12);
  EXPECT_LE(diff, bound) << what << ": recorded " << recorded << ", replayed " << replayed << ", sd " << sd;
  const double ratio = sd > 0.0 ? diff / sd : 0.0;
  if (ratio >= worst->sd_units) *worst = Worst{ratio, what};
}

void expectSameParameters(size_t epoch, const CalibrationStatus& rec, const CalibrationStatus& rep, Worst* worst) {
  const std::string tag = "epoch " + std::to_string(epoch) + " ";
  ASSERT_EQ(rec.left_intrinsics.size(), rep.left_intrinsics.size()) << tag;
  ASSERT_EQ(rec.right_intrinsics.size(), rep.right_intrinsics.size()) << tag;
  ASSERT_EQ(rec.left_intrinsics.size(), rec.left_intrinsics_stddev.size()) << tag;
  ASSERT_EQ(rec.right_intrinsics.size(), rec.right_intrinsics_stddev.size()) << tag;
  for (size_t j = 0; j < rec.left_intrinsics.size(); ++j)
    expectWithinSd(tag + "left[" + std::to_string(j) + "]", rec.left_intrinsics[j], rep.left_intrinsics[j],
                   rec.left_intrinsics_stddev[j], worst);
  for (size_t j = 0; j < rec.right_intrinsics.size(); ++j)
    expectWithinSd(tag + "right[" + std::to_string(j) + "]", rec.right_intrinsics[j], rep.right_intrinsics[j],
                   rec.right_intrinsics_stddev[j], worst);
  expectWithinSd(tag + "baseline", rec.baseline_m, rep.baseline_m, rec.baseline_stddev_m, worst);
}

// The left->right rotation of the last transform to kRightFrame in `messages`.
bool lastRightRotation(const std::vector<tf2_msgs::TFMessage::ConstPtr>& messages, tf2::Quaternion* q) {
  bool found = false;
  for (const auto& m : messages)
    for (const auto& t : m->transforms)
      if (t.child_frame_id == kRightFrame) {
        const auto& r = t.transform.rotation;
        *q = tf2::Quaternion(r.x, r.y, r.z, r.w);
        found = true;
      }
  return found;
}

// Phase 1: the live head, recorded into `bag_path`: the statuses published while recording to
// *live_recorded, the stamp of the last status before it to *record_start_stamp.
void recordLiveHead(const std::string& dir, const std::string& bag_path, const std::string& prior_file,
                    std::vector<CalibrationStatus::ConstPtr>* live_recorded, ros::Time* record_start_stamp) {
  ros::NodeHandle nh;
  Collector<CalibrationMode> modes(nh, "calibration_mode", 2000);
  Collector<CalibrationStatus> live(nh, "calibration/status");
  ChildLaunch head({launchFile("driver.launch"), launchFile("tracker.launch"), launchFile("calibrator.launch"),
                    "calibration_period_s:=" + std::to_string(kPeriodS), "calibration_frames:=10",
                    "left_camera_info_url:=file://" + dir + "/left.yaml",
                    "right_camera_info_url:=file://" + dir + "/right.yaml", "prior_file:=" + prior_file,
                    kEachWindowAlone},
                   dir + "/head.log");
  ASSERT_TRUE(head.started());
  // Windows at 0 s (no light-off frame yet to teach with), 4 s (teaching), 8 s: first solve.
  ASSERT_TRUE(live.waitForCount(1, 3 * kPeriodS + 25.0)) << "no calibration/status\n" << head.logTail();
  ASSERT_TRUE(std::filesystem::exists(prior_file)) << "the tracker did not write its prior\n" << head.logTail();
  *record_start_stamp = live.snapshot().back()->header.stamp;
  // The status comes after the window's light-off: start recording in the dark gap, so that
  // the bag holds whole windows only.
  ASSERT_TRUE(modes.waitFor([](const auto& m) { return !m.empty() && !m.back()->light_on; }, 2.0));
  const size_t light_on_before = lightOnFrames(modes.snapshot());

  ChildLaunch recorder({launchFile("record.launch"), "bag:=" + bag_path}, dir + "/record.log");
  ASSERT_TRUE(recorder.started());
  ASSERT_TRUE(waitUntil(
      [] {
        return subscribedBy("/record", {"/stereo/left/image_raw", "/stereo/right/image_raw",
                                        "/stereo/left/camera_info", "/stereo/right/camera_info",
                                        "/stereo/calibration_mode", "/stereo/calibration/status", "/tf_static"});
      },
      15.0))
      << recorder.logTail();
  ASSERT_EQ(lightOnFrames(modes.snapshot()), light_on_before)
      << "the recorder subscribed only after the next light window had started";

  // Drift the rig so that the recorded epochs change the calibration.
  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.05;
  drift.request.right_rotation_deg = {0.0, 0.3, 0.0};
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;

  ASSERT_TRUE(live.waitForCount(1 + kRecordedWindows, kRecordedWindows * kPeriodS + 15.0)) << head.logTail();
  // A third of a second more of frames: the recorder has received the last status by then.
  const size_t frames_now = modes.snapshot().size();
  ASSERT_TRUE(modes.waitForCount(frames_now + 10, 5.0));
  EXPECT_TRUE(recorder.stop(20.0)) << "record.launch did not stop in time\n" << recorder.logTail();
  EXPECT_TRUE(head.stop(20.0)) << "the head did not stop in time";
  const auto all_live = live.snapshot();
  live_recorded->assign(all_live.begin() + 1, all_live.end());
}

// What the recorded bag holds: the statuses of its windows (not the one latched before the
// recording), /tf_static, and how many images and calibration_mode messages.
struct BagContents {
  std::vector<CalibrationStatus::ConstPtr> statuses;
  std::vector<tf2_msgs::TFMessage::ConstPtr> tf;
  size_t left_images = 0, modes = 0;
  ros::Time end;
};

BagContents readBag(const std::string& bag_path, const ros::Time& record_start_stamp) {
  BagContents contents;
  BagContents* out = &contents;
  rosbag::Bag bag(bag_path, rosbag::bagmode::Read);
  rosbag::View view(bag);
  out->end = view.getEndTime();
  out->left_images = rosbag::View(bag, rosbag::TopicQuery("/stereo/left/image_raw")).size();
  out->modes = rosbag::View(bag, rosbag::TopicQuery("/stereo/calibration_mode")).size();
  for (const rosbag::MessageInstance& m :
       rosbag::View(bag, rosbag::TopicQuery(std::vector<std::string>{"/stereo/calibration/status", "/tf_static"}))) {
    if (m.getTopic() == "/stereo/calibration/status") {
      // The status latched before the recorder started is in the bag too; its window is not.
      const auto status = m.instantiate<CalibrationStatus>();
      if (status && status->header.stamp > record_start_stamp) out->statuses.push_back(status);
    } else if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) {
      out->tf.push_back(tf);
    }
  }
  std::printf("bag: %.1f s, %zu left images, %zu calibration_mode, %zu statuses of its windows, %.0f MB\n",
              (view.getEndTime() - view.getBeginTime()).toSec(), out->left_images, out->modes, out->statuses.size(),
              std::filesystem::file_size(bag_path) / 1e6);
  return contents;
}

// Each replayed epoch against the recorded one: the gate's decision, the epoch, the frames and
// the parameters within their standard deviations.
void expectEpochsReproduced(const std::vector<CalibrationStatus::ConstPtr>& recorded,
                            const std::vector<CalibrationStatus::ConstPtr>& replay_statuses) {
  Worst worst;
  for (size_t i = 0; i < recorded.size(); ++i) {
    const CalibrationStatus& rec = *recorded[i];
    const CalibrationStatus& rep = *replay_statuses[i];
    std::printf("epoch %zu: recorded %s (%s, epoch %u, %u frames, rms %.4f/%.4f px, fx %.3f +- %.3f), replay %s "
                "(%s, epoch %u, %u frames, rms %.4f/%.4f px, fx %.3f)\n",
                i, rec.accepted ? "accepted" : "rejected", rec.reason.c_str(), rec.epoch, rec.frames_used,
                rec.rms_left_px, rec.rms_right_px, rec.left_intrinsics.empty() ? 0.0 : rec.left_intrinsics[0],
                rec.left_intrinsics_stddev.empty() ? 0.0 : rec.left_intrinsics_stddev[0],
                rep.accepted ? "accepted" : "rejected", rep.reason.c_str(), rep.epoch, rep.frames_used,
                rep.rms_left_px, rep.rms_right_px, rep.left_intrinsics.empty() ? 0.0 : rep.left_intrinsics[0]);
    ASSERT_EQ(rep.accepted, rec.accepted) << "epoch " << i << ": the gate decided otherwise (" << rep.reason << ")";
    if (rec.accepted) {
      // Accepted, committed nowhere: the epoch in force stays the one the driver had (2 below
      // the recorded one, which counts the driver's two set_camera_info).
      EXPECT_EQ(rep.reason, embedded_calibration_stereo::kAcceptedNotCommittedReason);
      EXPECT_EQ(rep.epoch + 2, rec.epoch);
    } else {
      EXPECT_EQ(rep.epoch, rec.epoch);
    }
    // A frame lost by a starved queue in either run is tolerated (see the file comment).
    EXPECT_LE(std::abs(static_cast<int>(rep.frames_used) - static_cast<int>(rec.frames_used)), 1) << "epoch " << i;
    expectSameParameters(i, rec, rep, &worst);
  }
  std::printf("largest replay - recorded difference: %.3g sd (%s)\n", worst.sd_units, worst.what.c_str());
}

}  // namespace

TEST(Replay, ReproducesTheRecordedCalibrationEpochs) {
  ros::NodeHandle nh;
  test_support::TempDir dir("ecs_replay_test");
  ASSERT_FALSE(dir.path.empty());
  const std::string bag_path = dir.path + "/run.bag";
  const std::string prior_file = dir.path + "/pattern_prior.yaml";

  // ---- Phase 1: the live head, recorded --------------------------------------------------
  std::vector<CalibrationStatus::ConstPtr> live_recorded;  // statuses published while recording
  ros::Time record_start_stamp;                            // stamp of the last status before it
  recordLiveHead(dir.path, bag_path, prior_file, &live_recorded, &record_start_stamp);
  if (HasFatalFailure()) return;

  // ---- The bag: the statuses published while recording, whole windows --------------------
  ASSERT_TRUE(std::filesystem::exists(bag_path)) << "no bag (still .active?)";
  const BagContents contents = readBag(bag_path, record_start_stamp);
  const std::vector<CalibrationStatus::ConstPtr>& recorded = contents.statuses;
  const size_t left_images = contents.left_images, modes_in_bag = contents.modes;
  const ros::Time bag_end = contents.end;
  ASSERT_EQ(recorded.size(), live_recorded.size()) << "the bag lost or gained statuses";
  for (size_t i = 0; i < recorded.size(); ++i) {
    EXPECT_EQ(recorded[i]->accepted, live_recorded[i]->accepted);
    EXPECT_EQ(recorded[i]->left_intrinsics, live_recorded[i]->left_intrinsics);
  }
  EXPECT_GE(left_images + 5, modes_in_bag) << "the recorder dropped images";
  const size_t accepted_count = static_cast<size_t>(
      std::count_if(recorded.begin(), recorded.end(), [](const auto& s) { return s->accepted; }));
  ASSERT_GE(accepted_count, 1u) << "no recorded epoch changed the calibration: the comparison would be vacuous";

  // ---- Phase 2: the replay ----------------------------------------------------------------
  Collector<CalibrationStatus> replayed(nh, "calibration/status");
  Collector<CalibrationStatus> replayed_recorded(nh, "recorded/calibration/status");
  Collector<tf2_msgs::TFMessage> replay_tf(nh, "/tf_static");
  Collector<rosgraph_msgs::Clock> clock(nh, "/clock", 5000);
  Collector<stereo_msgs::DisparityImage> disparity(nh, "disparity", 5);  // the depth half runs too
  ChildLaunch replay({launchFile("replay.launch"), "bag:=" + bag_path, "prior_file:=" + prior_file, kEachWindowAlone},
                     dir.path + "/replay.log");
  ASSERT_TRUE(replay.started());
  const double bag_duration_s = (bag_end - record_start_stamp).toSec();
  ASSERT_TRUE(replayed.waitForCount(recorded.size(), bag_duration_s + 30.0))
      << "replayed " << replayed.snapshot().size() << " of " << recorded.size() << " epochs\n" << replay.logTail();
  const ros::Time nearly_bag_end = bag_end - ros::Duration(0.2);
  ASSERT_TRUE(clock.waitFor([&](const auto& m) { return !m.empty() && m.back()->clock >= nearly_bag_end; }, 20.0))
      << "the bag did not play to its end\n" << replay.logTail();
  // (rosbag play's last clock is that of its last message but one or so.) Every window of the
  // bag is solved by now (a solve takes well under a second): an extra
  // status would mean an epoch the recording did not have.
  EXPECT_FALSE(replayed.waitForCount(recorded.size() + 1, 3.0)) << "the replay solved more windows than recorded";
  EXPECT_TRUE(replayed_recorded.waitForCount(1, 1.0)) << "the bag's status was not played on recorded/...";
  const size_t disparity_images = disparity.snapshot().size();
  EXPECT_GE(disparity_images, left_images / 2) << "disparity did not keep up with the replay";
  const auto replay_statuses = replayed.snapshot();
  const auto replay_tf_messages = replay_tf.snapshot();
  EXPECT_TRUE(replay.stop(20.0)) << "replay.launch did not stop in time";

  expectEpochsReproduced(recorded, replay_statuses);
  if (HasFatalFailure()) return;
  std::printf("replay: %zu disparity images for %zu left images\n", disparity_images, left_images);

  // The replay's last accepted geometry on /tf_static is the recorded one.
  tf2::Quaternion recorded_q, replay_q;
  ASSERT_TRUE(lastRightRotation(contents.tf, &recorded_q)) << "no recorded /tf_static";
  ASSERT_TRUE(lastRightRotation(replay_tf_messages, &replay_q)) << "no /tf_static from the replay";
  const auto last_accepted =
      *std::find_if(recorded.rbegin(), recorded.rend(), [](const auto& s) { return s->accepted; });
  const double angle_deg = recorded_q.angleShortestPath(replay_q) * 180.0 / M_PI;
  std::printf("last /tf_static rotation: replay - recorded %.5f deg (sd %.5f deg)\n", angle_deg,
              last_accepted->rotation_stddev_deg);
  EXPECT_LE(angle_deg, kToleranceSd * last_accepted->rotation_stddev_deg);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "replay_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
