// Depth from the simulated head against the simulator's depth map: a textured frontal panel at
// exactly 2 m in front of the usual scene, light-off frames (noise on), rectified with the true
// calibration, disparity with the default settings and with each algorithm. The bound:
// median absolute depth error <= 1 % at 2 m.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace ecs {
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
      for (const std::string algorithm : {"sad", "bm", "sgbm"}) {
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

// The same measure must see a wrong calibration: rectifying with a 2 % longer baseline scales
// every depth by 1.02 (and a test that could not fail would not show this).
TEST(SimDepth, AWrongBaselineShowsAsDepthError) {
  const SimRig rig(withPanelAtTwoMetres());
  const SimFrame frame = rig.render(0.0, 0.0, 43);
  const RectificationMaps maps = RectificationMaps::build(frame.truth, RectificationOptions());
  const cv::Mat true_disparity = rectifiedDisparityFromDepth(frame.left_depth, maps);
  const auto rect = maps.rectify(frame.left, frame.right);
  DisparityComputer matcher{DisparityOptions()};
  const cv::Mat disparity = matcher.compute(rect.first, rect.second);
  const DepthErrors right = panelDepthErrors(disparity, true_disparity, maps.geometry());
  // The same disparities read with a 2 % longer baseline: z' = 1.02 z.
  const DepthErrors wrong = panelDepthErrors(disparity / 1.02, true_disparity, maps.geometry());
  EXPECT_LE(right.median_rel, 0.01);
  EXPECT_NEAR(wrong.median_rel, 0.02, 0.005);
}

}  // namespace
}  // namespace ecs
