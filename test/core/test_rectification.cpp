// Rectification against ground truth: points projected through the true (distorted) rig must
// land on the same rectified row in both images, their rectified disparity must give the true
// depth through Q, and the fixed-point remap tables must agree with cv::undistortPoints.
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "embedded_calibration_stereo/core/depth/rectification.h"

namespace embedded_calibration_stereo::core {
namespace {

// A head like the original one: 752x480, strong barrel distortion, 12 cm baseline, the right
// camera rotated by about one degree.
StereoRig testRig() {
  StereoRig rig;
  rig.left.width = rig.right.width = 752;
  rig.left.height = rig.right.height = 480;
  rig.left.fx = 650;
  rig.left.fy = 651;
  rig.left.cx = 379;
  rig.left.cy = 236;
  rig.left.dist = {-0.28, 0.07, 0.0004, -0.0003, 0};
  rig.right.fx = 655;
  rig.right.fy = 654;
  rig.right.cx = 372;
  rig.right.cy = 243;
  rig.right.dist = {-0.27, 0.068, -0.0002, 0.0005, 0};
  rig.right_from_left.linear() = rotationFromVectorDeg(Eigen::Vector3d(0.4, -0.8, 0.5));
  rig.right_from_left.translation() = Eigen::Vector3d(-0.12, 0.002, -0.001);
  return rig;
}

struct Correspondences {
  std::vector<cv::Point2d> left, right;  // raw pixels
  std::vector<double> depth_left;        // z in the left optical frame
  std::vector<cv::Point3d> points_left;
};

// Random points 1.2-10 m in front, projected with OpenCV (independent of the code under test).
Correspondences projectRandomPoints(const StereoRig& rig, int count, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> z_dist(1.2, 10.0), u_dist(-0.5, 0.5);
  Correspondences c;
  const cv::Matx33d K1 = cameraMatrix(rig.left), K2 = cameraMatrix(rig.right);
  cv::Matx33d R;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) R(r, k) = rig.right_from_left.linear()(r, k);
  cv::Vec3d rvec;
  cv::Rodrigues(R, rvec);
  const Eigen::Vector3d t = rig.right_from_left.translation();
  while (static_cast<int>(c.left.size()) < count) {
    const double z = z_dist(rng);
    const cv::Point3d p(u_dist(rng) * z * 1.1, u_dist(rng) * z * 0.7, z);
    std::vector<cv::Point2d> l, r;
    cv::projectPoints(std::vector<cv::Point3d>{p}, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K1,
                      distortionVector(rig.left), l);
    cv::projectPoints(std::vector<cv::Point3d>{p}, rvec, cv::Vec3d(t.x(), t.y(), t.z()), K2,
                      distortionVector(rig.right), r);
    const auto inside = [&](const cv::Point2d& q) {
      return q.x >= 5 && q.y >= 5 && q.x <= rig.left.width - 6 && q.y <= rig.left.height - 6;
    };
    if (!inside(l[0]) || !inside(r[0])) continue;
    c.left.push_back(l[0]);
    c.right.push_back(r[0]);
    c.depth_left.push_back(z);
    c.points_left.push_back(p);
  }
  return c;
}

std::vector<cv::Point2d> rectifyPoints(const std::vector<cv::Point2d>& raw,
                                       const PinholeCamera& cam, const cv::Matx33d& R,
                                       const cv::Matx34d& P) {
  std::vector<cv::Point2d> out;
  cv::undistortPoints(raw, out, cameraMatrix(cam), distortionVector(cam), R, P,
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-12));
  return out;
}

class RectificationTest : public ::testing::TestWithParam<RectificationMethod> {};

