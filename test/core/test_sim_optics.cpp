// Tests of the simulated rig's real-head optics (half-mirror ghost, vignetting, exposure, the
// light's rise and fall, shot + read noise): each model changes the rendered image the way its
// formula says, measured on the images with an independent method (phase correlation, least
// squares, cv::undistortPoints, a numeric integral, the photon transfer curve), and the ideal
// options leave the image exactly as it was.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/light/light_schedule.h"
#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kDefaultConfig = std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml";

SimRigConfig noiseFree() {
  SimRigConfig c = loadSimRigConfig(kDefaultConfig);
  c.noise_sigma = 0.0;
  return c;
}

cv::Mat toFloat(const cv::Mat& m) {
  cv::Mat f;
  m.convertTo(f, CV_64F);
  return f;
}

// Least-squares slope of y against x (through the origin) over the mask.
double lsSlope(const cv::Mat& y, const cv::Mat& x, const cv::Mat& mask) {
  return cv::sum(y.mul(x).mul(mask))[0] / cv::sum(x.mul(x).mul(mask))[0];
}

void expectSameFrame(const SimFrame& a, const SimFrame& b, const std::string& what) {
  EXPECT_EQ(cv::norm(a.left, b.left, cv::NORM_INF), 0.0) << what;
  EXPECT_EQ(cv::norm(a.right, b.right, cv::NORM_INF), 0.0) << what;
  EXPECT_EQ(cv::norm(a.left_scene, b.left_scene, cv::NORM_INF), 0.0) << what;
  EXPECT_EQ(cv::norm(a.right_scene, b.right_scene, cv::NORM_INF), 0.0) << what;
}

// --- The ideal options -----------------------------------------------------------------

TEST(SimOptics, IdealOptionsRenderTheSameImages) {
  // Every model present with its ideal value (and the other fields of each set to real-head
  // values that must then have no effect), against the default file without them.
  const SimRigConfig plain = loadSimRigConfig(kDefaultConfig);
  SimRigConfig ideal = plain;
  ideal.optics.ghost = {2.0, 45.0, 1.517, 0.0, 90.0};
  ideal.optics.vignetting = {0.0, 0.0};
  ideal.optics.exposure.mode = "fixed";
  ideal.optics.exposure.gain = 1.0;
  ideal.optics.exposure.time_s = 0.008;
  ideal.optics.light.model = "schedule";
  ideal.optics.light.rise_time_s = 0.05;
  const SimRig a(plain), b(ideal);
  const double levels[] = {1.0, 0.5, 0.0, 1.0};
  for (int k = 0; k < 4; ++k) {
    SimRenderRequest r;
    r.time_s = k / 30.0;
    r.light_level = levels[k];
    r.noise_seed = k + 1;
    r.has_light_command = true;  // ignored by the schedule model
    r.light_command.on = false;
    const SimFrame fa = a.render(k / 30.0, levels[k], k + 1);
    const SimFrame fb = b.render(r);
    expectSameFrame(fa, fb, "frame " + std::to_string(k));
    EXPECT_EQ(cv::norm(fa.left_depth, fb.left_depth, cv::NORM_INF), 0.0);
    EXPECT_DOUBLE_EQ(fb.light_level, levels[k]);
    EXPECT_DOUBLE_EQ(fb.exposure_gain, 1.0);
  }
}

// --- Half-mirror ghost -----------------------------------------------------------------

