// Projection / undistortion round trips of the plumb_bob pinhole model, against OpenCV's
// implementation of the same model as an independent reference.
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <random>

#include "embedded_calibration_stereo/core/geometry/camera_model.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {
namespace {

PinholeCamera headCamera() {
  PinholeCamera c;
  c.width = 752;
  c.height = 480;
  c.fx = 651.3;
  c.fy = 649.8;
  c.cx = 371.2;
  c.cy = 244.6;
  c.dist = {-0.28, 0.07, 4e-4, -3e-4, 0.0};
  return c;
}

TEST(PinholeCamera, PixelRoundTripBelowMicroPixel) {
  for (const auto& dist : {std::array<double, 5>{-0.28, 0.07, 4e-4, -3e-4, 0.0},
                           std::array<double, 5>{0.1, -0.05, 0.0, 0.0, 0.01},
                           std::array<double, 5>{0, 0, 0, 0, 0}}) {
    PinholeCamera c = headCamera();
    c.dist = dist;
    double worst = 0.0;
    for (int v = 0; v < c.height; v += 7)
      for (int u = 0; u < c.width; u += 7) {
        const Eigen::Vector2d px(u + 0.25, v + 0.75);
        const Eigen::Vector2d back = c.normalizedToPixel(c.pixelToNormalized(px));
        worst = std::max(worst, (back - px).norm());
      }
    EXPECT_LT(worst, 1e-6) << "k1=" << dist[0];
  }
}

TEST(PinholeCamera, ProjectionMatchesOpenCv) {
  const PinholeCamera c = headCamera();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> xy(-0.5, 0.5), z(1.0, 10.0);
  std::vector<cv::Point3d> pts;
  for (int i = 0; i < 200; ++i) {
    const double zz = z(rng);
    pts.emplace_back(xy(rng) * zz, xy(rng) * zz * 0.6, zz);
  }
  cv::Mat K = (cv::Mat_<double>(3, 3) << c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
  cv::Mat D(1, 5, CV_64F, const_cast<double*>(c.dist.data()));
  std::vector<cv::Point2d> ref;
  cv::projectPoints(pts, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D, ref);
  for (size_t i = 0; i < pts.size(); ++i) {
    Eigen::Vector2d px;
    ASSERT_TRUE(c.project(Eigen::Vector3d(pts[i].x, pts[i].y, pts[i].z), &px));
    EXPECT_NEAR(px.x(), ref[i].x, 1e-9);
    EXPECT_NEAR(px.y(), ref[i].y, 1e-9);
  }
  EXPECT_FALSE(c.project(Eigen::Vector3d(0, 0, -1), nullptr));
}

TEST(PinholeCamera, UndistortPixelMatchesOpenCv) {
  const PinholeCamera c = headCamera();
  cv::Mat K = (cv::Mat_<double>(3, 3) << c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
  cv::Mat D(1, 5, CV_64F, const_cast<double*>(c.dist.data()));
  std::vector<cv::Point2d> raw{{10, 10}, {376, 240}, {740, 470}, {100, 400}}, ours, ref;
  // OpenCV's iterative undistortion stops at a tolerance; allow for it.
  cv::undistortPoints(raw, ref, K, D, cv::noArray(), K,
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-12));
  for (size_t i = 0; i < raw.size(); ++i) {
    const Eigen::Vector2d u = c.undistortPixel(Eigen::Vector2d(raw[i].x, raw[i].y));
    EXPECT_NEAR(u.x(), ref[i].x, 1e-4);
    EXPECT_NEAR(u.y(), ref[i].y, 1e-4);
  }
}

TEST(PinholeCamera, ValidateNamesTheField) {
  PinholeCamera c = headCamera();
  EXPECT_EQ(c.validate(), "");
  c.fx = 0;
  EXPECT_NE(c.validate().find("fx"), std::string::npos);
  c = headCamera();
  c.fy = -3;
  EXPECT_NE(c.validate().find("fy"), std::string::npos);
  c = headCamera();
  c.width = 0;
  EXPECT_NE(c.validate().find("width"), std::string::npos);
}

TEST(StereoRig, RotationHelpers) {
  const Eigen::Matrix3d r = rotationFromVectorDeg(Eigen::Vector3d(0, 0.3, 0));
  EXPECT_NEAR(rotationAngleDeg(Eigen::Matrix3d::Identity(), r), 0.3, 1e-12);
  EXPECT_NEAR(rotationAngleDeg(r, r), 0.0, 1e-12);
  const Eigen::Matrix3d tiny = rotationFromVectorDeg(Eigen::Vector3d(1e-5, 0, 0));
  EXPECT_NEAR(rotationAngleDeg(Eigen::Matrix3d::Identity(), tiny), 1e-5, 1e-12);
}

// Rotation vectors in radians against OpenCV's Rodrigues formula, both ways, from a zero turn to
// nearly half a turn.
TEST(StereoRig, RotationVectorsMatchRodrigues) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> component(-1.0, 1.0);
  for (const double angle : {0.0, 1e-9, 2e-3, 0.3, 1.5, 3.1}) {
    for (int trial = 0; trial < 5; ++trial) {
      Eigen::Vector3d axis(component(rng), component(rng), component(rng));
      axis.normalize();
      const Eigen::Vector3d rotvec = angle * axis;
      cv::Mat cv_rotation;
      cv::Rodrigues(cv::Vec3d(rotvec.x(), rotvec.y(), rotvec.z()), cv_rotation);
      const Eigen::Matrix3d rotation = rotationFromVector(rotvec);
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(rotation(r, c), cv_rotation.at<double>(r, c), 1e-12) << angle;
      cv::Vec3d cv_back;
      cv::Rodrigues(cv_rotation, cv_back);
      const Eigen::Vector3d back = rotationVector(rotation);
      for (int k = 0; k < 3; ++k) EXPECT_NEAR(back[k], cv_back[k], 1e-9) << angle;
      EXPECT_NEAR((back - rotvec).norm(), 0.0, 1e-9) << angle;
    }
  }
  // The same in degrees.
  cv::Mat cv_rotation;
  cv::Rodrigues(cv::Vec3d(10, -20, 30) * (M_PI / 180.0), cv_rotation);
  const Eigen::Matrix3d rotation = rotationFromVectorDeg(Eigen::Vector3d(10, -20, 30));
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(rotation(r, c), cv_rotation.at<double>(r, c), 1e-12);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
