// Tests of the simulated stereo rig against its own ground truth: rendered corners vs the
// projected truth, depth vs rendered disparity, observations, drift, determinism, config errors.
// Where the truth is a projection, it is OpenCV's (cv::projectPoints, cv::undistortPoints with
// the camera's K and D), not the PinholeCamera the simulator itself projects with.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <thread>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/test_support/symmetric_corner.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kDefaultConfig = std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml";

SimRigConfig defaultConfig() { return loadSimRigConfig(kDefaultConfig); }

cv::Matx33d opencvK(const PinholeCamera& c) { return {c.fx, c.skew, c.cx, 0, c.fy, c.cy, 0, 0, 1}; }
cv::Mat opencvD(const PinholeCamera& c) { return cv::Mat(cv::Matx<double, 1, 5>(c.dist.data()), true); }

// Raw pixel of a point in the camera's optical frame, by cv::projectPoints.
Eigen::Vector2d opencvProject(const PinholeCamera& c, const Eigen::Vector3d& p_cam) {
  std::vector<cv::Point2d> px;
  cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(p_cam.x(), p_cam.y(), p_cam.z())}, cv::Vec3d(0, 0, 0),
                    cv::Vec3d(0, 0, 0), opencvK(c), opencvD(c), px);
  return Eigen::Vector2d(px[0].x, px[0].y);
}

// Normalised undistorted coordinates of raw pixels, by cv::undistortPoints iterated to
// convergence (its default five iterations are not enough for this lens at the image edge).
std::vector<cv::Point2d> opencvUndistort(const PinholeCamera& c, const std::vector<cv::Point2d>& pixels) {
  std::vector<cv::Point2d> out;
  cv::undistortPoints(pixels, out, opencvK(c), opencvD(c), cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-12));
  return out;
}

// --- Measuring corner positions in rendered images -------------------------------------
// cv::cornerSubPix has an error floor of its own (bilinear resampling of the window and
// discrete gradients), larger on sharp pixel-area-averaged edges than with a lens blur, whoever
// renders the image (CornersMatchSupersampledReference prints it). To measure the
// renderer to 0.02 px the main check uses an estimator without that floor: around a
// chessboard corner the (blurred) image is point-symmetric, I(c + d) = I(c - d), so the corner
// is the centre c minimising sum_d (I(c + d) - I(c - d))^2, sampled with bicubic interpolation.

struct CornerErrors {
  double symmetric_rms = 0, symmetric_max = 0, subpix_rms = 0;
  size_t count = 0;
};

// Refines every true corner, started 0.36 px away, with both estimators; errors vs the truth.
CornerErrors measureCornerErrors(const SimFrame& frame) {
  CornerErrors e;
  double sum_sym = 0, sum_sub = 0;
  for (int side = 0; side < 2; ++side) {
    const cv::Mat& image = side == 0 ? frame.left : frame.right;
    cv::Mat image_f;
    image.convertTo(image_f, CV_32F);
    for (const BoardCorners& b : side == 0 ? frame.observations.left : frame.observations.right) {
      std::vector<cv::Point2f> points;
      for (size_t i = 0; i < b.size(); ++i) points.emplace_back(b.u[i] + 0.3f, b.v[i] - 0.2f);
      cv::cornerSubPix(image, points, cv::Size(5, 5), cv::Size(-1, -1),
                       cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-5));
      for (size_t i = 0; i < b.size(); ++i) {
        const cv::Point2d sym = symmetricCorner(image_f, cv::Point2d(b.u[i] + 0.3, b.v[i] - 0.2), 5);
        const double e_sym = std::hypot(sym.x - b.u[i], sym.y - b.v[i]);
        sum_sym += e_sym * e_sym;
        e.symmetric_max = std::max(e.symmetric_max, e_sym);
        sum_sub += std::pow(points[i].x - b.u[i], 2) + std::pow(points[i].y - b.v[i], 2);
        ++e.count;
      }
    }
  }
  if (e.count == 0) return {1e9, 1e9, 1e9, 0};
  e.symmetric_rms = std::sqrt(sum_sym / e.count);
  e.subpix_rms = std::sqrt(sum_sub / e.count);
  return e;
}

SimRigConfig cornerTestConfig() {
  SimRigConfig c = defaultConfig();  // keeps the default lens blur (optics.psf_sigma_px)
  c.scene.enabled = false;
  c.noise_sigma = 0.0;
  return c;
}

