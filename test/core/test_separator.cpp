// Separator against the simulated rig's ground truth: the separated light-on image against the
// scene-only image (PSNR), and disparity from separated light-on frames against disparity from
// light-off frames of the same scene (bad > 2 px vs the true disparity from the depth map).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/depth/disparity.h"
#include "embedded_calibration_stereo/core/depth/disparity_evaluation.h"
#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/depth/separator.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kConfigPath = std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml";
constexpr int kTeachFrames = 8;

struct StereoTemplates {
  DeviceTemplate left, right;
};

// The teach step as the head would run it: I_C from light-on frames with the scene covered,
// then the paper's cubic from a static (teach) scene shown at several light levels and dark.
StereoTemplates teach(const SimRigConfig& config) {
  SimRigConfig dark = config;
  dark.scene.enabled = false;
  const SimRig dark_rig(dark);
  std::vector<cv::Mat> left_frames, right_frames;
  for (int i = 0; i < kTeachFrames; ++i) {
    const SimFrame f = dark_rig.render(0.0, 1.0, 1000 + i);
    left_frames.push_back(f.left);
    right_frames.push_back(f.right);
  }
  StereoTemplates t{teachDeviceImage(left_frames), teachDeviceImage(right_frames)};

  const SimRig rig(config);
  const SimFrame off = rig.render(0.0, 0.0, 2000);
  std::vector<AlphaSample> left_samples, right_samples;
  for (double light : {0.2, 0.4, 0.6, 0.8, 1.0}) {
    const SimFrame on = rig.render(0.0, light, 2001 + static_cast<uint64_t>(light * 10));
    left_samples.push_back(measureAlphaSample(t.left, on.left, off.left));
    right_samples.push_back(measureAlphaSample(t.right, on.right, off.right));
  }
  t.left.alpha_curve = fitAlphaCurve(left_samples);
  t.right.alpha_curve = fitAlphaCurve(right_samples);
  return t;
}

SeparatorOptions withMethod(SeparationMethod method) {
  SeparatorOptions options;
  options.method = method;
  return options;
}

struct Psnr {
  double left, right;
  double worst() const { return std::min(left, right); }
};

Psnr separationPsnr(const StereoTemplates& t, SeparationMethod method, const SimFrame& frame) {
  const ImageSeparator left(withMethod(method), t.left), right(withMethod(method), t.right);
  cv::Mat left_scene, right_scene;
  separateStereo(left, right, frame.left, frame.right, &left_scene, &right_scene);
  return {cv::PSNR(left_scene, frame.left_scene), cv::PSNR(right_scene, frame.right_scene)};
}

class SeparatorSimTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    config_ = new SimRigConfig(loadSimRigConfig(kConfigPath));
    templates_ = new StereoTemplates(teach(*config_));
  }
  static void TearDownTestSuite() {
    delete templates_;
    delete config_;
  }
  static SimRigConfig* config_;
  static StereoTemplates* templates_;
};
SimRigConfig* SeparatorSimTest::config_ = nullptr;
StereoTemplates* SeparatorSimTest::templates_ = nullptr;

TEST_F(SeparatorSimTest, AlphaTeachSamplesRecoverTheLightLevel) {
  // The teach samples' "true" alpha is measured, not given: it must match the sim's light level.
  const SimRig rig(*config_);
  const SimFrame off = rig.render(0.0, 0.0, 31);
  const SimFrame on = rig.render(0.0, 0.7, 32);
  const AlphaSample s = measureAlphaSample(templates_->left, on.left, off.left);
  std::printf("measured alpha at light 0.7: %.4f; cubic fit rms %.4f (degree %d)\n", s.alpha,
              templates_->left.alpha_curve.rms_residual, templates_->left.alpha_curve.degree);
  EXPECT_NEAR(s.alpha, 0.7, 0.01);
  // The regional method finds the same gain without teaching samples.
  double regional_alpha = 0.0;
  cv::Mat scene;
  ImageSeparator(SeparatorOptions(), templates_->left).separate(on.left, &scene, &regional_alpha);
  std::printf("regional mean alpha at light 0.7: %.4f\n", regional_alpha);
  EXPECT_NEAR(regional_alpha, 0.7, 0.01);
  EXPECT_NEAR(templates_->left.alpha_curve.evaluate(s.mean_difference), 0.7, 0.02);
}