TEST(SimOptics, GhostIsTheDeviceAtThePredictedShiftAndWeight) {
  SimRigConfig ideal = noiseFree();
  // A distortion-free lens: the predicted shift f s / Z is then exact for a pinhole.
  ideal.rig.left.dist.fill(0.0);
  ideal.rig.right.dist.fill(0.0);
  SimRigConfig ghosted = ideal;
  SimGhostConfig& g = ghosted.optics.ghost;
  g.thickness_mm = 10.0;  // thick and bright, so that the measurement is precise
  g.angle_deg = 45.0;
  g.refractive_index = 1.5;
  g.back_reflectance = 0.2;
  g.direction_deg = 30.0;
  const SimRig a(ghosted), b(ideal);
  // Light on minus light off: the device part of each image (the scene cancels).
  const SimFrame a_on = a.render(0.0, 1.0, 1), a_off = a.render(0.0, 0.0, 1);
  const SimFrame b_on = b.render(0.0, 1.0, 1), b_off = b.render(0.0, 0.0, 1);
  cv::Mat device = toFloat(b_on.left) - toFloat(b_off.left);
  cv::Mat ghost = (toFloat(a_on.left) - toFloat(a_off.left)) - device;  // the ghost alone

  // Plate optics by hand: refraction angle, then the beam separation and the weight.
  const double incidence = (90.0 - 45.0) * M_PI / 180.0;
  const double refracted = std::asin(std::sin(incidence) / 1.5);
  const double separation_m = 2.0 * 10e-3 * std::tan(refracted) * std::cos(incidence);
  const double weight = (1 - 0.5) * (1 - 0.5) * 0.2 / 0.5;
  const Eigen::Vector2d direction(std::cos(M_PI / 6), std::sin(M_PI / 6));

  const PinholeCamera& cam = ideal.rig.left;
  const std::vector<VirtualBoard> boards = ideal.device.virtualBoards();
  int measured_boards = 0;
  for (const BoardCorners& bc : a_on.observations.left) {
    const VirtualBoard* board = nullptr;
    for (const VirtualBoard& vb : boards)
      if (vb.virtual_id == bc.board_id) board = &vb;
    ASSERT_NE(board, nullptr);
    // Predicted shift: f s / Z averaged over the board's corners (it is slanted).
    double inverse_depth = 0.0;
    for (int id : bc.corner_ids) inverse_depth += 1.0 / board->cornerInRig(id).z();
    inverse_depth /= bc.corner_ids.size();
    const Eigen::Vector2d predicted(cam.fx * separation_m * inverse_depth * direction.x(),
                                    cam.fy * separation_m * inverse_depth * direction.y());
    // A window over the board's corners and one square around them.
    const auto [umin, umax] = std::minmax_element(bc.u.begin(), bc.u.end());
    const auto [vmin, vmax] = std::minmax_element(bc.v.begin(), bc.v.end());
    const cv::Rect window = cv::Rect(cv::Point(static_cast<int>(*umin) - 16, static_cast<int>(*vmin) - 16),
                                     cv::Point(static_cast<int>(*umax) + 16, static_cast<int>(*vmax) + 16)) &
                            cv::Rect(0, 0, device.cols, device.rows);
    cv::Mat d32, g32, hann;
    device(window).convertTo(d32, CV_32F);
    ghost(window).convertTo(g32, CV_32F);
    cv::createHanningWindow(hann, window.size(), CV_32F);
    const cv::Point2d coarse = cv::phaseCorrelate(d32, g32, hann);
    // Refined by least squares (Gauss-Newton on shift and weight): ghost(x) ~ w device(x - shift)
    // over the window, the moved device image interpolated bicubically.
    double w = 0.1;
    cv::Point2d shift = coarse;
    cv::Mat inner = cv::Mat::zeros(device.size(), CV_64F);
    inner(window) = 1.0;
    for (int it = 0; it < 20; ++it) {
      cv::Mat moved, gx, gy;
      cv::warpAffine(device, moved, cv::Matx23d(1, 0, shift.x, 0, 1, shift.y), device.size(), cv::INTER_CUBIC,
                     cv::BORDER_REPLICATE);
      cv::Sobel(moved, gx, CV_64F, 1, 0, 1, 0.5);  // central differences
      cv::Sobel(moved, gy, CV_64F, 0, 1, 1, 0.5);
      const cv::Mat r = (ghost - w * moved).mul(inner);
      // d(model)/d(w, shift.x, shift.y) = (moved, -w gx, -w gy)
      const cv::Mat J[3] = {moved.mul(inner), -w * gx.mul(inner), -w * gy.mul(inner)};
      cv::Matx33d A;
      cv::Vec3d b;
      for (int i = 0; i < 3; ++i) {
        b[i] = J[i].dot(r);
        for (int j = 0; j < 3; ++j) A(i, j) = J[i].dot(J[j]);
      }
      const cv::Vec3d step = A.solve(b, cv::DECOMP_CHOLESKY);
      w += step[0], shift.x += step[1], shift.y += step[2];
      if (std::abs(step[1]) + std::abs(step[2]) < 1e-6) break;
    }
    EXPECT_NEAR(coarse.x, predicted.x(), 0.5) << "board " << bc.board_id << ": phase correlation";
    EXPECT_NEAR(coarse.y, predicted.y(), 0.5) << "board " << bc.board_id << ": phase correlation";
    EXPECT_NEAR(shift.x, predicted.x(), 0.08) << "board " << bc.board_id;
    EXPECT_NEAR(shift.y, predicted.y(), 0.08) << "board " << bc.board_id;
    EXPECT_NEAR(w, weight, 0.02 * weight) << "board " << bc.board_id;
    std::printf("ghost, board %d: shift (%.3f, %.3f) px, predicted (%.3f, %.3f); weight %.4f, predicted %.4f\n",
                bc.board_id, shift.x, shift.y, predicted.x(), predicted.y(), w, weight);
    ++measured_boards;
  }
  EXPECT_EQ(measured_boards, 6);
  // The ghost follows the light: nothing of it with the light off.
  EXPECT_EQ(cv::norm(a_off.left, b_off.left, cv::NORM_INF), 0.0);
}