TEST(SimRig, RenderedCornersMatchTruth) {
  const SimRig rig(cornerTestConfig());
  const SimFrame frame = rig.render(0.0, 1.0, 1);
  const CornerErrors e = measureCornerErrors(frame);
  std::printf("[ figures  ] rendered corners vs truth over %zu corners (both cameras): symmetric "
              "estimator RMS %.4f px (max %.4f), cv::cornerSubPix 5x5 RMS %.4f px\n",
              e.count, e.symmetric_rms, e.symmetric_max, e.subpix_rms);
  EXPECT_EQ(e.count, 2u * 6u * 48u);
  EXPECT_LE(e.symmetric_rms, 0.02);
  EXPECT_LE(e.subpix_rms, 0.04);  // the estimator's own floor, not the renderer's accuracy
}

TEST(SimRig, RenderedCornersMatchTruthAfterZoomAndRotation) {
  SimRig rig(cornerTestConfig());
  DriftRequest drift;
  drift.focal_scale = 1.05;
  drift.right_rotation_deg = Eigen::Vector3d(0.2, -0.3, 0.1);
  ASSERT_EQ(rig.setDrift(drift, 0.0), "");
  const SimFrame frame = rig.render(0.0, 1.0, 1);
  const CornerErrors e = measureCornerErrors(frame);
  std::printf("[ figures  ] after zoom 1.05 + right rotation, %zu corners: symmetric RMS %.4f px, "
              "cornerSubPix RMS %.4f px\n", e.count, e.symmetric_rms, e.subpix_rms);
  EXPECT_GT(e.count, 2u * 6u * 40u);
  EXPECT_LE(e.symmetric_rms, 0.02);
}

// An independent, brute-force reference: 16 x 16 point samples per pixel, each undistorted
// with cv::undistortPoints and intersected with the board plane; the corner where
// cv::projectPoints puts it. Without lens blur, cornerSubPix must find the same corner in the
// renderer's image and in the reference, and in the reference where OpenCV projects it.
TEST(SimRig, CornersMatchSupersampledReference) {
  SimRigConfig config = cornerTestConfig();
  config.optics.psf_sigma_px = 0.0;
  const SimRig rig(config);
  const SimFrame frame = rig.render(0.0, 1.0, 1);
  const double scale = config.optics.reflectance * 255.0;
  const int kHalf = 10, kSub = 16;
  double sum_sq = 0, sum_truth_sq = 0;
  int n = 0;
  for (int side = 0; side < 2; ++side) {
    const PinholeCamera& cam = side == 0 ? frame.truth.left : frame.truth.right;
    const Eigen::Isometry3d rig_from_cam = side == 0 ? Eigen::Isometry3d::Identity() : frame.truth.leftFromRight();
    for (const VirtualBoard& vb : rig.virtualBoards()) {
      const int id = vb.cols + 2;  // an inner corner one row and two columns in
      const Eigen::Vector3d p_rig = vb.cornerInRig(id);
      const Eigen::Vector3d p_cam = rig_from_cam.inverse() * p_rig;
      ASSERT_GT(p_cam.z(), 0.0);
      const Eigen::Vector2d px = opencvProject(cam, p_cam);
      const int x0 = static_cast<int>(px.x()) - kHalf, y0 = static_cast<int>(px.y()) - kHalf;
      const Eigen::Isometry3d board_from_cam = vb.rig_from_board.inverse() * rig_from_cam;
      cv::Mat reference(2 * kHalf + 1, 2 * kHalf + 1, CV_8U);
      std::vector<cv::Point2d> samples;
      for (int y = 0; y < reference.rows; ++y)
        for (int x = 0; x < reference.cols; ++x)
          for (int j = 0; j < kSub; ++j)
            for (int i = 0; i < kSub; ++i)
              samples.emplace_back(x0 + x - 0.5 + (i + 0.5) / kSub, y0 + y - 0.5 + (j + 0.5) / kSub);
      const std::vector<cv::Point2d> rays = opencvUndistort(cam, samples);
      size_t next = 0;
      for (int y = 0; y < reference.rows; ++y)
        for (int x = 0; x < reference.cols; ++x) {
          double sum = 0;
          for (int j = 0; j < kSub; ++j)
            for (int i = 0; i < kSub; ++i) {
              const Eigen::Vector2d m(rays[next].x, rays[next].y);
              ++next;
              const Eigen::Vector3d o = board_from_cam.translation();
              const Eigen::Vector3d d = board_from_cam.linear() * Eigen::Vector3d(m.x(), m.y(), 1.0);
              const Eigen::Vector3d hit = o - o.z() / d.z() * d;
              const int col = static_cast<int>(std::floor(hit.x() / vb.square));
              const int row = static_cast<int>(std::floor((vb.mirrored ? -hit.y() : hit.y()) / vb.square));
              sum += ((col + row) % 2 == 0) ? config.optics.device_black : config.optics.device_white;
            }
          reference.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(scale * sum / (kSub * kSub));
        }
      const cv::Mat rendered = (side == 0 ? frame.left : frame.right)(cv::Rect(x0, y0, reference.cols, reference.rows)).clone();
      std::vector<cv::Point2f> a{cv::Point2f(px.x() - x0 + 0.3, px.y() - y0 - 0.2)}, b = a;
      const cv::TermCriteria criteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-5);
      cv::cornerSubPix(rendered, a, cv::Size(5, 5), cv::Size(-1, -1), criteria);
      cv::cornerSubPix(reference, b, cv::Size(5, 5), cv::Size(-1, -1), criteria);
      sum_sq += std::pow(a[0].x - b[0].x, 2) + std::pow(a[0].y - b[0].y, 2);
      sum_truth_sq += std::pow(b[0].x - (px.x() - x0), 2) + std::pow(b[0].y - (px.y() - y0), 2);
      ++n;
    }
  }
  const double rms = std::sqrt(sum_sq / n);
  std::printf("[ figures  ] renderer vs 16x16-supersampled reference (cornerSubPix on both, no blur, "
              "%d corners): RMS difference %.4f px; cornerSubPix on the reference vs truth %.4f px\n",
              n, rms, std::sqrt(sum_truth_sq / n));
  EXPECT_LE(rms, 0.01);
  // The reference itself against OpenCV's projection of the corner: within cornerSubPix's own
  // error floor on sharp edges (see above), with a margin.
  EXPECT_LE(std::sqrt(sum_truth_sq / n), 0.1);
}

