// The simulated head in motion: trajectories, rendered corners and depth against the truth while
// the head drives or is hand-held through a photographed world, a static world point seen where
// the frame's head pose puts it (cv::projectPoints), motion blur, determinism, scene coverage.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/sim/trajectory.h"
#include "embedded_calibration_stereo/test_support/symmetric_corner.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kConfigDir = std::string(ECS_SOURCE_DIR) + "/config/";

SimRigConfig realScenario(const std::string& name) { return loadSimRigConfig(kConfigDir + name + ".yaml"); }

// The scenario with ideal optics: these tests check geometry under motion. The real-head optics
// move the device image on purpose (the ghost) and carry state from frame to frame (the
// auto-exposure); test_sim_optics checks them.
SimRigConfig scenario(const std::string& name) {
  SimRigConfig c = realScenario(name);
  c.optics.ghost = SimGhostConfig();
  c.optics.vignetting = SimVignettingConfig();
  c.optics.exposure = SimExposureConfig();
  c.optics.light = SimLightResponseConfig();
  c.optics.sensor = SimSensorConfig();
  return c;
}

double yawOf(const Eigen::Isometry3d& pose) { return std::atan2(pose.linear()(0, 2), pose.linear()(2, 2)); }

// --- Trajectories -------------------------------------------------------------------------

TEST(SimTrajectory, StaticIsTheStartPose) {
  SimTrajectory t;
  for (double s : {0.0, 1.5, 1000.0}) EXPECT_TRUE(trajectoryPose(t, s).isApprox(Eigen::Isometry3d::Identity(), 0));
  t.start.translation() = Eigen::Vector3d(1, 2, 3);
  EXPECT_TRUE(trajectoryPose(t, 7.0).isApprox(t.start, 0));
}

TEST(SimTrajectory, DriveFollowsItsSpeedAndHeadingAndLoopsBack) {
  SimTrajectory t;
  t.kind = SimTrajectory::Kind::kDrive;
  t.speed_m_s = 1.5;
  t.yaw_rate_amplitude_deg_s = 12.0;
  t.yaw_period_s = 8.0;
  t.loop_s = 20.0;
  ASSERT_EQ(t.validate(), "");
  // Speed by central differences.
  for (double s : {0.7, 3.3, 6.1}) {
    const double h = 1e-4;
    const Eigen::Vector3d v = (trajectoryPose(t, s + h).translation() - trajectoryPose(t, s - h).translation()) / (2 * h);
    EXPECT_NEAR(v.norm(), 1.5, 1e-6) << s;
    // Moving along its own forward (z) axis.
    EXPECT_NEAR(v.normalized().dot(trajectoryPose(t, s).linear().col(2)), 1.0, 1e-6) << s;
  }
  // Heading amplitude = peak yaw rate * period / 2 pi, reached at a quarter period.
  EXPECT_NEAR(yawOf(trajectoryPose(t, 2.0)), 12.0 * M_PI / 180 * 8.0 / (2 * M_PI), 1e-9);
  // Position against a brute-force trapezoid integration of the heading.
  const int n = 200000;
  const double T = 7.3, A = 12.0 * M_PI / 180 * 8.0 / (2 * M_PI);
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  for (int i = 0; i < n; ++i) {
    const double a = A * std::sin(2 * M_PI * (i * T / n) / 8.0), b = A * std::sin(2 * M_PI * ((i + 1) * T / n) / 8.0);
    p += 0.5 * 1.5 * T / n * Eigen::Vector3d(std::sin(a) + std::sin(b), 0, std::cos(a) + std::cos(b));
  }
  EXPECT_LT((trajectoryPose(t, T).translation() - p).norm(), 1e-6);
  // Forward for half the loop, back along the same path, then again.
  EXPECT_TRUE(trajectoryPose(t, 10.0 + 2.5).isApprox(trajectoryPose(t, 10.0 - 2.5), 1e-12));
  EXPECT_TRUE(trajectoryPose(t, 23.0).isApprox(trajectoryPose(t, 3.0), 1e-12));
  EXPECT_LT((trajectoryPose(t, 19.999).translation() - trajectoryPose(t, 0.0).translation()).norm(), 0.002);
  // Bumps: small, bounded, deterministic, absent at t = 0.
  t.bump_amplitude_m = 0.004;
  t.pitch_amplitude_deg = 0.3;
  double max_y = 0, max_pitch = 0;
  for (double s = 0; s < 5; s += 0.01) {
    const Eigen::Isometry3d pose = trajectoryPose(t, s);
    max_y = std::max(max_y, std::abs(pose.translation().y()));
    max_pitch = std::max(max_pitch, std::abs(std::asin(pose.linear()(1, 2))) * 180 / M_PI);
  }
  EXPECT_GT(max_y, 0.002);
  EXPECT_LE(max_y, 2 * 0.004);
  EXPECT_GT(max_pitch, 0.1);
  EXPECT_LE(max_pitch, 2 * 0.3 + 1e-9);
  EXPECT_TRUE(trajectoryPose(t, 0.0).isApprox(Eigen::Isometry3d::Identity(), 1e-12));
}