// --- Vignetting ------------------------------------------------------------------------

// cos(theta)^(4 strength) at every `step`-th pixel, theta from OpenCV's undistortion.
void expectVignetting(const cv::Mat& real, const cv::Mat& ideal, const PinholeCamera& cam, double strength,
                      const std::string& what) {
  const cv::Matx33d K(cam.fx, cam.skew, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1);
  const cv::Mat D(cv::Matx<double, 1, 5>(cam.dist.data()), true);
  std::vector<cv::Point2d> pixels, rays;
  const int step = 4;
  for (int v = 0; v < real.rows; v += step)
    for (int u = 0; u < real.cols; u += step) pixels.emplace_back(u, v);
  cv::undistortPoints(pixels, rays, K, D, cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-12));
  double worst = 0.0, min_factor = 1.0;
  for (size_t i = 0; i < pixels.size(); ++i) {
    const double cos_theta = 1.0 / std::sqrt(1.0 + rays[i].x * rays[i].x + rays[i].y * rays[i].y);
    const double factor = std::pow(cos_theta, 4.0 * strength);
    min_factor = std::min(min_factor, factor);
    const int u = static_cast<int>(pixels[i].x), v = static_cast<int>(pixels[i].y);
    // Both images are rounded to grey levels: at most 0.5 + 0.5 * factor apart.
    worst = std::max(worst, std::abs(real.at<uchar>(v, u) - factor * ideal.at<uchar>(v, u)));
  }
  EXPECT_LE(worst, 1.0) << what;
  EXPECT_LT(min_factor, 0.9) << what << ": the corners must be noticeably darker for the check to mean anything";
}

TEST(SimOptics, VignettingFollowsCosineFourthPerPathAndPixel) {
  SimRigConfig ideal = noiseFree();
  SimRigConfig real = ideal;
  real.optics.vignetting.scene = 0.5;
  real.optics.vignetting.device = 1.0;
  {  // scene path: the scene-only ground truth (and the light-off image)
    const SimFrame a = SimRig(real).render(0.0, 0.0, 1), b = SimRig(ideal).render(0.0, 0.0, 1);
    expectVignetting(a.left_scene, b.left_scene, ideal.rig.left, 0.5, "left scene");
    expectVignetting(a.right_scene, b.right_scene, ideal.rig.right, 0.5, "right scene");
    expectVignetting(a.left, b.left, ideal.rig.left, 0.5, "left light off");
  }
  // Device path: without a scene the lit image is the device alone.
  ideal.scene.enabled = false;
  real.scene.enabled = false;
  const SimFrame a = SimRig(real).render(0.0, 1.0, 1), b = SimRig(ideal).render(0.0, 1.0, 1);
  expectVignetting(a.left, b.left, ideal.rig.left, 1.0, "left device");
  expectVignetting(a.right, b.right, ideal.rig.right, 1.0, "right device");
}

// --- Exposure --------------------------------------------------------------------------

