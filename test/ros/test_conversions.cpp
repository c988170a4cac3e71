// Conversions core <-> messages, checked against image_geometry (the consumer's view) and by
// round trips.
#include <gtest/gtest.h>
#include <image_geometry/stereo_camera_model.h>
#include <tf2_eigen/tf2_eigen.h>

#include <opencv2/calib3d.hpp>
#include <stdexcept>

#include "embedded_calibration_stereo/ros/conversions.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;

namespace {

core::PinholeCamera camera(double fx, double fy, double cx, double cy) {
  core::PinholeCamera c;
  c.width = 752;
  c.height = 480;
  c.fx = fx;
  c.fy = fy;
  c.cx = cx;
  c.cy = cy;
  c.dist = {{-0.12, 0.05, 0.0008, -0.0005, 0.0}};
  return c;
}

core::StereoRig rig() {
  core::StereoRig r;
  r.left = camera(640, 642, 370, 245);
  r.right = camera(650, 651, 380, 238);
  r.right_from_left.linear() = core::rotationFromVectorDeg(Eigen::Vector3d(0.4, -0.8, 0.3));
  r.right_from_left.translation() = Eigen::Vector3d(-0.12, 0.003, -0.002);
  return r;
}

}  // namespace

TEST(Conversions, MonoCameraInfoIsPlumbBobWithIdentityRectification) {
  const core::PinholeCamera c = camera(600, 610, 371.5, 239.25);
  const sensor_msgs::CameraInfo info = toCameraInfo(c);
  EXPECT_EQ(info.distortion_model, "plumb_bob");
  ASSERT_EQ(info.D.size(), 5u);
  EXPECT_EQ(info.D[0], c.dist[0]);
  EXPECT_EQ(info.K[0], 600);
  EXPECT_EQ(info.K[2], 371.5);
  EXPECT_EQ(info.K[4], 610);
  EXPECT_EQ(info.K[5], 239.25);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(info.R[i], (i % 4 == 0) ? 1.0 : 0.0) << i;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) EXPECT_EQ(info.P[4 * i + j], info.K[3 * i + j]);
    EXPECT_EQ(info.P[4 * i + 3], 0.0);
  }
  core::PinholeCamera back;
  std::string error;
  ASSERT_TRUE(fromCameraInfo(info, &back, &error)) << error;
  EXPECT_EQ(back.width, c.width);
  EXPECT_EQ(back.height, c.height);
  EXPECT_EQ(back.fx, c.fx);
  EXPECT_EQ(back.fy, c.fy);
  EXPECT_EQ(back.cx, c.cx);
  EXPECT_EQ(back.cy, c.cy);
  EXPECT_EQ(back.dist, c.dist);
}

TEST(Conversions, StereoCameraInfoGivesImageGeometryTheRigBaseline) {
  const core::StereoRig r = rig();
  const auto infos = toStereoCameraInfo(r);
  image_geometry::StereoCameraModel model;
  ASSERT_TRUE(model.fromCameraInfo(infos.first, infos.second));
  EXPECT_NEAR(model.baseline(), r.baseline(), 1e-9);
  // Tx = -fx' * baseline, and both rectified cameras share fx', fy', cx', cy'.
  EXPECT_NEAR(infos.second.P[3], -infos.second.P[0] * r.baseline(), 1e-9);
  EXPECT_EQ(infos.first.P[0], infos.second.P[0]);
  EXPECT_EQ(infos.first.P[2], infos.second.P[2]);
  EXPECT_EQ(infos.first.P[6], infos.second.P[6]);
  EXPECT_EQ(infos.first.P[3], 0.0);

  // A point seen by both raw cameras lands on the same rectified row, with the disparity that
  // the stereo model converts back to its depth.
  for (const Eigen::Vector3d& p_left : {Eigen::Vector3d(0.3, -0.2, 2.0), Eigen::Vector3d(-0.5, 0.25, 4.0),
                                       Eigen::Vector3d(0.05, 0.1, 1.2)}) {
    Eigen::Vector2d raw_left, raw_right;
    ASSERT_TRUE(r.left.project(p_left, &raw_left));
    ASSERT_TRUE(r.right.project(r.right_from_left * p_left, &raw_right));
    const cv::Point2d rect_left = model.left().rectifyPoint(cv::Point2d(raw_left.x(), raw_left.y()));
    const cv::Point2d rect_right = model.right().rectifyPoint(cv::Point2d(raw_right.x(), raw_right.y()));
    EXPECT_NEAR(rect_left.y, rect_right.y, 0.05) << p_left.transpose();
    // Depth in the rectified left frame: rotate by R1.
    Eigen::Matrix3d r1;
    for (int i = 0; i < 9; ++i) r1(i / 3, i % 3) = infos.first.R[i];
    const double z_rect = (r1 * p_left).z();
    EXPECT_NEAR(model.getZ(rect_left.x - rect_right.x), z_rect, z_rect * 1e-3) << p_left.transpose();
  }
}