TEST_P(RectificationTest, RowsAgreeAndDepthFromQ) {
  const StereoRig rig = testRig();
  RectificationOptions options;
  options.method = GetParam();
  const RectificationGeometry g = computeRectificationGeometry(rig, options);
  const Correspondences c = projectRandomPoints(rig, 500, 7);
  const auto l = rectifyPoints(c.left, rig.left, g.R1, g.P1);
  const auto r = rectifyPoints(c.right, rig.right, g.R2, g.P2);

  double sum_sq = 0;
  for (size_t i = 0; i < l.size(); ++i) sum_sq += (l[i].y - r[i].y) * (l[i].y - r[i].y);
  const double vertical_rms = std::sqrt(sum_sq / l.size());
  std::printf("[ %s ] vertical disparity RMS %.2e px over %zu points\n",
              toString(GetParam()).c_str(), vertical_rms, l.size());
  EXPECT_LE(vertical_rms, 0.1);

  // Depth through Q: the rectified frame is the left frame rotated by R1, so compare ranges.
  int checked = 0;
  for (size_t i = 0; i < l.size(); ++i) {
    const double d = l[i].x - r[i].x;
    ASSERT_GT(d, 0) << "disparity must be positive for points in front";
    const cv::Vec4d X = g.Q * cv::Vec4d(l[i].x, l[i].y, d, 1.0);
    const cv::Vec3d p(X[0] / X[3], X[1] / X[3], X[2] / X[3]);
    const double range_true = cv::norm(c.points_left[i]);
    const double range = cv::norm(p);
    const double rel = std::abs(range - range_true) / range_true;
    if (c.depth_left[i] < 2.5) {
      EXPECT_LE(rel, 0.001) << "point " << i << " at z " << c.depth_left[i];
      ++checked;
    }
    EXPECT_LE(rel, 0.001);
  }
  EXPECT_GT(checked, 10);
  EXPECT_NEAR(g.baseline(), rig.baseline(), 1e-9);
}

TEST_P(RectificationTest, FixedPointMapsAgreeWithUndistortPoints) {
  const StereoRig rig = testRig();
  RectificationOptions options;
  options.method = GetParam();
  const RectificationMaps maps = RectificationMaps::build(rig, options);
  ASSERT_EQ(maps.leftMap1().type(), CV_16SC2);
  ASSERT_EQ(maps.leftMap2().type(), CV_16UC1);
  const RectificationGeometry& g = maps.geometry();
  for (int side = 0; side < 2; ++side) {
    const PinholeCamera& cam = side == 0 ? rig.left : rig.right;
    cv::Mat mx, my;
    cv::convertMaps(side == 0 ? maps.leftMap1() : maps.rightMap1(),
                    side == 0 ? maps.leftMap2() : maps.rightMap2(), mx, my, CV_32FC1);
    std::vector<cv::Point2d> rect_px, raw_px;
    for (int v = 10; v < g.size.height - 10; v += 23)
      for (int u = 10; u < g.size.width - 10; u += 29) {
        const cv::Point2d raw(mx.at<float>(v, u), my.at<float>(v, u));
        if (raw.x < 0 || raw.y < 0 || raw.x > cam.width - 1 || raw.y > cam.height - 1) continue;
        rect_px.emplace_back(u, v);
        raw_px.push_back(raw);
      }
    ASSERT_GT(rect_px.size(), 300u);
    const auto back = rectifyPoints(raw_px, cam, side == 0 ? g.R1 : g.R2,
                                    side == 0 ? g.P1 : g.P2);
    double worst = 0;
    for (size_t i = 0; i < back.size(); ++i) worst = std::max(worst, cv::norm(back[i] - rect_px[i]));
    std::printf("[ %s ] %s map vs undistortPoints: worst %.4f px\n", toString(GetParam()).c_str(),
                side == 0 ? "left" : "right", worst);
    EXPECT_LE(worst, 0.05);
  }
}

TEST_P(RectificationTest, RectifiedImagesKeepRowCorrespondence) {
  // A vertical-gradient scene at infinity-free depth: remapping must move the image content of a
  // projected point to its rectified position. Check with a bright dot rendered in the raw image.
  const StereoRig rig = testRig();
  RectificationOptions options;
  options.method = GetParam();
  const RectificationMaps maps = RectificationMaps::build(rig, options);
  const Correspondences c = projectRandomPoints(rig, 1, 3);
  cv::Mat left(480, 752, CV_32F, cv::Scalar(0)), right = left.clone();
  const auto blob = [](cv::Mat& img, cv::Point2d q) {
    for (int y = 0; y < img.rows; ++y)
      for (int x = 0; x < img.cols; ++x) {
        const double r2 = (x - q.x) * (x - q.x) + (y - q.y) * (y - q.y);
        img.at<float>(y, x) = static_cast<float>(std::exp(-r2 / (2 * 2.0 * 2.0)));
      }
  };
  blob(left, c.left[0]);
  blob(right, c.right[0]);
  const auto [lr, rr] = maps.rectify(left, right);
  const auto centroid = [](const cv::Mat& img) {
    const cv::Moments m = cv::moments(img);
    return cv::Point2d(m.m10 / m.m00, m.m01 / m.m00);
  };
  const cv::Point2d cl = centroid(lr), cr = centroid(rr);
  const auto expected_l = rectifyPoints(c.left, rig.left, maps.geometry().R1, maps.geometry().P1);
  // The blob is slightly warped by the distortion, so its centroid moves a little: 0.2 px.
  EXPECT_NEAR(cl.x, expected_l[0].x, 0.2);
  EXPECT_NEAR(cl.y, expected_l[0].y, 0.2);
  EXPECT_NEAR(cl.y, cr.y, 0.2);
  cv::Mat l_out, r_out;
  EXPECT_THROW(maps.rectify(cv::Mat(10, 10, CV_8U), right, &l_out, &r_out), std::invalid_argument);
  EXPECT_THROW(maps.rectify(left, right, &left, &r_out), std::invalid_argument);
}