TEST(SimOptics, AutoExposureFollowsItsLawOverFrames) {
  SimRigConfig ideal = noiseFree();
  SimRigConfig real = ideal;
  SimExposureConfig& e = real.optics.exposure;
  e.mode = "auto";
  e.gain = 2.5;  // starts too bright (some pixels saturate)
  e.target_mean = 100.0;
  e.time_constant_frames = 4.0;
  e.min_gain = 0.25;
  e.max_gain = 4.0;
  const double a = 1.0 - std::exp(-1.0 / 4.0);
  const SimRig ae(real), reference(ideal);

  double previous_gain = 0.0, previous_mean = 0.0, worst = 0.0;
  int checked = 0;
  for (int k = 0; k < 40; ++k) {
    const double light = (k >= 25 && k < 30) ? 1.0 : 0.0;  // a light window: the AE reacts to it
    const SimFrame f = ae.render(k / 30.0, light, k + 1);
    const SimFrame r = reference.render(k / 30.0, light, k + 1);
    // The gain measured on the image: least squares against the gain-1 image over the pixels
    // that saturate in neither.
    const cv::Mat fa = toFloat(f.left), ra = toFloat(r.left);
    cv::Mat mask = (f.left < 255) & (r.left > 20);
    mask.convertTo(mask, CV_64F, 1.0 / 255);
    const double gain = lsSlope(fa, ra, mask);
    const double mean = cv::mean(f.left)[0];
    if (k == 0) EXPECT_NEAR(gain, 2.5, 0.01);
    if (k > 0) {
      const double predicted = std::clamp(previous_gain * std::pow(100.0 / previous_mean, a), 0.25, 4.0);
      EXPECT_NEAR(gain, predicted, 0.002 * predicted) << "frame " << k;
      worst = std::max(worst, std::abs(gain / predicted - 1.0));
      ++checked;
    }
    if (k == 24) EXPECT_NEAR(mean, 100.0, 1.5) << "converged before the light window";
    if (k == 26) EXPECT_LT(gain, previous_gain) << "the lit device darkens the next frames";
    previous_gain = gain;
    previous_mean = mean;
  }
  EXPECT_EQ(checked, 39);
  std::printf("auto-exposure: measured gain within %.3f %% of the law over 39 frames\n", 100.0 * worst);
}

TEST(SimOptics, FixedGainScalesTheWholeSignalAndSaturates) {
  SimRigConfig ideal = noiseFree();
  SimRigConfig real = ideal;
  real.optics.exposure.gain = 1.7;
  const SimFrame f = SimRig(real).render(0.0, 1.0, 1), r = SimRig(ideal).render(0.0, 1.0, 1);
  // Gain before quantisation: |round(g x) - g round(x)| <= 0.5 + 0.5 g, saturating at 255.
  cv::Mat expected = toFloat(r.left) * 1.7;
  cv::Mat capped = cv::min(expected, 255.0);
  EXPECT_LE(cv::norm(toFloat(f.left), capped, cv::NORM_INF), 0.5 + 0.5 * 1.7 + 1e-9);
  EXPECT_GT(cv::countNonZero(f.left == 255), 100) << "some pixels must saturate";
  EXPECT_DOUBLE_EQ(f.exposure_gain, 1.7);
  // The scene-only truth carries the gain too (so that image minus scene is the device).
  EXPECT_LE(cv::norm(toFloat(f.left_scene), cv::min(toFloat(r.left_scene) * 1.7, 255.0), cv::NORM_INF), 1.36);
}

// --- The light's rise and fall ---------------------------------------------------------

// The light level by the config's definition, integrated numerically (midpoint rule).
struct Switch {
  double time_s;
  bool on;
};
double numericLevel(const std::vector<Switch>& switches, const SimLightResponseConfig& l, double t) {
  double level = 0.0, since = -1e9;
  bool on = false;
  for (const Switch& s : switches) {
    const double start = s.time_s + l.delay_s;
    if (start > t) break;
    // Level reached when this change starts, then a ramp towards the new state.
    const double ramp = on ? l.rise_time_s : l.fall_time_s;
    level = on ? std::min(1.0, level + (ramp > 0 ? (start - since) / ramp : 1.0))
               : std::max(0.0, level - (ramp > 0 ? (start - since) / ramp : 1.0));
    on = s.on;
    since = start;
  }
  const double ramp = on ? l.rise_time_s : l.fall_time_s;
  return on ? std::min(1.0, level + (ramp > 0 ? (t - since) / ramp : 1.0))
            : std::max(0.0, level - (ramp > 0 ? (t - since) / ramp : 1.0));
}
double numericMean(const std::vector<Switch>& switches, const SimLightResponseConfig& l, double t0, double t1) {
  const int n = 4000;
  double sum = 0.0;
  for (int i = 0; i < n; ++i) sum += numericLevel(switches, l, t0 + (i + 0.5) * (t1 - t0) / n);
  return sum / n;
}