TEST(SimTrajectory, HandheldStartsAtStartIsBoundedAndPeriodicPerAxis) {
  SimTrajectory t;
  t.kind = SimTrajectory::Kind::kHandheld;
  t.start.translation() = Eigen::Vector3d(0.1, 0.2, 0.3);
  t.translation_amplitude_m = Eigen::Vector3d(0.05, 0, 0);
  t.translation_period_s = Eigen::Vector3d(3.0, 4.0, 5.0);
  ASSERT_EQ(t.validate(), "");
  SimTrajectory all_axes = t;
  all_axes.translation_amplitude_m = Eigen::Vector3d(0.05, 0.04, 0.03);
  all_axes.rotation_amplitude_deg = Eigen::Vector3d(2, 3, 4);
  EXPECT_TRUE(trajectoryPose(all_axes, 0.0).isApprox(t.start, 1e-12));
  EXPECT_FALSE(trajectoryPose(all_axes, 0.5).isApprox(t.start, 1e-3));
  double max_dx = 0;
  for (double s = 0; s < 6; s += 0.01) {
    const Eigen::Vector3d d = trajectoryPose(t, s).translation() - t.start.translation();
    max_dx = std::max(max_dx, std::abs(d.x()));
    EXPECT_NEAR(d.y(), 0.0, 1e-15);
    EXPECT_NEAR((trajectoryPose(t, s + 3.0).translation() - trajectoryPose(t, s).translation()).norm(), 0.0, 1e-12);
  }
  EXPECT_GT(max_dx, 0.03);
  EXPECT_LE(max_dx, 2 * 0.05);
  // A rotation about y only.
  t.translation_amplitude_m.setZero();
  t.rotation_amplitude_deg = Eigen::Vector3d(0, 4.0, 0);
  const Eigen::AngleAxisd aa(trajectoryPose(t, 1.3).linear());
  EXPECT_GT(aa.angle(), 1e-3);
  EXPECT_NEAR(std::abs(aa.axis().y()), 1.0, 1e-9);
}

