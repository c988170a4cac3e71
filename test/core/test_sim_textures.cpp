// Photographed textures and moving panels of the simulated world, and the scenario config's
// validation. References are computed here from the image file (cv::imread, cv::remap) and the
// camera model by hand (an ideal pinhole), not by the renderer's code.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {
namespace {

const std::string kConfigDir = std::string(ECS_SOURCE_DIR) + "/config/";
const std::string kPhoto = "/usr/lib/python3/dist-packages/skimage/data/camera.png";
constexpr double kF = 650.0, kCx = 375.5, kCy = 239.5;

// An ideal pinhole pair (no distortion), no lens blur, no noise, full transmittance: the scene
// image is the scene radiance itself, rounded.
SimRigConfig idealConfig() {
  SimRigConfig c = loadSimRigConfig(kConfigDir + "sim_rig.yaml");
  for (PinholeCamera* cam : {&c.rig.left, &c.rig.right}) {
    cam->fx = cam->fy = kF;
    cam->cx = kCx;
    cam->cy = kCy;
    cam->dist = {{0, 0, 0, 0, 0}};
  }
  c.optics.psf_sigma_px = 0.0;
  c.optics.transmittance = 1.0;
  c.noise_sigma = 0.0;
  return c;
}

// The photograph's radiance where a ray of the ideal left camera (pixel u, v) meets a frontal
// plane at depth z whose corner is `origin`, the photograph covering tile_w x tile_h metres and
// repeating: cv::remap of the image file (bilinear) at the photograph's pixel centres.
cv::Mat referenceView(const cv::Mat& photo, double z, const Eigen::Vector3d& origin, double tile_w, double tile_h,
                      const cv::Rect& roi) {
  cv::Mat map(roi.size(), CV_32FC2);
  for (int v = 0; v < roi.height; ++v)
    for (int u = 0; u < roi.width; ++u) {
      const double x = (roi.x + u - kCx) / kF * z - origin.x(), y = (roi.y + v - kCy) / kF * z - origin.y();
      const double tx = std::fmod(x, tile_w), ty = std::fmod(y, tile_h);
      map.at<cv::Vec2f>(v, u) = cv::Vec2f(tx / tile_w * photo.cols - 0.5, ty / tile_h * photo.rows - 0.5);
    }
  cv::Mat f, out;
  photo.convertTo(f, CV_32F, 239.0 / 255.0, 16.0);  // the documented grey mapping to [16, 255]
  cv::remap(f, out, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  return out;
}

TEST(SimTextures, PhotographIsStretchedOrTiledOverItsPlane) {
  const cv::Mat photo = cv::imread(kPhoto, cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(photo.empty()) << kPhoto;
  const double z = 2.0;
  // A photograph pixel of 4 mm: 0.77 image pixels at 2 m, so the finest mip level is sampled.
  for (const bool tiled : {false, true}) {
    SimRigConfig c = idealConfig();
    ScenePlane p;
    p.origin = Eigen::Vector3d(-1.2, -0.8, z);
    p.width_m = tiled ? 2.4 : 512 * 0.004;
    p.height_m = tiled ? 1.6 : 512 * 0.004;
    p.texture_image = kPhoto;
    const double tile = tiled ? 0.6 : 512 * 0.004;
    if (tiled) p.texture_tile_m = Eigen::Vector2d(0.6, 0.6);
    // (a 0.6 m tile of 512 px: 1.2 mm photograph pixels, ~2.6 per image pixel: mip-mapped, so
    // compare against the photograph pre-shrunk to about the image's sampling)
    c.scene.planes = {p};
    const SimFrame f = SimRig(c).render(0.0, 0.0, 1);
    const cv::Rect roi(200, 100, 350, 250);
    cv::Mat source = photo;
    if (tiled) cv::resize(photo, source, cv::Size(), 1 / 2.6, 1 / 2.6, cv::INTER_AREA);
    const cv::Mat ref = referenceView(source, z, p.origin, tile, tile, roi);
    cv::Mat rendered;
    f.left_scene(roi).convertTo(rendered, CV_32F);
    cv::Mat diff = cv::abs(rendered - ref);
    const double mean_abs = cv::mean(diff)[0];
    cv::Mat a, b;
    cv::matchTemplate(rendered, ref, a, cv::TM_CCOEFF_NORMED);
    // Control: the reference one photograph pixel off (stretched; a few image pixels tiled)
    // matches worse.
    const double shift = tiled ? tile / 64 : tile / 512;
    const cv::Mat shifted = referenceView(source, z, p.origin + Eigen::Vector3d(shift, 0, 0), tile, tile, roi);
    cv::matchTemplate(rendered, shifted, b, cv::TM_CCOEFF_NORMED);
    std::printf("[ figures  ] photograph %s: rendered vs reference mean |diff| %.2f grey levels, NCC %.4f "
                "(reference shifted: NCC %.4f)\n", tiled ? "tiled 0.6 m" : "stretched", mean_abs,
                a.at<float>(0, 0), b.at<float>(0, 0));
    if (!tiled) {
      EXPECT_LT(mean_abs, 0.6);  // rounding to 8 bits and float sampling
      EXPECT_GT(a.at<float>(0, 0), 0.999);
    } else {
      EXPECT_GT(a.at<float>(0, 0), 0.97);
    }
    EXPECT_GT(a.at<float>(0, 0), b.at<float>(0, 0) + 0.005);
  }
}

// A panel crossing in front of a wall: it hides the wall, and left_depth is the panel's where
// (by the pinhole model) its rectangle is, the wall's elsewhere; it moves between frames.
TEST(SimTextures, MoverOccludesTheSceneAndAppearsInDepth) {
  SimRigConfig c = idealConfig();
  ScenePlane wall;
  wall.origin = Eigen::Vector3d(-5, -4, 6.0);
  wall.width_m = 10;
  wall.height_m = 8;
  wall.texel_m = 0.01;
  c.scene.planes = {wall};
  SimMover person;
  person.panel.origin = Eigen::Vector3d(0, -0.85, 0);
  person.panel.width_m = 0.6;
  person.panel.height_m = 1.7;
  person.panel.texture_image = kPhoto;
  person.trajectory.kind = SimTrajectory::Kind::kWaypoints;
  person.trajectory.waypoints.resize(2);
  person.trajectory.waypoints[0].pose.translation() = Eigen::Vector3d(-2.0, 0, 2.5);
  person.trajectory.waypoints[1].t_s = 2.0;
  person.trajectory.waypoints[1].pose.translation() = Eigen::Vector3d(1.0, 0, 2.5);  // 1.5 m/s
  c.scene.movers = {person};
  const SimRig rig(c);
  for (double t : {0.8, 1.4}) {
    const SimFrame f = rig.render(t, 0.0, 1);
    const double x0 = -2.0 + 1.5 * t;  // the panel's left edge at time t
    int on_panel = 0, on_wall = 0, wrong = 0;
    for (int v = 5; v < 475; v += 5)
      for (int u = 5; u < 750; u += 5) {
        const double x = (u - kCx) / kF, y = (v - kCy) / kF;
        const double px = x * 2.5, py = y * 2.5;
        const double margin = 0.01;
        const bool inside = px > x0 + margin && px < x0 + 0.6 - margin && py > -0.85 + margin && py < 0.85 - margin;
        const bool outside = px < x0 - margin || px > x0 + 0.6 + margin || py < -0.85 - margin || py > 0.85 + margin;
        const float depth = f.left_depth.at<float>(v, u);
        if (inside) {
          ++on_panel;
          wrong += std::abs(depth - 2.5) > 1e-4;
        } else if (outside) {
          ++on_wall;
          wrong += std::abs(depth - 6.0) > 1e-4;
        }
      }
    std::printf("[ figures  ] mover at t=%.1f s: %d samples on the panel, %d on the wall, %d with a wrong depth\n", t,
                on_panel, on_wall, wrong);
    EXPECT_GT(on_panel, 300);
    EXPECT_EQ(wrong, 0);
  }
}

// A door hinged on its left edge, swinging open by 90 deg: the hinge stays where it is, the far
// edge comes towards the camera.
TEST(SimTextures, SwingingDoorRotatesAboutItsHinge) {
  SimRigConfig c = idealConfig();
  ScenePlane wall;
  wall.origin = Eigen::Vector3d(-5, -4, 6.0);
  wall.width_m = 10;
  wall.height_m = 8;
  wall.texel_m = 0.01;
  c.scene.planes = {wall};
  SimMover door;
  door.panel.origin = Eigen::Vector3d::Zero();  // the hinge: the mover's origin
  door.panel.width_m = 1.0;
  door.panel.height_m = 2.0;
  door.trajectory.kind = SimTrajectory::Kind::kWaypoints;
  door.trajectory.start.translation() = Eigen::Vector3d(-0.5, -1.0, 4.0);
  door.trajectory.waypoints.resize(2);
  door.trajectory.waypoints[1].t_s = 3.0;
  door.trajectory.waypoints[1].pose.linear() = rotationFromVectorDeg(Eigen::Vector3d(0, 90, 0));
  c.scene.movers = {door};
  const SimRig rig(c);
  const SimFrame closed = rig.render(0.0, 0.0, 1), open = rig.render(3.0, 0.0, 1);
  // Straight ahead: the closed door at 4 m; once open, the wall behind it at 6 m.
  const auto pixel = [](double x, double y, double z) { return cv::Point(static_cast<int>(std::lround(kF * x / z + kCx)), static_cast<int>(std::lround(kF * y / z + kCy))); };
  const cv::Point middle = pixel(0.0, 0.0, 4.0);
  EXPECT_NEAR(closed.left_depth.at<float>(middle), 4.0, 1e-4);
  EXPECT_NEAR(open.left_depth.at<float>(middle), 6.0, 1e-4);
  // Opened by 90 deg about y (x towards -z): the door now lies along -z from the hinge, at
  // x = -0.5 from z = 4 to z = 3; a ray through (-0.5, 0, 3.5) hits it there.
  const cv::Point side = pixel(-0.5, 0.0, 3.5);
  const double x = (side.x - kCx) / kF;
  EXPECT_NEAR(open.left_depth.at<float>(side), -0.5 / x, 1e-3);
  EXPECT_LT(open.left_depth.at<float>(side), 4.0);
}

// --- Config validation ---------------------------------------------------------------------

std::string readFile(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string writeVariant(const std::string& base, const std::string& from, const std::string& to,
                         const std::string& name) {
  std::string text = readFile(kConfigDir + base);
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

TEST(SimTextures, EveryKernelRendersTheSameScene) {
  // The scene kernels differ in vector width, gathers and fused multiply-adds only: the same
  // pixels hit, the same texels, the same depth, to float rounding.
  const std::vector<std::string> kernels = SimRig::sceneKernelNames();
  if (kernels.size() < 2) GTEST_SKIP() << "this build or CPU has only the baseline scene kernel";
  for (const char* scenario : {"drive_photo.yaml", "handheld_photo.yaml"}) {
    const SimRigConfig config = loadSimRigConfig(kConfigDir + scenario);
    SimRig baseline(config), wide(config);
    ASSERT_TRUE(baseline.useSceneKernel("baseline"));
    ASSERT_TRUE(wide.useSceneKernel(kernels.back()));
    for (double t : {1.3, 4.7, 11.1}) {
      const SimFrame a = baseline.render(t, 1.0, 5), b = wide.render(t, 1.0, 5);
      for (int side = 0; side < 2; ++side) {
        const cv::Mat& sa = side == 0 ? a.left_scene : a.right_scene;
        const cv::Mat& sb = side == 0 ? b.left_scene : b.right_scene;
        cv::Mat diff;
        cv::absdiff(sa, sb, diff);
        diff.convertTo(diff, CV_32F);
        const double rms = std::sqrt(cv::mean(diff.mul(diff))[0]);
        double max_diff;
        cv::minMaxLoc(diff, nullptr, &max_diff);
        std::printf("[ figures  ] %s t=%.1f %s: %s against baseline, scene RMS %.4f grey, max %.0f\n", scenario, t,
                    side == 0 ? "left" : "right", kernels.back().c_str(), rms, max_diff);
        EXPECT_LT(rms, 0.02) << scenario << " t=" << t;
        EXPECT_LE(max_diff, 1.0) << scenario << " t=" << t;
      }
      const cv::Mat finite_a = a.left_depth < std::numeric_limits<float>::infinity();
      const cv::Mat finite_b = b.left_depth < std::numeric_limits<float>::infinity();
      EXPECT_EQ(cv::countNonZero(finite_a != finite_b), 0) << "the same pixels hit";
      cv::Mat relative;
      cv::divide(cv::abs(a.left_depth - b.left_depth), a.left_depth, relative);
      double worst;
      cv::minMaxLoc(relative, nullptr, &worst, nullptr, nullptr, finite_a & finite_b);
      EXPECT_LT(worst, 1e-5) << scenario << " t=" << t;
    }
  }
}

TEST(SimScenarioConfig, ScenariosLoad) {
  const SimRigConfig drive = loadSimRigConfig(kConfigDir + "drive_photo.yaml");
  EXPECT_EQ(drive.trajectory.kind, SimTrajectory::Kind::kDrive);
  EXPECT_EQ(drive.scene.movers.size(), 2u);
  EXPECT_EQ(drive.scene.planes[0].texture_image, "/usr/lib/python3/dist-packages/skimage/data/gravel.png");
  const SimRigConfig hand = loadSimRigConfig(kConfigDir + "handheld_photo.yaml");
  EXPECT_EQ(hand.trajectory.kind, SimTrajectory::Kind::kHandheld);
  EXPECT_GE(hand.scene.movers.size(), 1u);
  EXPECT_TRUE(loadSimRigConfig(kConfigDir + "sim_rig.yaml").trajectory.isStatic());
}

TEST(SimScenarioConfig, RelativeImagePathsResolveAgainstTheConfigFolder) {
  const std::string dir = ::testing::TempDir();
  ASSERT_TRUE(cv::imwrite(dir + "sim_relative_texture.png", cv::Mat(16, 16, CV_8U, cv::Scalar(90))));
  const std::string path =
      writeVariant("drive_photo.yaml", "\"skimage:gravel.png\"", "\"sim_relative_texture.png\"", "sim_relative.yaml");
  const SimRigConfig c = loadSimRigConfig(path);
  EXPECT_EQ(c.scene.planes[0].texture_image, dir + "sim_relative_texture.png");
}

TEST(SimScenarioConfig, ErrorsNameTheKey) {
  struct Case {
    const char* base;
    const char* from;
    const char* to;
    const char* key;
  };
  const Case cases[] = {
      {"drive_photo.yaml", "\"skimage:coffee.png\"", "\"/nonexistent/coffee.png\"", "scene.planes[6].texture.image: cannot read the image '/nonexistent/coffee.png'"},
      {"drive_photo.yaml", "\"skimage:astronaut.png\"", "\"missing_person.png\"", "scene.movers[0].texture.image"},
      {"drive_photo.yaml", "kind: drive", "kind: fly", "trajectory.kind: must be static, drive, handheld or waypoints"},
      {"drive_photo.yaml", "speed_m_s: 1.0", "speed_m_s: .nan", "trajectory.speed_m_s: must be finite"},
      {"drive_photo.yaml", "speed_m_s: 1.0", "speed_m_s: 50.0", "trajectory.speed_m_s: must be in [-20, 20]"},
      {"drive_photo.yaml", "speed_m_s: 1.0", "sped_m_s: 1.0", "trajectory.sped_m_s: unknown key"},
      {"drive_photo.yaml", "yaw_period_s: 8.0", "yaw_period_s: -8.0", "trajectory.yaw_period_s: must be in [0.01, 3600] s"},
      {"drive_photo.yaml", "loop_s: 20.0", "loop_s: -1.0", "trajectory.loop_s: must be >= 0"},
      {"drive_photo.yaml", "{t_s: 4.2,", "{t_s: 0.0,", "scene.movers[0].trajectory.waypoints[1].t_s: must be later"},
      {"drive_photo.yaml", "interpolation: spline", "interpolation: cubic", "scene.movers[0].trajectory.interpolation"},
      {"drive_photo.yaml", "samples: 1", "samples: 0", "motion_blur.samples"},
      {"drive_photo.yaml", "  exposure_s: 0.008\n", "  exposure_s: 0.05\n", "motion_blur.exposure_s: must be in [0, 1/fps]"},
      {"drive_photo.yaml", "tile_m: [1.5, 1.5]", "tile_m: [1.5, -1.5]", "scene.planes[0].texture.tile_m"},
      {"handheld_photo.yaml", "rotation_amplitude_deg: [3.0, 5.0, 2.0]", "rotation_amplitude_deg: [3.0, 90.0, 2.0]",
       "trajectory.rotation_amplitude_deg[1]: must be in [0, 45] deg"},
      {"handheld_photo.yaml", "translation_period_s: [5.0, 3.7, 6.1]", "translation_period_s: [5.0, 0.0, 6.1]",
       "trajectory.translation_period_s[1]"},
  };
  int i = 0;
  for (const Case& k : cases) {
    const std::string error = loadError(writeVariant(k.base, k.from, k.to, "sim_bad_" + std::to_string(i++) + ".yaml"));
    EXPECT_NE(error.find(k.key), std::string::npos) << "expected '" << k.key << "' in '" << error << "'";
  }
  // The same checks guard a config built in code.
  SimRigConfig c = loadSimRigConfig(kConfigDir + "handheld_photo.yaml");
  c.scene.planes[1].texture_image = "/nonexistent/floor.png";
  EXPECT_NE(c.validate().find("scene.planes[1].texture.image"), std::string::npos) << c.validate();
  EXPECT_THROW(SimRig rig(c), ConfigError);
  c = loadSimRigConfig(kConfigDir + "handheld_photo.yaml");
  c.trajectory.kind = SimTrajectory::Kind::kWaypoints;  // without waypoints
  EXPECT_NE(c.validate().find("trajectory.waypoints"), std::string::npos) << c.validate();
}

// A file with a PNG signature but no image in it passes the quick readability check of the
// config; reading it when the rig is built fails, and the rig refuses to start naming the key.
TEST(SimScenarioConfig, UndecodableImageIsRefusedWithItsKey) {
  const std::string bogus = ::testing::TempDir() + "sim_not_an_image.png";
  std::ofstream(bogus, std::ios::binary) << std::string("\x89PNG\r\n\x1a\n", 8) << "no image data follows";
  ASSERT_TRUE(cv::haveImageReader(bogus)) << "the file must pass the signature check for this test";
  SimRigConfig c = idealConfig();
  ScenePlane p;
  p.texture_image = bogus;
  c.scene.planes = {p};
  try {
    SimRig rig(c);
    FAIL() << "an undecodable texture was accepted";
  } catch (const ConfigError& e) {
    EXPECT_EQ(e.parameter(), "scene.planes[0].texture.image") << e.what();
    EXPECT_NE(std::string(e.what()).find(bogus), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
