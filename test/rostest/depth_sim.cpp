// rostest: Rectifier + Disparity on the simulated driver (depth_sim.test).
#include <gtest/gtest.h>
#include <image_geometry/stereo_camera_model.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/SetCameraInfo.h>

#include <algorithm>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "depth_test_utils.h"
#include "embedded_calibration_stereo/DisparityCoverage.h"
#include "driver_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using sensor_msgs::CameraInfo;
using sensor_msgs::Image;
using stereo_msgs::DisparityImage;

TEST(DepthSim, ImageRectHasTheRawHeaderAndEncoding) {
  ros::NodeHandle nh;
  Collector<Image> raw(nh, "left/image_raw", 50), left(nh, "left/image_rect"), right(nh, "right/image_rect");
  // The test's image_raw subscription may connect after the Rectifier's: wait for a rectified
  // frame whose raw frame this test received too.
  Image::ConstPtr rect, source;
  ASSERT_TRUE(left.waitFor(
      [&](const std::vector<Image::ConstPtr>& rects) {
        for (const auto& r : rects)
          if ((source = test_support::findByStamp(raw.snapshot(), r->header.stamp))) {
            rect = r;
            return true;
          }
        return false;
      },
      20.0))
      << "no left/image_rect whose stamp matches a received left/image_raw (" << left.snapshot().size()
      << " image_rect, " << raw.snapshot().size() << " image_raw received)";
  ASSERT_TRUE(right.waitForCount(1, 5.0)) << "no right/image_rect";
  EXPECT_EQ(rect->header.frame_id, source->header.frame_id);
  EXPECT_EQ(rect->encoding, source->encoding);
  EXPECT_EQ(rect->width, source->width);
  EXPECT_EQ(rect->height, source->height);
  EXPECT_NE(rect->data, source->data) << "image_rect is not rectified";
  EXPECT_EQ(right.snapshot().back()->header.frame_id, source->header.frame_id);
}

// disparity_coverage: the fraction of the image's pixels with a disparity, counted here.
void expectCoverageCounted(const DisparityImage& disp, const embedded_calibration_stereo::DisparityCoverage& coverage) {
  const float* d = reinterpret_cast<const float*>(disp.image.data.data());
  const size_t n = disp.image.width * disp.image.height;
  const size_t valid = std::count_if(d, d + n, [&](float v) { return v >= disp.min_disparity; });
  EXPECT_NEAR(coverage.valid_fraction, double(valid) / n, 1e-6);
  EXPECT_GT(coverage.valid_fraction, 0.5);
}

// disparity_mask: mono8 of the disparity's stamp and size; mostly matched, and the left border
// (where the right camera cannot see) marked hidden (census_sgm, the default).
void expectMaskOfDisparity(Collector<Image>& masks, const DisparityImage& disp) {
  Image::ConstPtr mask;
  ASSERT_TRUE(masks.waitFor(
      [&](const std::vector<Image::ConstPtr>& m) {
        mask = test_support::findByStamp(m, disp.header.stamp);
        return bool(mask);
      },
      5.0))
      << "no disparity_mask with the disparity's stamp";
  EXPECT_EQ(mask->encoding, "mono8");
  EXPECT_EQ(mask->width, disp.image.width);
  EXPECT_EQ(mask->height, disp.image.height);
  const auto count = [&](uint8_t v) { return std::count(mask->data.begin(), mask->data.end(), v); };
  EXPECT_GT(double(count(255)) / mask->data.size(), 0.5);
  EXPECT_GT(count(128), 0) << "nothing marked hidden from the right camera";
  EXPECT_EQ(count(255) + count(128) + count(0), static_cast<long>(mask->data.size()));
}

// The DisparityImage's fields against the stereo model of its camera_infos.
void expectDisparityFields(const DisparityImage& disp, const image_geometry::StereoCameraModel& model,
                           const CameraInfo& left) {
  EXPECT_FLOAT_EQ(disp.f, model.right().fx());
  EXPECT_NEAR(disp.T, model.baseline(), 1e-6);
  EXPECT_GT(disp.T, 0.05);
  EXPECT_EQ(disp.min_disparity, 0.0f);
  EXPECT_EQ(disp.max_disparity, 63.0f);
  EXPECT_GT(disp.delta_d, 0.0f);
  EXPECT_EQ(disp.image.encoding, "32FC1");
  EXPECT_EQ(disp.image.width, left.width);
  const auto& w = disp.valid_window;
  EXPECT_GT(w.width, left.width / 2);
  EXPECT_GT(w.height, left.height / 2);
  EXPECT_LE(w.x_offset + w.width, left.width);
  EXPECT_LE(w.y_offset + w.height, left.height);
  EXPECT_GE(w.x_offset, 63u) << "the leftmost max_disparity columns cannot be matched";
}

