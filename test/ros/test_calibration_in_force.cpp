// The OnlineCalibrator's calibration in force (CalibrationInForce): the latest valid left/right
// camera_info pair, when it changes (/tf_static), which side is dropped, and reading a commit's
// epoch back from the driver's frames.
#include <gtest/gtest.h>

#include "embedded_calibration_stereo/ros/calibration_in_force.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/rectified_pair.h"

namespace core = embedded_calibration_stereo::core;

namespace ecsr = embedded_calibration_stereo;
using sensor_msgs::CameraInfo;
using sensor_msgs::CameraInfoConstPtr;

namespace {

CameraInfoConstPtr stamped(const CameraInfo& info, int frame) {
  CameraInfo copy = info;
  copy.header.stamp = ros::Time(100, 0) + ros::Duration(0.1 * frame);
  return CameraInfoConstPtr(new CameraInfo(copy));
}

struct Pair {
  CameraInfo left, right;
};

Pair pair(double right_fx = 648.7) {
  Pair p;
  std::tie(p.left, p.right) = ecsr::toStereoCameraInfo(embedded_calibration_stereo::test_support::headRig(right_fx));
  return p;
}

}  // namespace

TEST(CalibrationInForce, ThePairInForceChangesOnlyWithItsRectification) {
  ecsr::CalibrationInForce in_force;
  const Pair a = pair(), b = pair(640.0);
  EXPECT_FALSE(in_force.store(true, stamped(a.left, 0), "left", "right").changed);  // its right side is missing
  EXPECT_FALSE(in_force.left());
  const ecsr::CalibrationInForce::Stored first = in_force.store(false, stamped(a.right, 0), "right", "left");
  EXPECT_TRUE(first.problem.empty()) << first.problem;
  EXPECT_TRUE(first.changed);
  ASSERT_TRUE(in_force.left() && in_force.right());
  // The same calibration with every frame: no change, nothing to put on /tf_static again.
  EXPECT_FALSE(in_force.store(true, stamped(a.left, 1), "left", "right").changed);
  EXPECT_FALSE(in_force.store(false, stamped(a.right, 1), "right", "left").changed);
  // Another calibration (a commit, a rollback): a change once both sides carry it.
  EXPECT_FALSE(in_force.store(true, stamped(b.left, 2), "left", "right").changed);
  EXPECT_TRUE(in_force.store(false, stamped(b.right, 2), "right", "left").changed);
  EXPECT_FALSE(in_force.store(true, stamped(b.left, 3), "left", "right").changed);
}

TEST(CalibrationInForce, ASideThatFailsTheChecksIsDroppedAndThePairInForceStays) {
  ecsr::CalibrationInForce in_force;
  const Pair a = pair();
  in_force.store(true, stamped(a.left, 0), "left", "right");
  in_force.store(false, stamped(a.right, 0), "right", "left");
  CameraInfo bad = a.left;
  bad.K[0] = -1.0;
  const ecsr::CalibrationInForce::Stored dropped = in_force.store(true, stamped(bad, 1), "left", "right");
  EXPECT_FALSE(dropped.problem.empty());
  EXPECT_FALSE(dropped.changed);
  EXPECT_EQ(in_force.left()->header.stamp, stamped(a.left, 0)->header.stamp);
  // The two sides of one frame that do not form a rectified pair.
  CameraInfo shifted = a.right;
  shifted.P[6] += 20.0;  // another rectified cy
  in_force.store(true, stamped(a.left, 2), "left", "right");
  EXPECT_FALSE(in_force.store(false, stamped(shifted, 2), "right", "left").problem.empty());
}

TEST(CalibrationInForce, TheCommitsEpochIsTheFirstFrameCarryingIt) {
  ecsr::CalibrationInForce in_force;
  const Pair a = pair(), b = pair(640.0);
  std::deque<core::FrameSeen> frames;
  for (int i = 0; i < 4; ++i) {
    const Pair& p = i < 2 ? a : b;  // b in force from frame 2 on
    in_force.store(true, stamped(p.left, i), "left", "right");
    in_force.store(false, stamped(p.right, i), "right", "left");
    frames.push_back({static_cast<core::StampNs>(stamped(p.left, i)->header.stamp.toNSec()), false,
                      static_cast<uint32_t>(i < 2 ? 3 : 5)});
  }
  const ecsr::CommittedCalibration committed{b.left, b.right};
  ASSERT_TRUE(in_force.epochCarrying(committed, 3, frames));
  EXPECT_EQ(*in_force.epochCarrying(committed, 3, frames), 5u);
  EXPECT_FALSE(in_force.epochCarrying(committed, 5, frames));  // only frames of another epoch count
  EXPECT_FALSE(in_force.epochCarrying({a.left, b.right}, 3, frames));
  // Committed again only while the calibration it was gated against is in force.
  ecsr::UncommittedCalibration u;
  u.left_in_force = b.left;
  u.right_in_force = b.right;
  EXPECT_TRUE(in_force.stillInForce(u));
  u.left_in_force = a.left;
  EXPECT_FALSE(in_force.stillInForce(u));
}