// A single fronto-parallel textured plane at z and an ideal rectified pair (no distortion,
// identity rotation): the right image must be the left shifted by fx * B / z.
SimRigConfig planeTestConfig(double z) {
  SimRigConfig c = defaultConfig();
  for (PinholeCamera* cam : {&c.rig.left, &c.rig.right}) {
    cam->fx = cam->fy = 650.0;
    cam->cx = 375.5;
    cam->cy = 239.5;
    cam->dist = {{0, 0, 0, 0, 0}};
  }
  c.rig.right_from_left = Eigen::Isometry3d::Identity();
  c.rig.right_from_left.translation() = Eigen::Vector3d(-0.12, 0, 0);
  ScenePlane plane;
  plane.origin = Eigen::Vector3d(-4.0, -3.0, z);
  plane.width_m = 8.0;
  plane.height_m = 6.0;
  plane.texel_m = 0.006;
  plane.texture_seed = 5;
  c.scene.planes = {plane};
  c.noise_sigma = 0.0;
  return c;
}

// Sub-pixel shift d minimising sum (left(u) - right(u - d))^2 over a region, with linear
// interpolation of the right image; coarse integer search, then a fine scan.
double measureDisparity(const cv::Mat& left, const cv::Mat& right, const cv::Rect& roi) {
  cv::Mat L, R;
  left.convertTo(L, CV_64F);
  right.convertTo(R, CV_64F);
  auto ssd = [&](double d) {
    double s = 0.0;
    for (int v = roi.y; v < roi.y + roi.height; ++v)
      for (int u = roi.x; u < roi.x + roi.width; ++u) {
        const double x = u - d;
        const int x0 = static_cast<int>(std::floor(x));
        const double f = x - x0;
        const double r = (1 - f) * R.at<double>(v, x0) + f * R.at<double>(v, x0 + 1);
        const double e = L.at<double>(v, u) - r;
        s += e * e;
      }
    return s;
  };
  int best_int = 0;
  double best = std::numeric_limits<double>::infinity();
  for (int d = 0; d < 80; ++d) {
    const double s = ssd(d);
    if (s < best) best = s, best_int = d;
  }
  double best_d = best_int;
  for (double d = best_int - 1.0; d <= best_int + 1.0; d += 0.002) {
    const double s = ssd(d);
    if (s < best) best = s, best_d = d;
  }
  return best_d;
}