// Sampled rectified pixels with a valid disparity against the depth truth: their disparity, and
// points2's depth.
void expectAgainstTruth(const std::string& name, const DisparityImage::ConstPtr& disp, const Image::ConstPtr& truth,
                        const CameraInfo::ConstPtr& li, const image_geometry::StereoCameraModel& model,
                        const sensor_msgs::PointCloud2::ConstPtr& cloud) {
  const auto& w = disp->valid_window;
  const cv::Matx33d K(li->K.data()), R(li->R.data());
  const cv::Mat D(li->D);
  const cv::Matx44d Q = model.reprojectionMatrix();
  const cv::Mat_<float> truth_z(truth->height, truth->width, (float*)truth->data.data(), truth->step);
  const float* d_image = reinterpret_cast<const float*>(disp->image.data.data());
  sensor_msgs::PointCloud2ConstIterator<float> cloud_z(*cloud, "z");
  std::vector<double> errors, depth_errors;
  for (uint32_t v = w.y_offset; v < w.y_offset + w.height; v += 7) {
    for (uint32_t u = w.x_offset; u < w.x_offset + w.width; u += 7) {
      const double d = d_image[v * disp->image.width + u];
      if (d < disp->min_disparity) continue;
      const cv::Vec4d h = Q * cv::Vec4d(u, v, d, 1.0);
      const cv::Vec3d rect(h[0] / h[3], h[1] / h[3], h[2] / h[3]);
      const cv::Vec3d raw = R.t() * rect;
      std::vector<cv::Point2d> pixel;
      cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(raw)}, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D,
                        pixel);
      const int ru = cvRound(pixel[0].x), rv = cvRound(pixel[0].y);
      if (ru < 0 || rv < 0 || ru >= truth_z.cols || rv >= truth_z.rows) continue;
      const double z = truth_z(rv, ru);
      if (!std::isfinite(z)) continue;
      const cv::Vec3d true_rect = R * (raw * (z / raw[2]));
      const double true_d = (Q(2, 3) / true_rect[2] - Q(3, 3)) / Q(3, 2);  // Q (u, v, d, 1) has depth Z
      errors.push_back(std::abs(d - true_d));
      const float cz = *(cloud_z + (v * cloud->width + u));
      depth_errors.push_back(std::abs(cz - true_rect[2]) / true_rect[2]);
    }
  }
  ASSERT_GT(errors.size(), 500u) << "too few valid disparities";
  const double median_error = test_support::median(errors);
  const double within_1px = std::count_if(errors.begin(), errors.end(), [](double e) { return e < 1.0; }) /
                            double(errors.size());
  const double median_depth_error = test_support::median(depth_errors);
  std::printf("%s: disparity vs ground truth over %zu pixels: median |error| %.3f px, %.1f %% within 1 px; "
              "points2 median relative depth error %.4f\n",
              name.c_str(), errors.size(), median_error, 100 * within_1px, median_depth_error);
  EXPECT_LT(median_error, 0.3);
  EXPECT_GT(within_1px, 0.8);
  EXPECT_LT(median_depth_error, 0.02);
}

// Rectified-pixel disparity against the simulator's depth: each sampled rectified left pixel
// with a valid disparity is mapped to its raw pixel (R^T, then K and D of the left CameraInfo);
// the ground-truth depth there gives the true 3D point, hence the true disparity f*T/Z_rect.
// `prefix`: namespace of the pipeline; `info`: the CameraInfo its Disparity reads.
void expectDisparityMatchesGroundTruth(const std::string& prefix, const std::string& info) {
  ros::NodeHandle nh;
  Collector<DisparityImage> disparity(nh, prefix + "disparity", 20);
  Collector<sensor_msgs::PointCloud2> points(nh, prefix + "points2", 20);
  Collector<embedded_calibration_stereo::DisparityCoverage> coverages(nh, prefix + "disparity_coverage", 20);
  Collector<Image> masks(nh, prefix + "disparity_mask", 20);
  Collector<Image> depth(nh, "ground_truth/left/depth", 50);
  Collector<CameraInfo> left_info(nh, prefix + "left/" + info, 50), right_info(nh, prefix + "right/" + info, 50);
  // A disparity frame for which the depth and both CameraInfos of the same stamp arrived.
  DisparityImage::ConstPtr disp;
  Image::ConstPtr truth;
  CameraInfo::ConstPtr li, ri;
  sensor_msgs::PointCloud2::ConstPtr cloud;
  embedded_calibration_stereo::DisparityCoverage::ConstPtr coverage;
  ASSERT_TRUE(disparity.waitFor(
      [&](const std::vector<DisparityImage::ConstPtr>& m) {
        for (const auto& d : m) {
          truth = test_support::findByStamp(depth.snapshot(), d->header.stamp);
          li = test_support::findByStamp(left_info.snapshot(), d->header.stamp);
          ri = test_support::findByStamp(right_info.snapshot(), d->header.stamp);
          cloud = test_support::findByStamp(points.snapshot(), d->header.stamp);
          coverage = test_support::findByStamp(coverages.snapshot(), d->header.stamp);
          if (truth && li && ri && cloud && coverage) {
            disp = d;
            return true;
          }
        }
        return false;
      },
      20.0))
      << "no disparity frame with matching ground truth, camera_info, points2 and disparity_coverage";
  expectCoverageCounted(*disp, *coverage);
  expectMaskOfDisparity(masks, *disp);
  if (::testing::Test::HasFatalFailure()) return;
  image_geometry::StereoCameraModel model;
  ASSERT_TRUE(model.fromCameraInfo(li, ri));
  expectDisparityFields(*disp, model, *li);
  expectAgainstTruth(prefix + "disparity", disp, truth, li, model, cloud);
}