TEST_F(SeparatorSimTest, PsnrOfSeparatedLightOnFrames) {
  struct Case {
    const char* name;
    double transmittance, light;
  };
  // The teach scene in steady state and mid-ramp, and a darker scene (what the paper's
  // brightness-driven alpha cannot tell from a dimmer device).
  const Case cases[] = {{"default scene, light 1.0", 0.5, 1.0},
                        {"default scene, light 0.6", 0.5, 0.6},
                        {"darker scene (t=0.35), light 1.0", 0.35, 1.0}};
  for (const Case& c : cases) {
    SimRigConfig config = *config_;
    config.optics.transmittance = c.transmittance;
    const SimRig rig(config);
    double worst_regional = 1e9, worst_paper = 1e9;
    for (uint64_t seed : {7u, 8u}) {
      const SimFrame frame = rig.render(0.0, c.light, seed);
      const Psnr regional = separationPsnr(*templates_, SeparationMethod::kRegionalAlpha, frame);
      const Psnr paper = separationPsnr(*templates_, SeparationMethod::kPaperGlobalAlpha, frame);
      const Psnr unseparated{cv::PSNR(frame.left, frame.left_scene),
                             cv::PSNR(frame.right, frame.right_scene)};
      std::printf("%-34s seed %d: PSNR dB L/R regional(default) %.2f/%.2f  paper %.2f/%.2f  "
                  "unseparated %.2f/%.2f\n",
                  c.name, static_cast<int>(seed), regional.left, regional.right, paper.left,
                  paper.right, unseparated.left, unseparated.right);
      worst_regional = std::min(worst_regional, regional.worst());
      worst_paper = std::min(worst_paper, paper.worst());
    }
    EXPECT_GE(worst_regional, 35.0) << c.name;
    if (c.transmittance != 0.5) {
      EXPECT_GT(worst_regional, worst_paper) << c.name;
    }
  }
}

TEST_F(SeparatorSimTest, FollowsUnevenLight) {
  // A lamp brighter on one side: alpha ramps from 0.7 (left edge) to 1.0 (right edge). Built
  // from a light-off frame plus the taught device image (the sim lights the device evenly).
  const SimRig rig(*config_);
  const SimFrame off = rig.render(0.0, 0.0, 41);
  const cv::Mat& device = templates_->left.device;
  cv::Mat on(off.left.size(), CV_32F);
  for (int y = 0; y < on.rows; ++y)
    for (int x = 0; x < on.cols; ++x)
      on.at<float>(y, x) = off.left.at<uchar>(y, x) +
                           (0.7f + 0.3f * x / (on.cols - 1)) * device.at<float>(y, x);
  cv::Mat on_u8;
  on.convertTo(on_u8, CV_8U);
  cv::Mat regional, paper;
  ImageSeparator(withMethod(SeparationMethod::kRegionalAlpha), templates_->left)
      .separate(on_u8, &regional);
  ImageSeparator(withMethod(SeparationMethod::kPaperGlobalAlpha), templates_->left)
      .separate(on_u8, &paper);
  const double psnr_regional = cv::PSNR(regional, off.left_scene);
  const double psnr_paper = cv::PSNR(paper, off.left_scene);
  std::printf("uneven light (alpha 0.7..1.0 across x): PSNR regional %.2f dB, paper %.2f dB\n",
              psnr_regional, psnr_paper);
  EXPECT_GE(psnr_regional, 35.0);
  EXPECT_GT(psnr_regional, psnr_paper);
}

TEST_F(SeparatorSimTest, PsnrOfBgr8Frames) {
  SimRigConfig config = *config_;
  config.encoding = "bgr8";
  const StereoTemplates t = teach(config);
  const SimFrame frame = SimRig(config).render(0.0, 1.0, 9);
  ASSERT_EQ(frame.left.type(), CV_8UC3);
  const Psnr regional = separationPsnr(t, SeparationMethod::kRegionalAlpha, frame);
  const Psnr paper = separationPsnr(t, SeparationMethod::kPaperGlobalAlpha, frame);
  std::printf("bgr8: PSNR dB L/R regional %.2f/%.2f paper %.2f/%.2f\n", regional.left,
              regional.right, paper.left, paper.right);
  EXPECT_GE(regional.worst(), 35.0);
}

TEST_F(SeparatorSimTest, StaleTemplateAfterZoomAndReteach) {
  // The device image moves with a 2% zoom: the old template leaves the pattern's edges behind;
  // re-teaching under the new calibration restores the separation.
  SimRigConfig config = *config_;
  SimRig rig(config);
  DriftRequest zoom;
  zoom.focal_scale = 1.02;
  ASSERT_EQ(rig.setDrift(zoom, 0.0), "");
  const SimFrame frame = rig.render(1.0, 1.0, 11);
  const double stale = separationPsnr(*templates_, SeparationMethod::kRegionalAlpha, frame).worst();

  SimRigConfig dark = config;
  dark.scene.enabled = false;
  SimRig dark_rig(dark);
  ASSERT_EQ(dark_rig.setDrift(zoom, 0.0), "");
  std::vector<cv::Mat> left_frames, right_frames;
  for (int i = 0; i < kTeachFrames; ++i) {
    const SimFrame f = dark_rig.render(1.0, 1.0, 3000 + i);
    left_frames.push_back(f.left);
    right_frames.push_back(f.right);
  }
  const StereoTemplates fresh{teachDeviceImage(left_frames, 1), teachDeviceImage(right_frames, 1)};
  const double retaught = separationPsnr(fresh, SeparationMethod::kRegionalAlpha, frame).worst();
  std::printf("after 2%% zoom: stale template %.2f dB, re-taught %.2f dB (regional)\n", stale,
              retaught);
  EXPECT_LT(stale, 30.0);
  EXPECT_GE(retaught, 35.0);
}