TEST(Conversions, StereoCameraInfoRoundTripRecoversTheRig) {
  const core::StereoRig r = rig();
  const auto infos = toStereoCameraInfo(r);
  core::StereoRig back;
  std::string error;
  ASSERT_TRUE(fromStereoCameraInfo(infos.first, infos.second, &back, &error)) << error;
  EXPECT_LT(core::rotationAngleDeg(back.right_from_left.rotation(), r.right_from_left.rotation()), 1e-7);
  EXPECT_LT((back.right_from_left.translation() - r.right_from_left.translation()).norm(), 1e-9);
  EXPECT_EQ(back.right.fx, r.right.fx);
  EXPECT_EQ(back.left.cy, r.left.cy);
}

// R and P against cv::stereoRectify called here on the rig's K, D, R, T (Bouguet, zero
// disparity at infinity) with the same alpha; alpha 0 is the default.
TEST(Conversions, StereoRectificationIsOpenCvsForTheGivenAlpha) {
  const core::StereoRig r = rig();
  const cv::Matx33d k1(r.left.fx, 0, r.left.cx, 0, r.left.fy, r.left.cy, 0, 0, 1);
  const cv::Matx33d k2(r.right.fx, 0, r.right.cx, 0, r.right.fy, r.right.cy, 0, 0, 1);
  const cv::Matx<double, 1, 5> d1(r.left.dist.data()), d2(r.right.dist.data());
  cv::Matx33d rotation;
  for (int i = 0; i < 9; ++i) rotation(i / 3, i % 3) = r.right_from_left.linear()(i / 3, i % 3);
  const Eigen::Vector3d t = r.right_from_left.translation();
  std::vector<double> focal;
  for (const double alpha : {0.0, 1.0}) {
    cv::Mat r1, r2, p1, p2, q;
    cv::stereoRectify(k1, d1, k2, d2, cv::Size(r.left.width, r.left.height), rotation,
                      cv::Vec3d(t.x(), t.y(), t.z()), r1, r2, p1, p2, q, cv::CALIB_ZERO_DISPARITY,
                      alpha);
    const auto infos = alpha == 0.0 ? toStereoCameraInfo(r) : toStereoCameraInfo(r, alpha);
    for (int i = 0; i < 9; ++i) {
      EXPECT_NEAR(infos.first.R[i], r1.at<double>(i / 3, i % 3), 1e-12) << "alpha " << alpha << " R1 " << i;
      EXPECT_NEAR(infos.second.R[i], r2.at<double>(i / 3, i % 3), 1e-12) << "alpha " << alpha << " R2 " << i;
    }
    for (int i = 0; i < 12; ++i) {
      EXPECT_NEAR(infos.first.P[i], p1.at<double>(i / 4, i % 4), 1e-9) << "alpha " << alpha << " P1 " << i;
      EXPECT_NEAR(infos.second.P[i], p2.at<double>(i / 4, i % 4), 1e-9) << "alpha " << alpha << " P2 " << i;
    }
    focal.push_back(infos.first.P[0]);
  }
  // Alpha 1 keeps every raw pixel, so it zooms out: the two cases differ (the test can tell).
  EXPECT_LT(focal[1], focal[0] * 0.98);
}

TEST(Conversions, StereoCameraInfoOfAnUnusableRigThrowsWithAReason) {
  core::StereoRig r = rig();
  r.right_from_left.translation().setZero();
  try {
    toStereoCameraInfo(r);
    FAIL() << "a rig without baseline was converted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("right_from_left"), std::string::npos) << e.what();
  }
}

TEST(Conversions, UnusableCameraInfoIsRefusedWithAReason) {
  core::PinholeCamera c;
  std::string error;
  sensor_msgs::CameraInfo info = toCameraInfo(camera(600, 600, 370, 240));
  info.K[0] = 0.0;
  EXPECT_FALSE(fromCameraInfo(info, &c, &error));
  EXPECT_NE(error.find("focal"), std::string::npos) << error;
  info = toCameraInfo(camera(600, 600, 370, 240));
  info.K[4] = -5.0;
  EXPECT_FALSE(fromCameraInfo(info, &c, &error));
  info = toCameraInfo(camera(600, 600, 370, 240));
  info.distortion_model = "rational_polynomial";
  info.D.resize(8, 0.0);
  EXPECT_FALSE(fromCameraInfo(info, &c, &error));
  EXPECT_NE(error.find("rational_polynomial"), std::string::npos) << error;
  info = toCameraInfo(camera(600, 600, 370, 240));
  info.width = 0;
  EXPECT_FALSE(fromCameraInfo(info, &c, &error));
  // Four coefficients are plumb_bob without k3.
  info = toCameraInfo(camera(600, 600, 370, 240));
  info.D.resize(4);
  ASSERT_TRUE(fromCameraInfo(info, &c, &error)) << error;
  EXPECT_EQ(c.dist[4], 0.0);
}