TEST(SimRig, DepthAgreesWithRenderedDisparity) {
  const double z = 2.1;
  const SimRig rig(planeTestConfig(z));
  const SimFrame frame = rig.render(0.0, 0.0, 3);
  double min_depth, max_depth;
  cv::minMaxLoc(frame.left_depth, &min_depth, &max_depth);
  std::printf("[ figures  ] plane at %.3f m: left_depth in [%.6f, %.6f] m\n", z, min_depth, max_depth);
  EXPECT_NEAR(min_depth, z, 1e-4);
  EXPECT_NEAR(max_depth, z, 1e-4);
  const double expected = 650.0 * 0.12 / z;
  const double measured = measureDisparity(frame.left_scene, frame.right_scene, cv::Rect(150, 100, 450, 280));
  std::printf("[ figures  ] disparity: expected %.3f px (fx*B/z), measured %.3f px (error %.3f px)\n",
              expected, measured, measured - expected);
  EXPECT_NEAR(measured, expected, 0.1);
}

TEST(SimRig, DefaultSceneCoversEveryPixelWithinRange) {
  const SimRig rig(defaultConfig());
  const SimFrame frame = rig.render(0.0, 0.0, 3);
  double min_depth, max_depth;
  cv::minMaxLoc(frame.left_depth, &min_depth, &max_depth);
  std::printf("[ figures  ] default scene depth range [%.2f, %.2f] m\n", min_depth, max_depth);
  EXPECT_GE(min_depth, 1.5);
  EXPECT_LE(max_depth, 10.0);
  EXPECT_EQ(cv::countNonZero(frame.right_scene == 0), 0);
}

TEST(SimRig, ObservationsAreTheProjectedTruth) {
  const SimRig rig(defaultConfig());
  const SimFrame frame = rig.render(0.5, 1.0, 7);
  EXPECT_DOUBLE_EQ(frame.observations.stamp, 0.5);
  const auto& boards = rig.virtualBoards();
  ASSERT_EQ(boards.size(), 6u);
  for (int side = 0; side < 2; ++side) {
    const auto& seen = side == 0 ? frame.observations.left : frame.observations.right;
    ASSERT_EQ(seen.size(), 6u) << "camera " << side;
    for (size_t k = 0; k < seen.size(); ++k) {
      const BoardCorners& b = seen[k];
      ASSERT_EQ(b.board_id, static_cast<int>(k));
      const VirtualBoard& vb = boards[k];
      ASSERT_EQ(vb.virtual_id, b.board_id);
      ASSERT_EQ(static_cast<int>(b.size()), vb.cornerCount()) << "every corner visible";
      for (size_t i = 0; i < b.size(); ++i) {
        EXPECT_EQ(b.corner_ids[i], static_cast<int>(i));
        Eigen::Vector3d p = vb.cornerInRig(b.corner_ids[i]);
        if (side == 1) p = frame.truth.right_from_left * p;
        ASSERT_GT(p.z(), 0.0);
        const Eigen::Vector2d px = opencvProject(side == 0 ? frame.truth.left : frame.truth.right, p);
        EXPECT_NEAR(px.x(), b.u[i], 1e-3);
        EXPECT_NEAR(px.y(), b.v[i], 1e-3);
      }
    }
  }
  // Geometric truth does not depend on the light.
  const SimFrame dark = rig.render(0.5, 0.0, 7);
  EXPECT_EQ(dark.observations.cornerCount(), frame.observations.cornerCount());
}