struct LitFrame {
  double level_measured;  // from the image
  double level_predicted;
  bool settled, light_on;
  bool identical_to_full;  // the image equals a fully lit render with the same seed
};

// Runs the driver's default schedule (settle_frames 2 at 30 fps) through a light window and
// measures each frame's light level on its image.
std::vector<LitFrame> runWindow(const SimLightResponseConfig& light, double exposure_s, double noise) {
  SimRigConfig c = loadSimRigConfig(kDefaultConfig);
  c.noise_sigma = noise;
  c.optics.light = light;
  c.optics.exposure.time_s = exposure_s;
  SimRigConfig ideal = c;
  ideal.optics.light = SimLightResponseConfig();
  const SimRig rig(c), reference(ideal);
  LightSchedule schedule(LightScheduleConfig{0.0, 10, 2});
  std::vector<Switch> switches;
  std::vector<LitFrame> frames;
  double switch_time = -1e300;
  for (int k = 0; k < 30; ++k) {
    if (k == 3) schedule.request(true);
    if (k == 15) schedule.request(false);
    const double t = k / 30.0;
    const LightState state = schedule.step(t);
    if (state.switched) {
      switch_time = t;
      switches.push_back({t, state.light_on});
    }
    SimRenderRequest r;
    r.time_s = t;
    r.light_level = state.light_level;
    r.noise_seed = k + 1;
    r.has_light_command = true;
    r.light_command = {state.light_on, switch_time};
    const SimFrame f = rig.render(r);
    const SimFrame off = reference.render(t, 0.0, k + 1), full = reference.render(t, 1.0, k + 1);
    const cv::Mat device = toFloat(full.left) - toFloat(off.left);
    cv::Mat mask = device > 30;
    mask.convertTo(mask, CV_64F, 1.0 / 255);
    LitFrame lf;
    lf.level_measured = lsSlope(toFloat(f.left) - toFloat(off.left), device, mask);
    lf.level_predicted = numericMean(switches, light, t, t + exposure_s);
    lf.settled = state.settled;
    lf.light_on = state.light_on;
    lf.identical_to_full = cv::norm(f.left, full.left, cv::NORM_INF) == 0.0;
    frames.push_back(lf);
  }
  return frames;
}

TEST(SimOptics, PartlyLitFramesShowTheLightIntegratedOverTheExposure) {
  SimLightResponseConfig light;
  light.model = "response";
  light.rise_time_s = 0.05;
  light.fall_time_s = 0.03;
  light.delay_s = 0.004;
  const std::vector<LitFrame> frames = runWindow(light, 0.012, 0.0);
  int partly = 0;
  for (size_t k = 0; k < frames.size(); ++k) {
    EXPECT_NEAR(frames[k].level_measured, frames[k].level_predicted, 0.004) << "frame " << k;
    if (frames[k].level_predicted > 0.02 && frames[k].level_predicted < 0.98) ++partly;
  }
  EXPECT_GE(partly, 3) << "the window must contain partly lit frames, rising and falling";
}

TEST(SimOptics, SettleFramesMustCoverTheRiseTime) {
  SimLightResponseConfig light;
  light.model = "response";
  light.delay_s = 0.005;
  // Longer than the two settle frames at 30 fps (66.7 ms): a "settled" frame is still rising.
  light.rise_time_s = 0.1;
  light.fall_time_s = 0.02;
  double least_settled_on = 1.0;
  for (const LitFrame& f : runWindow(light, 0.008, 0.0))
    if (f.settled && f.light_on) least_settled_on = std::min(least_settled_on, f.level_measured);
  EXPECT_LT(least_settled_on, 0.9) << "a settled frame with the light on should be partly lit";

  // Delay + rise within the settle frames: every settled frame is fully lit or fully dark, to
  // the bit (same image as an ideally lit render with the same noise).
  light.rise_time_s = 0.05;
  light.fall_time_s = 0.05;
  int settled_on = 0;
  for (const LitFrame& f : runWindow(light, 0.008, 1.0)) {
    if (!f.settled) continue;
    if (f.light_on) {
      EXPECT_TRUE(f.identical_to_full);
      ++settled_on;
    } else {
      EXPECT_NEAR(f.level_measured, 0.0, 0.01);
    }
  }
  EXPECT_EQ(settled_on, 10);
}