TEST_F(SeparatorSimTest, DisparityFromSeparatedFramesMatchesLightOff) {
  const SimRig rig(*config_);
  const SimFrame off = rig.render(0.0, 0.0, 21);
  const SimFrame on = rig.render(0.0, 1.0, 22);
  const RectificationMaps maps = RectificationMaps::build(on.truth, RectificationOptions());
  const cv::Mat truth = rectifiedDisparityFromDepth(on.left_depth, maps);
  DisparityComputer matcher{DisparityOptions()};
  const auto bad = [&](const cv::Mat& left, const cv::Mat& right) {
    const auto rect = maps.rectify(left, right);
    return evaluateBadPixels(matcher.compute(rect.first, rect.second), truth, 2.0).badPercent();
  };
  const double bad_off = bad(off.left, off.right);
  const double bad_on_raw = bad(on.left, on.right);
  double bad_sep[2];
  for (SeparationMethod method :
       {SeparationMethod::kRegionalAlpha, SeparationMethod::kPaperGlobalAlpha}) {
    const ImageSeparator left(withMethod(method), templates_->left);
    const ImageSeparator right(withMethod(method), templates_->right);
    cv::Mat left_scene, right_scene;
    separateStereo(left, right, on.left, on.right, &left_scene, &right_scene);
    bad_sep[method == SeparationMethod::kRegionalAlpha ? 0 : 1] = bad(left_scene, right_scene);
  }
  std::printf("bad > 2 px vs true disparity: light-off %.2f%%, separated regional %.2f%%, "
              "separated paper %.2f%%, light-on unseparated %.2f%%\n",
              bad_off, bad_sep[0], bad_sep[1], bad_on_raw);
  EXPECT_LE(std::abs(bad_sep[0] - bad_off), 2.0);
}

TEST(Separator, RejectsWrongInputs) {
  DeviceTemplate templ = teachDeviceImage({cv::Mat(48, 64, CV_8UC1, cv::Scalar(100))});
  const ImageSeparator separator(SeparatorOptions(), templ);
  cv::Mat out;
  EXPECT_THROW(separator.separate(cv::Mat(48, 64, CV_16UC1, cv::Scalar(0)), &out),
               std::invalid_argument);
  EXPECT_THROW(separator.separate(cv::Mat(48, 64, CV_32FC1, cv::Scalar(0)), &out),
               std::invalid_argument);
  EXPECT_THROW(separator.separate(cv::Mat(48, 32, CV_8UC1, cv::Scalar(0)), &out),
               std::invalid_argument);
  EXPECT_THROW(separator.separate(cv::Mat(48, 64, CV_8UC3, cv::Scalar(0)), &out),
               std::invalid_argument);
  EXPECT_THROW(separator.separate(cv::Mat(), &out), std::invalid_argument);
  cv::Mat same(48, 64, CV_8UC1, cv::Scalar(0));
  EXPECT_THROW(separator.separate(same, &same), std::invalid_argument);
  try {
    separator.separate(cv::Mat(48, 32, CV_8UC1), &out);
    ADD_FAILURE() << "an image of another size than the template must throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("64x48"), std::string::npos) << e.what();
  }
  SeparatorOptions bad;
  bad.tile_size = 2;
  EXPECT_NE(bad.validate(), "");
  EXPECT_THROW(ImageSeparator(bad, templ), std::invalid_argument);
  EXPECT_THROW(teachDeviceImage({}), std::invalid_argument);
  EXPECT_THROW(teachDeviceImage({cv::Mat(4, 4, CV_8UC1), cv::Mat(4, 5, CV_8UC1)}),
               std::invalid_argument);
  EXPECT_THROW(parseSeparationMethod("global"), std::invalid_argument);
  EXPECT_EQ(parseSeparationMethod(toString(SeparationMethod::kPaperGlobalAlpha)),
            SeparationMethod::kPaperGlobalAlpha);
}

TEST(Separator, CubicFitRecoversAKnownCurve) {
  std::vector<AlphaSample> samples;
  for (int i = 0; i <= 10; ++i) {
    const double x = 10.0 * i;
    samples.push_back({x, 0.2 + 0.01 * x - 1e-4 * x * x + 2e-7 * x * x * x});
  }
  const AlphaCurve curve = fitAlphaCurve(samples);
  EXPECT_EQ(curve.degree, 3);
  for (double x : {5.0, 42.0, 97.0})
    EXPECT_NEAR(curve.evaluate(x), 0.2 + 0.01 * x - 1e-4 * x * x + 2e-7 * x * x * x, 1e-9);
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