TEST(SimTrajectory, WaypointsInterpolateLinearlyOrBySplineWithSlerp) {
  SimTrajectory t;
  t.kind = SimTrajectory::Kind::kWaypoints;
  SimWaypoint a, b, c;
  a.t_s = 1.0;
  b.t_s = 3.0;
  b.pose.translation() = Eigen::Vector3d(2, 0, 0);
  b.pose.linear() = rotationFromVectorDeg(Eigen::Vector3d(0, 40, 0));
  c.t_s = 4.0;
  c.pose.translation() = Eigen::Vector3d(2, 1, 0);
  t.waypoints = {a, b, c};
  ASSERT_EQ(t.validate(), "");
  for (const SimWaypoint& w : t.waypoints) EXPECT_TRUE(trajectoryPose(t, w.t_s).isApprox(w.pose, 1e-12));
  EXPECT_TRUE(trajectoryPose(t, 0.0).isApprox(a.pose, 1e-12));   // held before
  EXPECT_TRUE(trajectoryPose(t, 9.0).isApprox(c.pose, 1e-12));   // and after
  const Eigen::Isometry3d mid = trajectoryPose(t, 2.0);
  EXPECT_LT((mid.translation() - Eigen::Vector3d(1, 0, 0)).norm(), 1e-12);
  EXPECT_NEAR(rotationAngleDeg(mid.linear(), a.pose.linear()), 20.0, 1e-9);
  EXPECT_NEAR(rotationAngleDeg(mid.linear(), b.pose.linear()), 20.0, 1e-9);
  t.spline = true;
  for (const SimWaypoint& w : t.waypoints) EXPECT_TRUE(trajectoryPose(t, w.t_s).isApprox(w.pose, 1e-12));
  // The spline bends towards the next waypoint: the middle of the first segment leaves the line.
  EXPECT_GT(std::abs(trajectoryPose(t, 2.0).translation().y()), 0.01);
  t.loop_s = 5.0;
  EXPECT_TRUE(trajectoryPose(t, 7.0).isApprox(trajectoryPose(t, 2.0), 1e-12));
}

// --- Rendering under motion --------------------------------------------------------------

// Corners are measured with the point-symmetry estimator (test support), free of
// cv::cornerSubPix's own error floor.

// RMS of the rendered corners against the frame's ground-truth observations, measured on the
// image minus the ground-truth scene layer (the device's light path alone), both cameras.
double cornerRms(const SimFrame& frame, size_t* count) {
  double sum = 0;
  *count = 0;
  for (int side = 0; side < 2; ++side) {
    cv::Mat device;
    cv::subtract(side == 0 ? frame.left : frame.right, side == 0 ? frame.left_scene : frame.right_scene, device,
                 cv::noArray(), CV_32F);
    for (const BoardCorners& b : side == 0 ? frame.observations.left : frame.observations.right)
      for (size_t i = 0; i < b.size(); ++i) {
        const cv::Point2d c = symmetricCorner(device, cv::Point2d(b.u[i] + 0.3, b.v[i] - 0.2), 5);
        sum += std::pow(c.x - b.u[i], 2) + std::pow(c.y - b.v[i], 2);
        ++*count;
      }
  }
  return *count ? std::sqrt(sum / *count) : 1e9;
}

TEST(SimMotion, RenderedCornersMatchTruthWhileTheHeadMoves) {
  for (const char* name : {"drive_photo", "handheld_photo"}) {
    SimRigConfig c = scenario(name);
    c.noise_sigma = 0.0;
    const SimRig rig(c);
    for (double t : {1.3, 4.7, 11.1}) {
      const SimFrame f = rig.render(t, 1.0, 1);
      // The head really moved.
      ASSERT_GT(f.world_from_left.translation().norm(), 0.01) << name << " t " << t;
      size_t n = 0;
      const double rms = cornerRms(f, &n);
      std::printf("[ figures  ] %s t=%.1f s (head at %.2f m from start): corners vs truth RMS %.4f px over %zu corners\n",
                  name, t, f.world_from_left.translation().norm(), rms, n);
      EXPECT_EQ(n, 2u * 6u * 48u);
      EXPECT_LE(rms, 0.02) << name << " t " << t;
    }
  }
}

// Left optical-frame rays of raw pixels, by cv::undistortPoints (independent of the renderer).
std::vector<cv::Point2d> undistort(const PinholeCamera& c, const std::vector<cv::Point2d>& pixels) {
  const cv::Matx33d K(c.fx, c.skew, c.cx, 0, c.fy, c.cy, 0, 0, 1);
  const cv::Mat D(cv::Matx<double, 1, 5>(c.dist.data()), true);
  std::vector<cv::Point2d> out;
  cv::undistortPoints(pixels, out, K, D, cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-12));
  return out;
}