TEST(SimRig, DriftChangesTruthAndObservations) {
  SimRig rig(defaultConfig());
  const StereoRig nominal = rig.config().rig;
  const SimFrame before = rig.render(1.0, 1.0, 1);

  DriftRequest zoom;
  zoom.focal_scale = 1.05;
  ASSERT_EQ(rig.setDrift(zoom), "");
  StereoRig t = rig.truthAt(1.0);
  EXPECT_NEAR(t.left.fx, 1.05 * nominal.left.fx, 1e-9);
  EXPECT_NEAR(t.right.fy, 1.05 * nominal.right.fy, 1e-9);
  EXPECT_NEAR(t.left.cx, nominal.left.cx, 1e-12);

  DriftRequest turn;  // absolute: replaces the zoom
  turn.right_rotation_deg = Eigen::Vector3d(0, 0.3, 0);
  ASSERT_EQ(rig.setDrift(turn, 1.0), "");
  t = rig.truthAt(1.0);
  EXPECT_NEAR(t.left.fx, nominal.left.fx, 1e-9);
  EXPECT_NEAR(rotationAngleDeg(nominal.right_from_left.linear(), t.right_from_left.linear()), 0.3, 1e-9);
  // The right camera turned about its own centre: the centre in the rig frame stays.
  EXPECT_LT((t.leftFromRight().translation() - nominal.leftFromRight().translation()).norm(), 1e-12);
  const SimFrame turned = rig.render(1.0, 1.0, 1);
  // A 0.3 deg turn about y moves right-image points by about fx * 0.3 deg (~3.4 px) in u.
  const double du = turned.observations.right[0].u[0] - before.observations.right[0].u[0];
  std::printf("[ figures  ] right corner shift after a 0.3 deg turn: %.3f px\n", du);
  EXPECT_NEAR(std::abs(du), nominal.right.fx * 0.3 * M_PI / 180.0, 0.5);
  EXPECT_FLOAT_EQ(turned.observations.left[0].u[0], before.observations.left[0].u[0]);

  DriftRequest knock;
  knock.knock_translation_m = Eigen::Vector3d(0.002, 0, 0);
  ASSERT_EQ(rig.setDrift(knock, 1.0), "");
  ASSERT_EQ(rig.setDrift(knock, 1.0), "");  // a second knock adds again; the turn is replaced
  t = rig.truthAt(1.0);
  EXPECT_NEAR((t.right_from_left.translation() - nominal.right_from_left.translation()).x(), 0.004, 1e-12);
  EXPECT_NEAR(rotationAngleDeg(nominal.right_from_left.linear(), t.right_from_left.linear()), 0.0, 1e-9);

  DriftRequest thermal;
  thermal.thermal_rate_deg_per_s = 0.1;
  ASSERT_EQ(rig.setDrift(thermal, 2.0), "");
  t = rig.truthAt(4.0);
  Eigen::Matrix3d knocked_rotation = nominal.right_from_left.linear();
  EXPECT_NEAR(rotationAngleDeg(knocked_rotation, t.right_from_left.linear()), 0.2, 1e-9);

  DriftRequest bad;
  bad.focal_scale = 0.0;
  EXPECT_NE(rig.setDrift(bad), "");
  EXPECT_NEAR(rotationAngleDeg(knocked_rotation, rig.truthAt(4.0).right_from_left.linear()), 0.2, 1e-9);

  DriftRequest reset;
  reset.reset = true;
  ASSERT_EQ(rig.setDrift(reset), "");
  t = rig.truthAt(10.0);
  EXPECT_TRUE(t.right_from_left.isApprox(nominal.right_from_left, 1e-12));
  EXPECT_DOUBLE_EQ(t.right.fx, nominal.right.fx);
  const SimFrame after = rig.render(10.0, 1.0, 1);
  EXPECT_FLOAT_EQ(after.observations.right[0].u[0], before.observations.right[0].u[0]);
  EXPECT_EQ(cv::norm(after.right, before.right, cv::NORM_INF), 0.0);
}

// setDrift() on another thread while frames render: every frame must be consistent with the
// truth it reports (render() works on one snapshot of the drift state).
TEST(SimRig, DriftFromAnotherThreadKeepsFramesConsistent) {
  SimRig rig(cornerTestConfig());  // no scene texture or noise around the measured corner
  std::atomic<bool> done{false};
  std::thread driver([&] {
    for (int i = 0; !done; ++i) {
      DriftRequest r;
      r.right_rotation_deg = Eigen::Vector3d(0, (i % 2) ? 0.5 : -0.5, 0);
      EXPECT_EQ(rig.setDrift(r), "");
      std::this_thread::sleep_for(std::chrono::microseconds(300));
    }
  });
  int turned_frames = 0;
  for (int k = 0; k < 20; ++k) {
    const SimFrame f = rig.render(k / 30.0, 1.0, k);
    const double angle = rotationAngleDeg(rig.config().rig.right_from_left.linear(), f.truth.right_from_left.linear());
    turned_frames += angle > 0.25;
    const VirtualBoard& vb = rig.virtualBoards()[0];
    const Eigen::Vector2d px = opencvProject(f.truth.right, f.truth.right_from_left * vb.cornerInRig(0));
    ASSERT_FALSE(f.observations.right.empty());
    EXPECT_NEAR(f.observations.right[0].u[0], px.x(), 1e-3);
    // The rendered right image shows the corner where the frame's truth puts it.
    cv::Mat img;
    f.right.convertTo(img, CV_32F);
    const cv::Point2d c = symmetricCorner(img, cv::Point2d(px.x() + 0.3, px.y() - 0.2), 5);
    EXPECT_LT(std::hypot(c.x - px.x(), c.y - px.y()), 0.1) << "frame " << k;
  }
  done = true;
  driver.join();
  EXPECT_GT(turned_frames, 0);
}