TEST(Conversions, ObservationsRoundTrip) {
  core::StereoObservation obs;
  obs.stamp = 1234.5;
  core::BoardCorners b;
  b.board_id = 4;
  b.corner_ids = {0, 1, 7, 34};
  b.u = {10.25f, 20.5f, 30.75f, 700.125f};
  b.v = {1.5f, 2.5f, 3.5f, 470.25f};
  obs.left = {b};
  b.board_id = 5;
  obs.right = {b, b};
  obs.scene = {{1.25f, 2.5f, 3.75f, 4.0f}, {700.5f, 470.25f, 650.125f, 469.0f}};
  const StereoPatternObservation msg = toMsg(obs);
  EXPECT_EQ(msg.header.stamp.toSec(), 1234.5);
  ASSERT_EQ(msg.left.size(), 1u);
  ASSERT_EQ(msg.right.size(), 2u);
  EXPECT_EQ(msg.left[0].board_id, 4);
  EXPECT_EQ(msg.right[1].corner_ids[3], 34);
  const core::StereoObservation back = fromMsg(msg);
  EXPECT_EQ(back.stamp, obs.stamp);
  EXPECT_EQ(back.cornerCount(), obs.cornerCount());
  EXPECT_EQ(back.left[0].corner_ids, obs.left[0].corner_ids);
  EXPECT_EQ(back.right[1].u, obs.right[1].u);
  EXPECT_EQ(back.right[1].v, obs.right[1].v);
  EXPECT_EQ(back.right[0].board_id, 5);
  ASSERT_EQ(msg.scene.size(), 2u);
  EXPECT_EQ(msg.scene[1].right_u, 650.125f);
  ASSERT_EQ(back.scene.size(), 2u);
  for (size_t i = 0; i < 2; ++i) {
    EXPECT_EQ(back.scene[i].left_u, obs.scene[i].left_u);
    EXPECT_EQ(back.scene[i].left_v, obs.scene[i].left_v);
    EXPECT_EQ(back.scene[i].right_u, obs.scene[i].right_u);
    EXPECT_EQ(back.scene[i].right_v, obs.scene[i].right_v);
  }
}

TEST(Conversions, TransformStampedMapsChildPointsIntoTheParentFrame) {
  Eigen::Isometry3d parent_from_child = Eigen::Isometry3d::Identity();
  parent_from_child.linear() = core::rotationFromVectorDeg(Eigen::Vector3d(3, -20, 45));
  parent_from_child.translation() = Eigen::Vector3d(0.12, -0.01, 0.3);
  const auto msg = toTransformStamped(parent_from_child, "left", "right", ros::Time(5, 0));
  EXPECT_EQ(msg.header.frame_id, "left");
  EXPECT_EQ(msg.child_frame_id, "right");
  EXPECT_EQ(msg.header.stamp, ros::Time(5, 0));
  const Eigen::Isometry3d back = tf2::transformToEigen(msg);
  const Eigen::Vector3d p(0.4, -1.0, 2.5);
  EXPECT_LT((back * p - parent_from_child * p).norm(), 1e-12);
}

// A driver with no calibration file publishes the drawing's cameras, or, when they do not have
// the image's size, messages that image_geometry calls uncalibrated.
TEST(Conversions, TheFallbackIsTheNominalPairOfTheImagesSizeOrUncalibrated) {
  const core::StereoRig nominal = rig();
  const auto [left, right] = fallbackCameraInfos(nominal, 752, 480);
  EXPECT_EQ(left.K[0], 640);
  EXPECT_EQ(left.K[4], 642);
  EXPECT_EQ(right.K[0], 650);
  EXPECT_EQ(right.K[5], 238);
  image_geometry::StereoCameraModel model;
  ASSERT_TRUE(model.fromCameraInfo(left, right));
  EXPECT_NEAR(model.baseline(), nominal.right_from_left.translation().norm(), 1e-9);

  for (const std::optional<core::StereoRig>& other : {std::optional<core::StereoRig>(), std::optional(nominal)}) {
    const int width = other ? 640 : 752;  // the nominal cameras are 752x480: another size
    const auto [l, r] = fallbackCameraInfos(other, width, 480);
    for (const sensor_msgs::CameraInfo* info : {&l, &r}) {
      EXPECT_EQ(info->width, static_cast<uint32_t>(width));
      EXPECT_EQ(info->height, 480u);
      for (double k : info->K) EXPECT_EQ(k, 0.0) << "uncalibrated: K all zero";
      for (double p : info->P) EXPECT_EQ(p, 0.0);
    }
  }
}