// --- Shot + read noise -----------------------------------------------------------------

TEST(SimOptics, ShotNoiseVarianceIsLinearInTheMean) {
  SimRigConfig c = loadSimRigConfig(kDefaultConfig);
  c.optics.sensor.enabled = true;
  c.optics.sensor.gain_e_per_dn = 4.0;  // slope 1/4 grey level per grey level
  c.optics.sensor.read_noise_e = 8.0;   // 2 grey levels rms: intercept 4 (+ 1/12 quantisation)
  c.optics.sensor.full_well_e = 4000.0; // 1000 grey levels: no clipping below 255
  const SimRig rig(c);
  const int n = 48;
  cv::Mat sum = cv::Mat::zeros(480, 752, CV_64F), sum2 = sum.clone();
  for (int k = 0; k < n; ++k) {
    const cv::Mat f = toFloat(rig.render(0.0, 0.0, 100 + k).left);
    sum += f;
    sum2 += f.mul(f);
  }
  const cv::Mat mean = sum / n;
  const cv::Mat variance = (sum2 - sum.mul(sum) / n) / (n - 1);  // unbiased per pixel
  // Photon transfer curve: least-squares line of variance against mean over unsaturated pixels.
  double sx = 0, sy = 0, sxx = 0, sxy = 0, count = 0;
  for (int v = 0; v < mean.rows; ++v)
    for (int u = 0; u < mean.cols; ++u) {
      const double m = mean.at<double>(v, u), s2 = variance.at<double>(v, u);
      if (m < 10 || m > 240) continue;
      sx += m, sy += s2, sxx += m * m, sxy += m * s2, count += 1;
    }
  const double slope = (count * sxy - sx * sy) / (count * sxx - sx * sx);
  const double intercept = (sy - slope * sx) / count;
  EXPECT_GT(count, 100000);
  EXPECT_NEAR(slope, 1.0 / 4.0, 0.01);
  EXPECT_NEAR(intercept, 4.0 + 1.0 / 12.0, 0.3);

  // Deterministic per seed, different between seeds.
  EXPECT_EQ(cv::norm(rig.render(0.0, 0.0, 7).left, rig.render(0.0, 0.0, 7).left, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(rig.render(0.0, 0.0, 7).left, rig.render(0.0, 0.0, 8).left, cv::NORM_INF), 0.0);
}

// --- Configuration ---------------------------------------------------------------------

std::string writeOptics(const std::string& extra, const std::string& name) {
  std::ifstream in(kDefaultConfig);
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const std::string anchor = "  psf_sigma_px: 1.0\n";
  const size_t at = text.find(anchor);
  EXPECT_NE(at, std::string::npos);
  text.insert(at + anchor.size(), extra);
  const std::string path = ::testing::TempDir() + name;
  std::ofstream(path) << text;
  return path;
}

TEST(SimOpticsConfig, ReadsEveryField) {
  const SimRigConfig c = loadSimRigConfig(writeOptics(
      "  ghost: {thickness_mm: 2.5, angle_deg: 40, refractive_index: 1.6, back_reflectance: 0.03, direction_deg: 80}\n"
      "  vignetting: {scene: 0.4, device: 0.9}\n"
      "  exposure: {mode: auto, gain: 1.5, target_mean: 90, time_constant_frames: 6, min_gain: 0.5, max_gain: 3,"
      " time_s: 0.01}\n"
      "  light: {model: response, rise_time_s: 0.02, fall_time_s: 0.03, delay_s: 0.004}\n"
      "  sensor: {gain_e_per_dn: 40, read_noise_e: 12, full_well_e: 10000}\n",
      "sim_optics_all.yaml"));
  const SimOpticsConfig& o = c.optics;
  EXPECT_DOUBLE_EQ(o.ghost.thickness_mm, 2.5);
  EXPECT_DOUBLE_EQ(o.ghost.angle_deg, 40);
  EXPECT_DOUBLE_EQ(o.ghost.refractive_index, 1.6);
  EXPECT_DOUBLE_EQ(o.ghost.back_reflectance, 0.03);
  EXPECT_DOUBLE_EQ(o.ghost.direction_deg, 80);
  EXPECT_DOUBLE_EQ(o.vignetting.scene, 0.4);
  EXPECT_DOUBLE_EQ(o.vignetting.device, 0.9);
  EXPECT_EQ(o.exposure.mode, "auto");
  EXPECT_DOUBLE_EQ(o.exposure.gain, 1.5);
  EXPECT_DOUBLE_EQ(o.exposure.target_mean, 90);
  EXPECT_DOUBLE_EQ(o.exposure.time_constant_frames, 6);
  EXPECT_DOUBLE_EQ(o.exposure.min_gain, 0.5);
  EXPECT_DOUBLE_EQ(o.exposure.max_gain, 3);
  EXPECT_DOUBLE_EQ(o.exposure.time_s, 0.01);
  EXPECT_EQ(o.light.model, "response");
  EXPECT_DOUBLE_EQ(o.light.rise_time_s, 0.02);
  EXPECT_DOUBLE_EQ(o.light.fall_time_s, 0.03);
  EXPECT_DOUBLE_EQ(o.light.delay_s, 0.004);
  EXPECT_TRUE(o.sensor.enabled);
  EXPECT_DOUBLE_EQ(o.sensor.gain_e_per_dn, 40);
  EXPECT_DOUBLE_EQ(o.sensor.read_noise_e, 12);
  EXPECT_DOUBLE_EQ(o.sensor.full_well_e, 10000);
  EXPECT_FALSE(loadSimRigConfig(kDefaultConfig).optics.sensor.enabled);
}

TEST(SimOpticsConfig, OutOfRangeValuesNameTheKey) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"ghost: 3", "optics.ghost"},
      {"ghost: {thickness_mm: -1}", "optics.ghost.thickness_mm"},
      {"ghost: {angle_deg: 0}", "optics.ghost.angle_deg"},
      {"ghost: {refractive_index: 0.5}", "optics.ghost.refractive_index"},
      {"ghost: {back_reflectance: 0.9}", "optics.ghost.back_reflectance"},
      {"ghost: {direction_deg: 1000}", "optics.ghost.direction_deg"},
      {"vignetting: {scene: -0.5}", "optics.vignetting.scene"},
      {"vignetting: {device: 5}", "optics.vignetting.device"},
      {"exposure: {mode: manual}", "optics.exposure.mode"},
      {"exposure: {gain: 0}", "optics.exposure.gain"},
      {"exposure: {mode: auto, gain: 8}", "optics.exposure.gain"},
      {"exposure: {target_mean: 300}", "optics.exposure.target_mean"},
      {"exposure: {time_constant_frames: 0}", "optics.exposure.time_constant_frames"},
      {"exposure: {min_gain: 0}", "optics.exposure.min_gain"},
      {"exposure: {max_gain: 0.1}", "optics.exposure.max_gain"},
      {"exposure: {time_s: 0.05}", "optics.exposure.time_s"},  // longer than a frame at 30 fps
      {"light: {model: ramp}", "optics.light.model"},
      {"light: {rise_time_s: -0.01}", "optics.light.rise_time_s"},
      {"light: {fall_time_s: 11}", "optics.light.fall_time_s"},
      {"light: {delay_s: -1}", "optics.light.delay_s"},
      {"sensor: {gain_e_per_dn: 0}", "optics.sensor.gain_e_per_dn"},
      {"sensor: {read_noise_e: -1}", "optics.sensor.read_noise_e"},
      {"sensor: {full_well_e: 0}", "optics.sensor.full_well_e"},
  };
  int i = 0;
  for (const auto& [yaml, key] : cases) {
    std::string error;
    try {
      loadSimRigConfig(writeOptics("  " + yaml + "\n", "sim_optics_bad_" + std::to_string(i++) + ".yaml"));
    } catch (const ConfigError& e) {
      error = e.what();
      EXPECT_EQ(e.parameter(), key) << yaml;
    }
    EXPECT_EQ(error.rfind(key + ": ", 0), 0u) << yaml << " -> '" << error << "'";
  }
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