TEST(DepthSim, BouguetDisparityMatchesGroundTruthDepth) { expectDisparityMatchesGroundTruth("", "camera_info"); }

TEST(DepthSim, FusielloDisparityMatchesGroundTruthDepth) {
  expectDisparityMatchesGroundTruth("fusiello/", "camera_info_rect");
}

// After left/set_camera_info changes the calibration mid-stream, every left/image_rect equals
// the rectification of the raw image of its stamp with the CameraInfo of its stamp (bit-exact:
// the same OpenCV calls as image_proc), before and after the switch: a frame of the new
// calibration is never remapped with the old maps. Runs last: it changes the calibration.
TEST(DepthSim, EpochSwitchRectifiesEachFrameWithItsOwnCalibration) {
  ros::NodeHandle nh;
  Collector<Image> raw(nh, "left/image_raw", 300), rect(nh, "left/image_rect", 300);
  Collector<CameraInfo> info(nh, "left/camera_info", 300);
  // Three checkable frames (raw, CameraInfo and image_rect of one stamp) before the switch.
  ASSERT_TRUE(rect.waitFor(
      [&](const std::vector<Image::ConstPtr>& m) {
        int n = 0;
        const auto infos = info.snapshot();
        const auto raws = raw.snapshot();
        for (const auto& r : m)
          n += test_support::findByStamp(infos, r->header.stamp) && test_support::findByStamp(raws, r->header.stamp);
        return n >= 3;
      },
      20.0));
  sensor_msgs::SetCameraInfo srv;
  srv.request.camera_info = *info.snapshot().back();
  srv.request.camera_info.D[0] += 0.03;  // k1: moves the image corners by several pixels
  const double new_k1 = srv.request.camera_info.D[0];
  ASSERT_TRUE(ros::service::call("left/set_camera_info", srv));
  ASSERT_TRUE(srv.response.success) << srv.response.status_message;
  const auto is_new = [&](const CameraInfo::ConstPtr& i) { return i && i->D[0] == new_k1; };
  ASSERT_TRUE(rect.waitFor(
      [&](const std::vector<Image::ConstPtr>& m) {
        // Counted as below: the new calibration's image_rect whose raw image is at hand too.
        int n = 0;
        const auto infos = info.snapshot();
        const auto raws = raw.snapshot();
        for (const auto& r : m)
          n += is_new(test_support::findByStamp(infos, r->header.stamp)) &&
               test_support::findByStamp(raws, r->header.stamp) != nullptr;
        return n >= 3;
      },
      15.0))
      << "no image_rect of the new calibration";
  int old_frames = 0, new_frames = 0;
  const auto infos = info.snapshot();
  const auto raws = raw.snapshot();
  for (const auto& r : rect.snapshot()) {
    const auto i = test_support::findByStamp(infos, r->header.stamp);
    const auto source = test_support::findByStamp(raws, r->header.stamp);
    if (!i || !source) continue;
    cv::Mat map1, map2, expected;
    cv::initUndistortRectifyMap(cv::Matx33d(i->K.data()), cv::Mat(i->D), cv::Matx33d(i->R.data()),
                                cv::Matx34d(i->P.data()), cv::Size(i->width, i->height), CV_16SC2, map1, map2);
    cv::remap(cv_bridge::toCvShare(source)->image, expected, map1, map2, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    EXPECT_EQ(cv::norm(expected, cv_bridge::toCvShare(r)->image, cv::NORM_INF), 0.0)
        << "image_rect at " << r->header.stamp << " is not the rectification with its own k1 " << i->D[0];
    ++(is_new(i) ? new_frames : old_frames);
  }
  std::printf("epoch switch: %d frames checked with the old calibration, %d with the new one\n", old_frames,
              new_frames);
  EXPECT_GE(old_frames, 3);
  EXPECT_GE(new_frames, 3);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "depth_sim_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