cv::Point2d project(const PinholeCamera& c, const Eigen::Isometry3d& camera_from_world, const Eigen::Vector3d& p) {
  const cv::Matx33d K(c.fx, c.skew, c.cx, 0, c.fy, c.cy, 0, 0, 1);
  const cv::Mat D(cv::Matx<double, 1, 5>(c.dist.data()), true);
  const Eigen::AngleAxisd aa(camera_from_world.linear());
  const Eigen::Vector3d r = aa.angle() * aa.axis(), t = camera_from_world.translation();
  std::vector<cv::Point2d> px;
  cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(p.x(), p.y(), p.z())}, cv::Vec3d(r.x(), r.y(), r.z()),
                    cv::Vec3d(t.x(), t.y(), t.z()), K, D, px);
  return px[0];
}

// A known plane in the world, seen at frame k: its depth from the plane equation (through the
// frame's head pose and cv::undistortPoints) against left_depth, and left/right scene images
// matching at the disparity that depth implies (right pixel by cv::projectPoints).
TEST(SimMotion, DepthOfAKnownWorldPlaneAgreesWithTheRenderedDisparity) {
  SimRigConfig c = scenario("handheld_photo");
  c.noise_sigma = 0.0;
  c.scene.movers.clear();
  const double time_s = 37 / c.fps;
  const Eigen::Isometry3d head = trajectoryPose(c.trajectory, time_s);
  // A textured panel 1.6 m in front of the head at that frame, yawed 20 deg, in world coordinates.
  ScenePlane panel;
  const Eigen::Matrix3d yaw = rotationFromVectorDeg(Eigen::Vector3d(0, 20, 0));
  panel.origin = head * Eigen::Vector3d(-0.6, -0.45, 1.6);
  panel.u_axis = head.linear() * yaw.col(0);
  panel.v_axis = head.linear() * Eigen::Vector3d::UnitY();
  panel.width_m = 1.2;
  panel.height_m = 0.9;
  panel.texture_seed = 77;
  panel.texel_m = 0.003;
  c.scene.planes.push_back(panel);
  const SimRig rig(c);
  const SimFrame f = rig.render(time_s, 0.0, 1);
  ASSERT_TRUE(f.world_from_left.isApprox(head, 1e-12));

  const Eigen::Isometry3d left_from_world = f.world_from_left.inverse();
  const Eigen::Vector3d n = left_from_world.linear() * panel.u_axis.cross(panel.v_axis);
  const double d = n.dot(left_from_world * panel.origin);
  std::vector<cv::Point2d> pixels;
  for (int v = 0; v < f.left_depth.rows; v += 3)
    for (int u = 0; u < f.left_depth.cols; u += 3) pixels.emplace_back(u, v);
  const std::vector<cv::Point2d> rays = undistort(f.truth.left, pixels);
  double max_error = 0;
  int inside = 0;
  std::vector<cv::Point2f> left_px, right_px;
  for (size_t i = 0; i < pixels.size(); ++i) {
    const Eigen::Vector3d m(rays[i].x, rays[i].y, 1.0);
    const double z = d / n.dot(m);
    const Eigen::Vector3d hit_world = f.world_from_left * (z * m);
    const double a = (hit_world - panel.origin).dot(panel.u_axis), b = (hit_world - panel.origin).dot(panel.v_axis);
    if (!(a > 0.03 && a < panel.width_m - 0.03 && b > 0.03 && b < panel.height_m - 0.03)) continue;
    ++inside;
    const float depth = f.left_depth.at<float>(static_cast<int>(pixels[i].y), static_cast<int>(pixels[i].x));
    max_error = std::max(max_error, std::abs(depth - z));
    const cv::Point2d r = project(f.truth.right, f.truth.right_from_left, z * m);
    if (pixels[i].x > 8 && pixels[i].y > 8 && pixels[i].x < 743 && pixels[i].y < 471 && r.x > 8 && r.x < 743 &&
        r.y > 8 && r.y < 471) {
      left_px.emplace_back(pixels[i]);
      right_px.emplace_back(r);
    }
  }
  std::printf("[ figures  ] known plane at frame 37 of handheld_photo: %d samples, depth vs plane equation max "
              "error %.2e m\n", inside, max_error);
  ASSERT_GT(inside, 2000);
  EXPECT_LT(max_error, 2e-4);

  // The right scene sampled where the depth puts each left pixel, shifted by dx along the rows:
  // the mismatch is smallest at dx = 0.
  cv::Mat L, R;
  f.left_scene.convertTo(L, CV_32F);
  f.right_scene.convertTo(R, CV_32F);
  auto mismatch = [&](double dx) {
    cv::Mat map(1, static_cast<int>(right_px.size()), CV_32FC2), sampled;
    for (size_t i = 0; i < right_px.size(); ++i) map.at<cv::Vec2f>(0, i) = cv::Vec2f(right_px[i].x + dx, right_px[i].y);
    cv::remap(R, sampled, map, cv::noArray(), cv::INTER_CUBIC, cv::BORDER_REPLICATE);
    double sum = 0;
    for (size_t i = 0; i < left_px.size(); ++i)
      sum += std::pow(L.at<float>(static_cast<int>(left_px[i].y), static_cast<int>(left_px[i].x)) - sampled.at<float>(0, i), 2);
    return std::sqrt(sum / left_px.size());
  };
  double best_dx = 0, best = std::numeric_limits<double>::infinity();
  for (double dx = -1.0; dx <= 1.0 + 1e-9; dx += 0.02) {
    const double e = mismatch(dx);
    if (e < best) best = e, best_dx = dx;
  }
  std::printf("[ figures  ] left vs right at the depth's disparity: RMS %.2f grey levels (best row shift %.2f px; "
              "at 1 px off: %.2f)\n", mismatch(0.0), best_dx, mismatch(1.0));
  EXPECT_LE(std::abs(best_dx), 0.1);
  EXPECT_LT(mismatch(0.0), 0.4 * mismatch(1.0));
}

