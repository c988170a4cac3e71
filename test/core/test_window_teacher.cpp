// Teaching the tracker from one light burst of a moving head (window_teacher.h), on the moving
// drive_photo scenario: the head drives, people cross, nothing is covered or still. The boards
// are identified with a nominal description off the simulated truth by a cold start's
// tolerances (focal lengths 2 %, principal points 8 px, k1 0.03), as a real head's drawing is.
// The taught prior is then scored by what matters: the corners the trackers find with it on
// later frames and windows, against the simulator's true corners.
#include <gtest/gtest.h>

#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/tracker/window_teacher.h"
#include "embedded_calibration_stereo/test_support/corner_score.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kConfig = std::string(ECS_SOURCE_DIR) + "/config/drive_photo.yaml";
constexpr double kFps = 30.0;

// One burst: a light-off frame, `lit` light-on frames, a light-off frame, from frame `first`.
struct Burst {
  WindowFrames left, right;
  SimFrame last_lit;
};

Burst renderBurst(SimRig& sim, int first, int lit) {
  Burst b;
  const SimFrame before = sim.render(first / kFps, 0.0, 100 + first);
  b.left.light_off_before.push_back(before.left);
  b.right.light_off_before.push_back(before.right);
  for (int k = 1; k <= lit; ++k) {
    b.last_lit = sim.render((first + k) / kFps, 1.0, 100 + first + k);
    b.left.light_on.push_back(b.last_lit.left);
    b.right.light_on.push_back(b.last_lit.right);
  }
  const SimFrame after = sim.render((first + lit + 1) / kFps, 0.0, 100 + first + lit + 1);
  b.left.light_off_after.push_back(after.left);
  b.right.light_off_after.push_back(after.right);
  return b;
}

// What the tracker nodelet teaches on: the first `n` light-on frames of a burst under way, with
// the light-off frame before it.
WindowFrames firstFrames(const WindowFrames& burst, int n) {
  WindowFrames first;
  first.light_off_before = burst.light_off_before;
  first.light_on.assign(burst.light_on.begin(), burst.light_on.begin() + n);
  return first;
}

// The drawing: the truth off by a cold start's tolerances.
PinholeCamera nominal(PinholeCamera c, double scale, double shift, double k1) {
  c.fx *= scale;
  c.fy *= scale;
  c.cx += shift;
  c.cy -= shift;
  c.dist[0] += k1;
  return c;
}

TEST(WindowTeacher, TeachesOnAMovingHeadFromOneBurstWithANominalDescription) {
  SimRig sim(loadSimRigConfig(kConfig));
  const StereoRig& truth = sim.config().rig;
  const PinholeCamera left_nominal = nominal(truth.left, 1.02, 8.0, 0.03);
  const PinholeCamera right_nominal = nominal(truth.right, 0.98, -8.0, -0.03);
  const Burst teach = renderBurst(sim, 60, 30);
  PatternPrior prior;
  prior.cameras.push_back(teachCameraFromWindow(
      teach.left, BoardLayout::device(sim.virtualBoards(), left_nominal, Eigen::Isometry3d::Identity()), "left").prior);
  prior.cameras.push_back(teachCameraFromWindow(
      teach.right, BoardLayout::device(sim.virtualBoards(), right_nominal, truth.right_from_left), "right").prior);
  for (const CameraPrior& c : prior.cameras)
    EXPECT_EQ(c.boards.size(), sim.virtualBoards().size()) << c.name << ": every board taught";

  // Per-frame tracking of later light-on frames (the scene moved on), and a later window.
  PatternTracker frames(prior, TrackerOptions());
  CornerScore per_frame;
  for (int k = 0; k < 10; ++k) {
    const SimFrame lit = sim.render((150 + 7 * k) / kFps, 1.0, 900 + k);
    per_frame.add(frames.trackStereo(lit.left, lit.right, (150 + 7 * k) / kFps), lit.observations);
  }
  WindowTracker windows(prior, TrackerOptions(), WindowTrackerOptions());
  const Burst later = renderBurst(sim, 240, 30);
  CornerScore window;
  window.add(windows.track(later.left, later.right, 271 / kFps).observation, later.last_lit.observations);
  std::printf("  per-frame tracking with the burst-taught prior: %s\n  a later window: %s\n", per_frame.str().c_str(),
              window.str().c_str());
  EXPECT_GE(per_frame.foundFraction(), 0.99) << per_frame.str();
  EXPECT_EQ(per_frame.wrong, 0u) << per_frame.str();
  EXPECT_GE(window.foundFraction(), 0.99) << window.str();
  EXPECT_EQ(window.wrong, 0u) << window.str();
  EXPECT_LE(window.rms(), 0.03) << window.str();
}

// The sim driver's first burst as it renders it (sim_frame_source.cpp: scene time frame / fps,
// the frame counter as noise seed, the light commanded on at 0.5 s for one unsettled and 30
// settled frames), taught with the simulator's own description: every board of both cameras at
// the burst's end, on drive_photo and on handheld_photo (at most one missed on its first 8
// frames). In some device images a board sits so near its
// neighbours that its search region holds parts of them; it is only found once the boards found
// are painted over and a tighter region is searched.
class WindowTeacherScenario : public ::testing::TestWithParam<const char*> {};