INSTANTIATE_TEST_SUITE_P(BothMethods, RectificationTest,
                         ::testing::Values(RectificationMethod::kBouguet,
                                           RectificationMethod::kFusiello),
                         [](const ::testing::TestParamInfo<RectificationMethod>& info) {
                           return toString(info.param);
                         });

// The pair remap (the Rectifier nodelet's, into the outgoing messages' buffers) equals
// cv::remap of each image alone, bit for bit, and writes into preallocated outputs in place,
// whatever the number of threads.
TEST(RemapStereoPairTest, EqualsRemapOfEachImageWrittenInPlace) {
  const RectificationMaps maps = RectificationMaps::build(testRig(), RectificationOptions());
  cv::Mat left(480, 752, CV_8U), right(480, 752, CV_8U);
  cv::RNG rng(5);
  rng.fill(left, cv::RNG::UNIFORM, 0, 256);
  rng.fill(right, cv::RNG::UNIFORM, 0, 256);
  cv::Mat expected_left, expected_right;
  cv::remap(left, expected_left, maps.leftMap1(), maps.leftMap2(), cv::INTER_LINEAR,
            cv::BORDER_CONSTANT);
  cv::remap(right, expected_right, maps.rightMap1(), maps.rightMap2(), cv::INTER_LINEAR,
            cv::BORDER_CONSTANT);
  const auto remapPair = [&](cv::Mat* left_out, cv::Mat* right_out) {
    remapStereoPair(left, right, maps.leftMap1(), maps.leftMap2(), maps.rightMap1(),
                    maps.rightMap2(), left_out, right_out);
  };
  const int threads = cv::getNumThreads();
  for (const int n : {1, 2, 4}) {
    cv::setNumThreads(n);
    cv::Mat left_out(left.size(), CV_8U, cv::Scalar(7));
    cv::Mat right_out(right.size(), CV_8U, cv::Scalar(7));
    const uchar* left_buffer = left_out.data;
    const uchar* right_buffer = right_out.data;
    remapPair(&left_out, &right_out);
    EXPECT_EQ(left_out.data, left_buffer) << n << " threads: not written in place";
    EXPECT_EQ(right_out.data, right_buffer) << n << " threads: not written in place";
    EXPECT_EQ(cv::norm(left_out, expected_left, cv::NORM_INF), 0) << n << " threads";
    EXPECT_EQ(cv::norm(right_out, expected_right, cv::NORM_INF), 0) << n << " threads";
  }
  cv::setNumThreads(threads);
  // Empty outputs are allocated.
  cv::Mat left_new, right_new;
  remapPair(&left_new, &right_new);
  EXPECT_EQ(cv::norm(left_new, expected_left, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(right_new, expected_right, cv::NORM_INF), 0);
}

TEST(RectificationGeometryTest, FusielloGivesBothCamerasTheSameIntrinsics) {
  RectificationOptions options;
  options.method = RectificationMethod::kFusiello;
  const RectificationGeometry g = computeRectificationGeometry(testRig(), options);
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) EXPECT_DOUBLE_EQ(g.P1(r, k), g.P2(r, k));
  EXPECT_NEAR(g.P2(0, 3), -g.P2(0, 0) * testRig().baseline(), 1e-9);
}

TEST(RectificationGeometryTest, RejectsBadInput) {
  StereoRig rig = testRig();
  rig.right_from_left.translation().setZero();
  EXPECT_THROW(computeRectificationGeometry(rig, RectificationOptions()), std::invalid_argument);
  EXPECT_THROW(parseRectificationMethod("loop"), std::invalid_argument);
  rig = testRig();
  rig.right_from_left.translation().x() = 0.12;  // "right" camera on the left
  RectificationOptions fusiello;
  fusiello.method = RectificationMethod::kFusiello;
  EXPECT_THROW(computeRectificationGeometry(rig, fusiello), std::invalid_argument);
  EXPECT_EQ(parseRectificationMethod("fusiello"), RectificationMethod::kFusiello);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