std::string writeImage(const std::string& name, const cv::Mat& image) {
  const std::string path = ::testing::TempDir() + name;
  EXPECT_TRUE(cv::imwrite(path, image));
  return path;
}

// A 20 cm X-corner (a 2x2 checker photograph) fixed in the world in front of a flat grey wall,
// the head moving by hand: at frame k the corner lands in both images where cv::projectPoints
// puts it through the frame's world_from_left.
TEST(SimMotion, HeadPoseOfFrameKReproducesAStaticWorldPoint) {
  SimRigConfig c = scenario("handheld_photo");
  c.noise_sigma = 0.0;
  c.scene.movers.clear();
  cv::Mat checker(64, 64, CV_8U, cv::Scalar(40));
  checker(cv::Rect(32, 0, 32, 32)).setTo(220);
  checker(cv::Rect(0, 32, 32, 32)).setTo(220);
  ScenePlane wall, feature;
  wall.origin = Eigen::Vector3d(-3, -2, 3.0);
  wall.width_m = 6;
  wall.height_m = 4;
  wall.texture_image = writeImage("sim_flat_grey.png", cv::Mat(8, 8, CV_8U, cv::Scalar(128)));
  feature.origin = Eigen::Vector3d(0.15, -0.05, 2.2);
  feature.width_m = feature.height_m = 0.2;
  feature.texture_image = writeImage("sim_checker.png", checker);
  c.scene.planes = {wall, feature};
  const Eigen::Vector3d corner_world = feature.origin + Eigen::Vector3d(0.1, 0.1, 0);
  const SimRig rig(c);
  double sum = 0, worst = 0;
  int n = 0;
  for (int k : {0, 23, 71, 140}) {
    const SimFrame f = rig.render(k / c.fps, 0.0, 1);
    const Eigen::Isometry3d left_from_world = f.world_from_left.inverse();
    for (int side = 0; side < 2; ++side) {
      const Eigen::Isometry3d cam_from_world = side == 0 ? left_from_world : f.truth.right_from_left * left_from_world;
      const cv::Point2d expected = project(side == 0 ? f.truth.left : f.truth.right, cam_from_world, corner_world);
      cv::Mat img;
      (side == 0 ? f.left_scene : f.right_scene).convertTo(img, CV_32F);
      const cv::Point2d found = symmetricCorner(img, expected + cv::Point2d(0.4, -0.3), 5);
      const double e = std::hypot(found.x - expected.x, found.y - expected.y);
      sum += e * e, worst = std::max(worst, e), ++n;
    }
    if (k == 140) EXPECT_GT(f.world_from_left.translation().norm(), 0.01);
  }
  std::printf("[ figures  ] static world X-corner vs cv::projectPoints through world_from_left(k), %d views: "
              "RMS %.4f px, max %.4f px\n", n, std::sqrt(sum / n), worst);
  EXPECT_LE(worst, 0.05);
}