TEST_P(WindowTeacherScenario, TeachesEveryBoardOnTheSimDriversFirstBurst) {
  SimRig sim(loadSimRigConfig(std::string(ECS_SOURCE_DIR) + "/config/" + GetParam() + ".yaml"));
  const int on_at = 15, off_at = on_at + 31;
  std::vector<SimFrame> frames;
  for (int i = 0; i <= off_at + 1; ++i) {
    SimRenderRequest request;
    request.time_s = i / kFps;
    request.noise_seed = static_cast<uint64_t>(i) + 1;
    request.has_light_command = true;
    request.light_command.on = i >= on_at && i < off_at;
    request.light_command.switch_time_s = i < on_at ? -1e300 : i < off_at ? on_at / kFps : off_at / kFps;
    request.light_level = request.light_command.on ? 1.0 : 0.0;
    frames.push_back(sim.render(request));
  }
  Burst b;
  b.left.light_off_before.push_back(frames[on_at - 1].left);
  b.right.light_off_before.push_back(frames[on_at - 1].right);
  for (int i = on_at + 1; i < off_at; ++i) {
    b.left.light_on.push_back(frames[i].left);
    b.right.light_on.push_back(frames[i].right);
  }
  b.left.light_off_after.push_back(frames[off_at + 1].left);
  b.right.light_off_after.push_back(frames[off_at + 1].right);
  const StereoRig& rig = sim.config().rig;
  // At its end (as the nodelet teaches again when the first frames missed a board) and on its
  // first 8 light-on frames (the nodelet teaches on those while the burst goes on).
  const TeachResult left = teachCameraFromWindow(
      b.left, BoardLayout::device(sim.virtualBoards(), rig.left, Eigen::Isometry3d::Identity()), "left");
  const TeachResult right = teachCameraFromWindow(
      b.right, BoardLayout::device(sim.virtualBoards(), rig.right, rig.right_from_left), "right");
  const TeachResult left_first = teachCameraFromWindow(
      firstFrames(b.left, 8), BoardLayout::device(sim.virtualBoards(), rig.left, Eigen::Isometry3d::Identity()),
      "left");
  const TeachResult right_first = teachCameraFromWindow(
      firstFrames(b.right, 8), BoardLayout::device(sim.virtualBoards(), rig.right, rig.right_from_left), "right");
  const auto notes = [](const TeachResult& r) {
    std::string text;
    for (const std::string& n : r.notes) text += "\n  " + n;
    return text;
  };
  // The burst's end (light-off frames on both sides): every board.
  for (const TeachResult* r : {&left, &right})
    EXPECT_EQ(r->prior.boards.size(), sim.virtualBoards().size()) << r->prior.name << notes(*r);
  // Its first frames (one side only: more of the scene left in the device image) may miss a
  // board, which the nodelet then teaches again at the burst's end.
  for (const TeachResult* r : {&left_first, &right_first}) {
    std::printf("  %s, %s, first 8 light-on frames: %zu of %zu boards\n", GetParam(), r->prior.name.c_str(),
                r->prior.boards.size(), sim.virtualBoards().size());
    EXPECT_GE(r->prior.boards.size() + 1, sim.virtualBoards().size()) << r->prior.name << notes(*r);
  }
}

INSTANTIATE_TEST_SUITE_P(Scenarios, WindowTeacherScenario, ::testing::Values("drive_photo", "handheld_photo"));

TEST(WindowTeacher, DeviceImageBecomesAnEightBitGreyTeachingFrame) {
  cv::Mat device(1, 4, CV_32FC1);
  device.at<float>(0) = -5.f;
  device.at<float>(1) = 10.4f;
  device.at<float>(2) = 10.6f;
  device.at<float>(3) = 300.f;
  const TeachFrame frame = teachFrameFromDevice(device);
  ASSERT_EQ(frame.light_on.type(), CV_8UC1);
  EXPECT_TRUE(frame.light_off.empty());
  EXPECT_EQ(frame.light_on.at<uchar>(0), 0);
  EXPECT_EQ(frame.light_on.at<uchar>(1), 10);
  EXPECT_EQ(frame.light_on.at<uchar>(2), 11);
  EXPECT_EQ(frame.light_on.at<uchar>(3), 255);
  // Colour: the grey of BGR by the standard weights (0.114 B + 0.587 G + 0.299 R).
  cv::Mat colour(1, 1, CV_32FC3, cv::Scalar(100, 50, 200));
  EXPECT_EQ(teachFrameFromDevice(colour).light_on.at<uchar>(0), 101);  // 11.4 + 29.35 + 59.8 = 100.55
  EXPECT_THROW(teachFrameFromDevice(cv::Mat(2, 2, CV_8UC1)), std::invalid_argument);
  EXPECT_THROW(teachFrameFromDevice(cv::Mat()), std::invalid_argument);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
