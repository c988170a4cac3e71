// Depth from the simulated head against the simulator's depth map: a textured frontal panel at
// exactly 2 m in front of the usual scene, light-off frames (noise on), rectified with the true
// calibration, disparity with the default settings and with each algorithm. The bound:
// median absolute depth error <= 1 % at 2 m.
#include <gtest/gtest.h>

#include <algorithm>
#include <opencv2/calib3d.hpp>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {
namespace {

constexpr double kPanelDepth = 2.0;

// The sim's scene plus a 1.2 m x 0.8 m textured panel facing the cameras at z = 2 m, centred
// between them (texel 5 mm, ~1.6 px at 2 m, like the other planes).
SimRigConfig withPanelAtTwoMetres() {
  SimRigConfig config = loadSimRigConfig(std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml");
  ScenePlane panel;
  panel.origin = Eigen::Vector3d(-0.54, -0.4, kPanelDepth);
  panel.u_axis = Eigen::Vector3d::UnitX();
  panel.v_axis = Eigen::Vector3d::UnitY();
  panel.width_m = 1.2;
  panel.height_m = 0.8;
  panel.texture_seed = 31;
  panel.texel_m = 0.005;
  config.scene.planes.push_back(panel);
  return config;
}

struct DepthErrors {
  int panel_pixels = 0;  // rectified left pixels that see the panel
  int valid = 0;         // ... with an output disparity
  double median_rel = 0.0, p90_rel = 0.0;
  double validFraction() const { return panel_pixels ? double(valid) / panel_pixels : 0.0; }
};

// Relative depth errors |z - z_true| / z_true over the rectified pixels whose true depth is the
// panel's, depth from disparity as the Disparity nodelet's points2 computes it (z = f' B / d).
DepthErrors panelDepthErrors(const cv::Mat& disparity, const cv::Mat& true_disparity,
                             const RectificationGeometry& g) {
  const double fb = g.P1(0, 0) * g.baseline();
  // The panel's true disparity range: the rectified z of a frontal plane varies only with the
  // small rectifying rotation, so a band of +-1 % around fB/2 m isolates it.
  const double d_panel = fb / kPanelDepth;
  DepthErrors out;
  std::vector<double> errors;
  for (int v = 0; v < disparity.rows; ++v) {
    for (int u = 0; u < disparity.cols; ++u) {
      const float d_true = true_disparity.at<float>(v, u);
      if (!(std::abs(d_true - d_panel) < 0.01 * d_panel)) continue;
      ++out.panel_pixels;
      const float d = disparity.at<float>(v, u);
      if (!isValidDisparity(d) || !(d > 0)) continue;
      ++out.valid;
      errors.push_back(std::abs(d_true / d - 1.0));  // z / z_true - 1 with z = fB/d
    }
  }
  if (!errors.empty()) {
    std::sort(errors.begin(), errors.end());
    out.median_rel = errors[errors.size() / 2];
    out.p90_rel = errors[errors.size() * 9 / 10];
  }
  return out;
}

TEST(SimDepth, MedianDepthErrorAtTwoMetresIsWithinOnePercent) {
  const SimRig rig(withPanelAtTwoMetres());
  for (RectificationMethod method : {RectificationMethod::kBouguet, RectificationMethod::kFusiello}) {
    RectificationOptions rectification;
    rectification.method = method;
    for (uint64_t seed : {41u, 42u}) {
      const SimFrame frame = rig.render(0.0, 0.0, seed);  // light off, sensor noise on
      const RectificationMaps maps = RectificationMaps::build(frame.truth, rectification);
      const cv::Mat true_disparity = rectifiedDisparityFromDepth(frame.left_depth, maps);
      const auto rect = maps.rectify(frame.left, frame.right);
      for (const std::string algorithm : {"census_sgm", "sad", "bm", "sgbm"}) {
        DisparityOptions options;  // the defaults, with the algorithm swapped
        options.algorithm = algorithm;
        DisparityComputer matcher(options);
        const DepthErrors e =
            panelDepthErrors(matcher.compute(rect.first, rect.second), true_disparity, maps.geometry());
        std::printf("%s rectification, seed %d, %s: panel at 2 m, %d px, %.1f %% valid, median "
                    "|depth error| %.3f %%, 90th percentile %.3f %%\n",
                    toString(method).c_str(), static_cast<int>(seed), algorithm.c_str(),
                    e.panel_pixels, 100 * e.validFraction(), 100 * e.median_rel, 100 * e.p90_rel);
        // The panel covers ~390 x 260 rectified pixels of the left image.
        EXPECT_GT(e.panel_pixels, 60000) << algorithm;
        EXPECT_GT(e.validFraction(), 0.95) << algorithm;
        EXPECT_LE(e.median_rel, 0.01) << algorithm;
      }
    }
  }
}

// Depth the way the Disparity nodelet's points2 computes it ((x, y, z, w) = Q (u, v, d, 1),
// z / w in the rectified left frame), divided by the true depth of the same rectified pixel.
// The truth does not use the product's maps: the rectified ray R1^T K'^-1 (u, v, 1) is projected
// into the raw left image with OpenCV and the simulator's depth map (z along the raw optical
// axis) read there; on that ray z_rect = z_raw / ray_raw.z. Only panel pixels count (raw depth
// exactly the panel's: it faces the left camera at z = 2 m).
struct DepthRatio {
  int panel_pixels = 0, valid = 0;
  double median = 0.0;  // of z_measured / z_true
};

DepthRatio panelDepthRatio(const cv::Mat& disparity, const RectificationGeometry& g, const cv::Mat& raw_depth,
                           const PinholeCamera& true_left) {
  const double f = g.P1(0, 0), fy = g.P1(1, 1), cx = g.P1(0, 2), cy = g.P1(1, 2);
  std::vector<cv::Point3d> rays;
  rays.reserve(disparity.total());
  for (int v = 0; v < disparity.rows; ++v)
    for (int u = 0; u < disparity.cols; ++u) {
      const cv::Vec3d r = g.R1.t() * cv::Vec3d((u - cx) / f, (v - cy) / fy, 1.0);
      rays.emplace_back(r[0], r[1], r[2]);
    }
  std::vector<cv::Point2d> raw;
  const cv::Matx33d K(true_left.fx, true_left.skew, true_left.cx, 0, true_left.fy, true_left.cy, 0, 0, 1);
  cv::projectPoints(rays, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K,
                    cv::Mat(cv::Matx<double, 1, 5>(true_left.dist.data()), true), raw);
  DepthRatio out;
  std::vector<double> ratios;
  for (int v = 0, k = 0; v < disparity.rows; ++v)
    for (int u = 0; u < disparity.cols; ++u, ++k) {
      const int x = static_cast<int>(std::lround(raw[k].x)), y = static_cast<int>(std::lround(raw[k].y));
      if (x < 0 || y < 0 || x >= raw_depth.cols || y >= raw_depth.rows) continue;
      const float z_raw = raw_depth.at<float>(y, x);
      if (!(std::abs(z_raw - kPanelDepth) < 1e-4)) continue;
      ++out.panel_pixels;
      const float d = disparity.at<float>(v, u);
      if (!isValidDisparity(d) || !(d > 0)) continue;
      const cv::Vec4d p = g.Q * cv::Vec4d(u, v, d, 1.0);
      const double z_true = z_raw / rays[k].z;
      ++out.valid;
      ratios.push_back(p[2] / p[3] / z_true);
    }
  if (!ratios.empty()) {
    std::nth_element(ratios.begin(), ratios.begin() + ratios.size() / 2, ratios.end());
    out.median = ratios[ratios.size() / 2];
  }
  return out;
}

// The product path must carry a wrong calibration into the depth: a rig whose baseline is 2 %
// too long rectifies the images exactly as the true one (the same rotations and focal length),
// so the disparities are the same and every depth comes out 1.02 times the truth.
TEST(SimDepth, AWrongBaselineShowsAsDepthError) {
  const SimRig rig(withPanelAtTwoMetres());
  const SimFrame frame = rig.render(0.0, 0.0, 43);
  StereoRig long_baseline = frame.truth;
  long_baseline.right_from_left.translation() *= 1.02;
  for (RectificationMethod method : {RectificationMethod::kBouguet, RectificationMethod::kFusiello}) {
    RectificationOptions rectification;
    rectification.method = method;
    DepthRatio ratio[2];
    for (int wrong = 0; wrong < 2; ++wrong) {
      const RectificationMaps maps = RectificationMaps::build(wrong ? long_baseline : frame.truth, rectification);
      const auto rect = maps.rectify(frame.left, frame.right);
      DisparityComputer matcher{DisparityOptions()};
      ratio[wrong] = panelDepthRatio(matcher.compute(rect.first, rect.second), maps.geometry(), frame.left_depth,
                                     frame.truth.left);
      std::printf("%s rectification, %s baseline: panel %d px, %d valid, median depth / true depth %.4f\n",
                  toString(method).c_str(), wrong ? "2 % long" : "true", ratio[wrong].panel_pixels,
                  ratio[wrong].valid, ratio[wrong].median);
      EXPECT_GT(ratio[wrong].panel_pixels, 60000);  // ~390 x 260 rectified pixels
      EXPECT_GT(ratio[wrong].valid, 0.95 * ratio[wrong].panel_pixels);
    }
    // The true calibration: the depth within the 1 % bound of the test above, here signed and
    // tighter so that 1.00 and 1.02 cannot be confused.
    EXPECT_NEAR(ratio[0].median, 1.0, 0.005) << toString(method);
    EXPECT_NEAR(ratio[1].median, 1.02, 0.005) << toString(method);
    // Identical disparities: the ratio between the two is the baseline's.
    EXPECT_NEAR(ratio[1].median / ratio[0].median, 1.02, 1e-3) << toString(method);
  }
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