// Gradient energy of a region along x and along y.
std::pair<double, double> gradientEnergy(const cv::Mat& image, const cv::Rect& roi) {
  cv::Mat f, gx, gy;
  image(roi).convertTo(f, CV_32F);
  cv::Sobel(f, gx, CV_32F, 1, 0);
  cv::Sobel(f, gy, CV_32F, 0, 1);
  return {cv::norm(gx, cv::NORM_L2SQR), cv::norm(gy, cv::NORM_L2SQR)};
}

TEST(SimMotion, MotionBlurSmearsTheSceneAlongTheMotionButNotTheBoards) {
  SimRigConfig sharp_config = scenario("drive_photo");
  sharp_config.noise_sigma = 0.0;
  SimRigConfig blur_config = sharp_config;
  blur_config.motion_blur.exposure_s = 0.03;
  blur_config.motion_blur.samples = 8;
  const SimRig sharp(sharp_config), blurred(blur_config);
  // t = 8 s: the heading swings at its peak yaw rate (12 deg/s, about 4 px over the exposure).
  const double t = 8.0;
  const SimFrame a = sharp.render(t, 1.0, 1), b = blurred.render(t, 1.0, 1);
  const cv::Rect roi(200, 120, 352, 240);
  const auto ea = gradientEnergy(a.left_scene, roi), eb = gradientEnergy(b.left_scene, roi);
  const double ratio_x = eb.first / ea.first, ratio_y = eb.second / ea.second;
  std::printf("[ figures  ] motion blur (exposure 30 ms, 8 samples, yaw 12 deg/s): scene gradient energy "
              "along x %.2f of sharp, along y %.2f\n", ratio_x, ratio_y);
  EXPECT_LT(ratio_x, 0.7);
  EXPECT_LT(ratio_x, ratio_y - 0.1);
  // Depth and head pose stay the frame time's.
  EXPECT_EQ(cv::norm(a.left_depth, b.left_depth, cv::NORM_INF), 0.0);
  EXPECT_TRUE(a.world_from_left.isApprox(b.world_from_left, 0));
  // The boards move with the cameras: their light path is the same with and without blur.
  cv::Mat da, db;
  cv::subtract(a.left, a.left_scene, da, cv::noArray(), CV_16S);
  cv::subtract(b.left, b.left_scene, db, cv::noArray(), CV_16S);
  EXPECT_LE(cv::norm(da, db, cv::NORM_INF), 1.0);  // rounding of the two 8-bit images
  size_t n = 0, n_sharp = 0;
  const double rms = cornerRms(b, &n), rms_sharp = cornerRms(a, &n_sharp);
  std::printf("[ figures  ] corners vs truth with motion blur: RMS %.4f px (without: %.4f px), %zu corners\n", rms,
              rms_sharp, n);
  EXPECT_LE(rms, 0.02);
}

uint64_t frameHash(const SimFrame& f) {
  uint64_t h = 1469598103934665603ULL;
  for (const cv::Mat* m : {&f.left, &f.right, &f.left_scene, &f.right_scene, &f.left_depth}) {
    const cv::Mat c = m->clone();
    for (size_t i = 0; i < c.total() * c.elemSize(); ++i) h = (h ^ c.data[i]) * 1099511628211ULL;
  }
  return h;
}