TEST(SimRig, RenderingIsDeterministicAndLightOffShowsNoBoards) {
  const SimRig rig(defaultConfig());
  const SimFrame a = rig.render(0.0, 1.0, 42), b = rig.render(0.0, 1.0, 42), c = rig.render(0.0, 1.0, 43);
  EXPECT_EQ(cv::norm(a.left, b.left, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(a.right, b.right, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(a.left, c.left, cv::NORM_INF), 0.0);

  // Where the lit device is white / black (from a noise-free scene-free render).
  SimRigConfig pattern_config = defaultConfig();
  pattern_config.scene.enabled = false;
  pattern_config.noise_sigma = 0.0;
  const SimFrame pattern = SimRig(pattern_config).render(0.0, 1.0, 1);
  const cv::Mat white = pattern.left > 100, black = pattern.left < 10;

  for (double light : {0.0, 1.0}) {
    const SimFrame f = rig.render(0.0, light, 9);
    cv::Mat diff;
    cv::subtract(f.left, f.left_scene, diff, cv::noArray(), CV_32F);
    const double on_white = cv::mean(diff, white)[0], on_black = cv::mean(diff, black)[0];
    std::printf("[ figures  ] light %.0f: image - t*scene on white squares %.2f, on black %.2f\n", light,
                on_white, on_black);
    if (light == 0.0) {
      cv::Scalar mean, stddev;
      cv::meanStdDev(diff, mean, stddev);
      EXPECT_NEAR(mean[0], 0.0, 0.05);
      EXPECT_NEAR(stddev[0], std::sqrt(1.0 + 1.0 / 12.0), 0.1) << "noise_sigma 1 plus rounding";
      EXPECT_NEAR(on_white - on_black, 0.0, 0.2);
    } else {
      EXPECT_GT(on_white - on_black, 0.5 * 0.9 * 255.0 - 5.0);
    }
  }
}

// Pearson correlation of two equally sized CV_32F images.
double correlation(const cv::Mat& a, const cv::Mat& b) {
  cv::Scalar ma, sa, mb, sb;
  cv::meanStdDev(a, ma, sa);
  cv::meanStdDev(b, mb, sb);
  return (cv::mean((a - ma[0]).mul(b - mb[0]))[0]) / (sa[0] * sb[0]);
}

TEST(SimRig, SensorNoiseIsWhiteAcrossPixelsRowsAndFrames) {
  // The noise is drawn per band of rows from a stream of its own: each row must be independent
  // of its neighbours, of the rows a band (16 rows) away, and of the same row in another frame.
  SimRigConfig config = defaultConfig();
  config.noise_sigma = 8.0;  // well above the rounding to 8 bit
  const SimRig rig(config);
  std::vector<cv::Mat> noise;
  for (uint64_t seed : {11, 12, 13}) {
    const SimFrame f = rig.render(0.0, 0.0, seed);
    cv::Mat n;
    cv::subtract(f.left, f.left_scene, n, cv::noArray(), CV_32F);
    noise.push_back(n(cv::Rect(0, 0, n.cols, n.rows)).clone());
  }
  const cv::Mat& n = noise[0];
  cv::Scalar mean, stddev;
  cv::meanStdDev(n, mean, stddev);
  const int W = n.cols, H = n.rows;
  const double along_row = correlation(n.colRange(0, W - 1), n.colRange(1, W));
  const double across_rows = std::max(std::abs(correlation(n.rowRange(0, H - 1), n.rowRange(1, H))),
                                      std::abs(correlation(n.rowRange(0, H - 16), n.rowRange(16, H))));
  const double across_frames = std::max(std::abs(correlation(noise[0], noise[1])), std::abs(correlation(noise[1], noise[2])));
  const double within_one_sigma = cv::countNonZero(cv::abs(n - mean[0]) <= 8.0) / static_cast<double>(n.total());
  std::printf("[ figures  ] noise: mean %.3f sd %.3f; correlation along rows %.4f, across rows (1 or 16) %.4f, across "
              "frames %.4f; within 1 sigma %.4f\n", mean[0], stddev[0], along_row, across_rows, across_frames,
              within_one_sigma);
  EXPECT_NEAR(mean[0], 0.0, 0.1);
  EXPECT_NEAR(stddev[0], std::sqrt(64.0 + 1.0 / 12.0), 0.1);
  EXPECT_LT(std::abs(along_row), 0.01);
  EXPECT_LT(across_rows, 0.01);
  EXPECT_LT(across_frames, 0.01);
  EXPECT_NEAR(within_one_sigma, 0.6827, 0.01) << "normal, not another distribution";
}

std::string writeVariant(const std::string& from, const std::string& to, const std::string& name) {
  std::ifstream in(kDefaultConfig);
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  const std::string path = ::testing::TempDir() + name;
  std::ofstream(path) << text;
  return path;
}

std::string loadError(const std::string& path) {
  try {
    loadSimRigConfig(path);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(SimRigConfig, LoadsDefaultFile) {
  const SimRigConfig c = defaultConfig();
  EXPECT_EQ(c.validate(), "");
  EXPECT_EQ(c.rig.left.width, 752);
  EXPECT_EQ(c.rig.left.height, 480);
  EXPECT_NEAR(c.rig.baseline(), 0.12, 0.005);
  EXPECT_EQ(c.device.boards.size(), 3u);
  EXPECT_EQ(c.device.copies.size(), 2u);
  EXPECT_GE(c.scene.planes.size(), 5u);
  EXPECT_DOUBLE_EQ(c.optics.transmittance, 0.5);
  EXPECT_EQ(c.encoding, "mono8");
}

TEST(SimRigConfig, ErrorsNameTheParameter) {
  EXPECT_NE(loadError("/nonexistent/sim_rig.yaml").find("/nonexistent/sim_rig.yaml"), std::string::npos);
  const std::string fx = loadError(writeVariant("fx: 652.4", "fx: -3.0", "sim_bad_fx.yaml"));
  EXPECT_NE(fx.find("rig.left.fx"), std::string::npos) << fx;
  const std::string t = loadError(writeVariant("transmittance: 0.5", "transmittance: 1.5", "sim_bad_t.yaml"));
  EXPECT_NE(t.find("optics.transmittance"), std::string::npos) << t;
  const std::string enc = loadError(writeVariant("encoding: \"mono8\"", "encoding: rgb16", "sim_bad_enc.yaml"));
  EXPECT_NE(enc.find("encoding"), std::string::npos) << enc;
  const std::string texel = loadError(writeVariant("texel_m: 0.02", "texel_m: 0.0", "sim_bad_texel.yaml"));
  EXPECT_NE(texel.find("scene.planes[0].texel_m"), std::string::npos) << texel;

  SimRigConfig c = defaultConfig();
  c.optics.reflectance = -0.1;
  EXPECT_NE(c.validate().find("optics.reflectance"), std::string::npos);
  EXPECT_EQ(c.problem().parameter, "optics.reflectance");
  try {
    SimRig rig(c);
    ADD_FAILURE() << "a negative reflectance was accepted";
  } catch (const ConfigError& e) {
    EXPECT_EQ(e.parameter(), "optics.reflectance") << e.what();  // carried, not cut from the text
  }
}

TEST(SimRig, BgrEncodingReplicatesChannels) {
  SimRigConfig c = defaultConfig();
  c.encoding = "bgr8";
  const SimFrame f = SimRig(c).render(0.0, 1.0, 1);
  ASSERT_EQ(f.left.type(), CV_8UC3);
  ASSERT_EQ(f.right_scene.type(), CV_8UC3);
  std::vector<cv::Mat> ch;
  cv::split(f.left, ch);
  EXPECT_EQ(cv::norm(ch[0], ch[2], cv::NORM_INF), 0.0);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