TEST(SimMotion, ScenarioFramesAreDeterministicInAnyOrder) {
  const SimRigConfig c = scenario("drive_photo");
  auto frame = [&](const SimRig& rig, int k) { return frameHash(rig.render(k / c.fps, 1.0, k)); };
  const SimRig first(c);
  const uint64_t f50 = frame(first, 50), f10 = frame(first, 10);
  const SimRig second(c);
  const uint64_t g10 = frame(second, 10), g50 = frame(second, 50);
  EXPECT_EQ(f50, g50);
  EXPECT_EQ(f10, g10);
  EXPECT_NE(f10, f50);
  EXPECT_EQ(frame(SimRig(c), 50), f50);
}

// With the real-head optics the auto-exposure depends on the frames before: a sequence rendered
// in order from the start is the same every run.
TEST(SimMotion, ScenarioSequencesWithRealOpticsAreDeterministic) {
  const SimRigConfig c = realScenario("drive_photo");
  ASSERT_EQ(c.optics.exposure.mode, "auto");
  const auto sequence = [&] {
    const SimRig rig(c);
    std::vector<uint64_t> hashes;
    for (int k = 0; k < 12; ++k) hashes.push_back(frameHash(rig.render(k / c.fps, k < 6 ? 0.0 : 1.0, k)));
    return hashes;
  };
  const std::vector<uint64_t> a = sequence(), b = sequence();
  EXPECT_EQ(a, b);
  EXPECT_NE(a[3], a[4]);
}

TEST(SimMotion, ExplicitStaticTrajectoryRendersTheDefaultWorldUnchanged) {
  const SimRigConfig plain = loadSimRigConfig(kConfigDir + "sim_rig.yaml");
  SimRigConfig held = plain;  // a waypoint trajectory that never leaves the origin
  held.trajectory.kind = SimTrajectory::Kind::kWaypoints;
  held.trajectory.waypoints = {SimWaypoint(), SimWaypoint()};
  held.trajectory.waypoints[1].t_s = 10.0;
  const SimRig a(plain), b(held);
  for (double t : {0.0, 2.5}) {
    const SimFrame fa = a.render(t, 1.0, 3), fb = b.render(t, 1.0, 3);
    EXPECT_EQ(frameHash(fa), frameHash(fb));
    EXPECT_TRUE(fa.world_from_left.isApprox(Eigen::Isometry3d::Identity(), 0));
    EXPECT_DOUBLE_EQ(fa.time_s, t);
  }
}

// Every pixel of both cameras sees the scene during the whole loop (drive) or 30 s (hand-held):
// no infinite depth on the left, no empty (zero) scene radiance on the right.
TEST(SimMotion, ScenariosFillEveryPixelAlongTheTrajectory) {
  for (const auto& run : {std::make_pair("drive_photo", 20.0), std::make_pair("handheld_photo", 30.0)}) {
    SimRigConfig c = scenario(run.first);
    c.noise_sigma = 0.0;
    const SimRig rig(c);
    int frames = 0, bad_frames = 0;
    double min_depth = 1e9, max_depth = 0;
    for (double t = 0.0; t <= run.second + 1e-9; t += 0.5, ++frames) {
      const SimFrame f = rig.render(t, 0.0, 1);
      const int holes = cv::countNonZero(f.left_depth == std::numeric_limits<float>::infinity()) +
                        cv::countNonZero(f.right_scene == 0);
      bad_frames += holes > 0;
      EXPECT_EQ(holes, 0) << run.first << " t " << t;
      double lo, hi;
      cv::minMaxLoc(f.left_depth, &lo, &hi);
      min_depth = std::min(min_depth, lo), max_depth = std::max(max_depth, hi);
    }
    std::printf("[ figures  ] %s: %d frames every 0.5 s, %d with an uncovered pixel; depth range [%.2f, %.2f] m\n",
                run.first, frames, bad_frames, min_depth, max_depth);
  }
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
