// The CameraInfo checks every consumer runs (stereo_input_check.h), judged by image_geometry
// itself: a pair the checks accept must never reach an assertion of
// image_geometry::StereoCameraModel (Debian's build keeps them: abort), and must give finite
// geometry. Each candidate pair is handed to image_geometry in a forked child process, so an
// abort is observed, not suffered. Controls show that the child does abort on the pairs the
// checks refuse, i.e. that the harness can see what it guards against.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <image_geometry/stereo_camera_model.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <functional>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <random>

#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;
using sensor_msgs::CameraInfo;

namespace {

constexpr uint32_t kWidth = 752, kHeight = 480;

// A rectified pair as the OnlineCalibrator commits it (Bouguet, right P with Tx = -fx' * b).
std::pair<CameraInfo, CameraInfo> validPair() {
  core::StereoRig rig;
  for (core::PinholeCamera* c : {&rig.left, &rig.right}) {
    c->width = kWidth;
    c->height = kHeight;
    c->cx = 371.5;
    c->cy = 243.25;
    c->dist = {{-0.12, 0.03, 0.0005, -0.0004, 0.0}};
  }
  rig.left.fx = 652.0;
  rig.left.fy = 651.0;
  rig.right.fx = 655.0;
  rig.right.fy = 654.5;
  rig.right.cx = 380.0;
  rig.right_from_left.linear() =
      Eigen::AngleAxisd(0.01, Eigen::Vector3d(0.2, 1.0, 0.1).normalized()).toRotationMatrix();
  rig.right_from_left.translation() = Eigen::Vector3d(-0.12, 0.002, 0.001);
  auto pair = toStereoCameraInfo(rig);
  pair.first.header.frame_id = pair.second.header.frame_id = "stereo_left_optical_frame";
  return pair;
}

// Every check a consumer (the Disparity) runs before image_geometry; "" when accepted.
std::string consumerChecks(const CameraInfo& left, const CameraInfo& right) {
  std::string problem = checkCameraInfo(left, "left/camera_info", kWidth, kHeight);
  if (problem.empty()) problem = checkCameraInfo(right, "right/camera_info", kWidth, kHeight);
  if (problem.empty()) problem = checkRectifiedPair(left, "left/camera_info", right, "right/camera_info");
  if (problem.empty()) problem = checkSameFrame(left, "left/camera_info", right, "right/camera_info");
  return problem;
}

enum class Outcome { kFinite, kNonFinite, kAborted };

// What image_geometry makes of the pair, in a child process: the Disparity's calls (model,
// baseline, reprojection of a disparity of 20 px at the image centre).
Outcome inImageGeometry(const CameraInfo& left, const CameraInfo& right) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int null_fd = ::open("/dev/null", O_WRONLY);  // the assertion's message is expected
    if (null_fd >= 0) ::dup2(null_fd, STDERR_FILENO);
    image_geometry::StereoCameraModel model;
    model.fromCameraInfo(left, right);
    cv::Point3d xyz;
    model.projectDisparityTo3d(cv::Point2d(kWidth / 2.0, kHeight / 2.0), 20.0f, xyz);
    const bool finite = std::isfinite(xyz.x) && std::isfinite(xyz.y) && std::isfinite(xyz.z) &&
                        std::isfinite(model.baseline()) && std::isfinite(model.right().fx());
    ::_exit(finite ? 0 : 1);
  }
  int status = 0;
  EXPECT_EQ(::waitpid(pid, &status, 0), pid);
  if (WIFSIGNALED(status)) return Outcome::kAborted;
  return WEXITSTATUS(status) == 0 ? Outcome::kFinite : Outcome::kNonFinite;
}

// Accepted pairs, aligned as the Disparity aligns them, are fine in image_geometry.
void expectSafeIfAccepted(const CameraInfo& left, const CameraInfo& right, const std::string& what, int* accepted) {
  if (!consumerChecks(left, right).empty()) return;
  ++*accepted;
  CameraInfo aligned = right;
  alignRectifiedPair(left, &aligned);
  EXPECT_EQ(inImageGeometry(left, aligned), Outcome::kFinite) << what << " was accepted";
  // The Rectifier's use: OpenCV's maps from K, D, R, P are finite.
  for (const CameraInfo* info : {&left, static_cast<const CameraInfo*>(&aligned)}) {
    cv::Mat map_x, map_y;
    cv::initUndistortRectifyMap(cv::Matx33d(info->K.data()), cv::Mat(info->D), cv::Matx33d(info->R.data()),
                                cv::Matx34d(info->P.data()), cv::Size(kWidth, kHeight), CV_32FC1, map_x, map_y);
    EXPECT_TRUE(cv::checkRange(map_x) && cv::checkRange(map_y)) << what << ": NaN in the rectification maps";
  }
}

struct Case {
  std::string name;
  std::function<void(CameraInfo& left, CameraInfo& right)> mutate;
  std::string needle;  // topic and field the refusal must name
  // What image_geometry makes of it; kFinite: harmless to image_geometry, wrong for the
  // rectification maps or the depth (R, K, D, size, Tx) and refused for that.
  Outcome in_image_geometry;
};

const double kNaN = std::numeric_limits<double>::quiet_NaN();

// The cameras disagreeing (one recalibrated alone, binning, frame ids aside) and principal points
// off the image.
std::vector<Case> disagreeingOrOffImageCases() {
  return {
      {"right fx' differs (one camera recalibrated)", [](CameraInfo&, CameraInfo& r) { r.P[0] += 0.5; },
       "right/camera_info: P: fx'", Outcome::kAborted},
      {"right fy' differs", [](CameraInfo&, CameraInfo& r) { r.P[5] -= 2.0; }, "right/camera_info: P: fy'",
       Outcome::kAborted},
      {"right cy' differs", [](CameraInfo&, CameraInfo& r) { r.P[6] += 1.0; }, "right/camera_info: P: cy'",
       Outcome::kAborted},
      {"right binning 1000", [](CameraInfo&, CameraInfo& r) { r.binning_x = r.binning_y = 1000; },
       "right/camera_info: binning", Outcome::kAborted},
      {"left binning 2 only", [](CameraInfo& l, CameraInfo&) { l.binning_x = 2; }, "left/camera_info: binning",
       Outcome::kAborted},
      {"NaN skew", [](CameraInfo& l, CameraInfo&) { l.K[1] = kNaN; }, "left/camera_info: K: K[1]", Outcome::kFinite},
      // Off-image principal points, consistent between the cameras: image_geometry takes them,
      // and the depth would be empty.
      {"cy' of both 100000 px below the image",
       [](CameraInfo& l, CameraInfo& r) {
         l.P[6] += 100000;
         r.P[6] += 100000;
       },
       "left/camera_info: P: cy' (P[6])", Outcome::kFinite},
      {"cx' of both 5000 px right of the image",
       [](CameraInfo& l, CameraInfo& r) {
         l.P[2] += 5000;
         r.P[2] += 5000;
       },
       "left/camera_info: P: cx' (P[2])", Outcome::kFinite},
  };
}

// Fields no consumer can use: P, R or D that do not make an image, NaN and infinities, zeros,
// sizes, ROI, Tx, models, frame ids.
std::vector<Case> unusableFieldCases() {
  return {
      // P that does not fit K and R, and distortion that folds over: harmless to image_geometry,
      // but the rectified images would be out of view or mirrored.
      {"P of another camera (fx', fy' 3 times K's)",
       [](CameraInfo& l, CameraInfo& r) {
         for (CameraInfo* c : {&l, &r}) {
           c->P[0] *= 3;
           c->P[5] *= 3;
         }
         r.P[3] *= 3;
       },
       "left/camera_info: P: fx'", Outcome::kFinite},
      {"R turned 60 degrees about y",
       [](CameraInfo& l, CameraInfo&) {
         const Eigen::Matrix3d turn = Eigen::AngleAxisd(M_PI / 3, Eigen::Vector3d::UnitY()).toRotationMatrix();
         Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> R(l.R.data());
         R = (turn * R).eval();
       },
       "left/camera_info: R, P: the raw image's centre", Outcome::kFinite},
      {"k1 -2 (folds over inside the image)", [](CameraInfo& l, CameraInfo&) { l.D[0] = -2.0; },
       "left/camera_info: D: the distortion folds over", Outcome::kFinite},
      {"right cx 5000 px left of the image", [](CameraInfo&, CameraInfo& r) { r.K[2] -= 5000; },
       "right/camera_info: K: cx (K[2])", Outcome::kFinite},
      {"NaN in R", [](CameraInfo&, CameraInfo& r) { r.R[4] = kNaN; }, "right/camera_info: R: R[4]", Outcome::kFinite},
      {"NaN in P", [](CameraInfo& l, CameraInfo&) { l.P[2] = kNaN; }, "left/camera_info: P: P[2]", Outcome::kNonFinite},
      {"infinite Tx", [](CameraInfo&, CameraInfo& r) { r.P[3] = INFINITY; }, "right/camera_info: P: P[3]",
       Outcome::kNonFinite},
      {"NaN in D", [](CameraInfo& l, CameraInfo&) { l.D[1] = kNaN; }, "left/camera_info: D: D[1]", Outcome::kFinite},
      {"all-zero P", [](CameraInfo& l, CameraInfo&) { l.P.fill(0.0); }, "left/camera_info: P: uncalibrated",
       Outcome::kAborted},
      {"all-zero K", [](CameraInfo&, CameraInfo& r) { r.K.fill(0.0); }, "right/camera_info: K: uncalibrated",
       Outcome::kFinite},
      {"all-zero R", [](CameraInfo& l, CameraInfo&) { l.R.fill(0.0); }, "left/camera_info: R: uncalibrated",
       Outcome::kFinite},
      {"R not a rotation", [](CameraInfo& l, CameraInfo&) { l.R[0] *= 1.01; }, "left/camera_info: R: not a rotation",
       Outcome::kFinite},
      {"R a reflection",
       [](CameraInfo&, CameraInfo& r) {
         for (int i : {6, 7, 8}) r.R[i] = -r.R[i];
       },
       "right/camera_info: R: not a rotation", Outcome::kFinite},
      {"negative focal in P", [](CameraInfo& l, CameraInfo& r) { l.P[0] = r.P[0] = -l.P[0]; },
       "left/camera_info: P: focal", Outcome::kFinite},
      {"negative focal in K", [](CameraInfo& l, CameraInfo&) { l.K[4] = -1.0; }, "left/camera_info: K: focal",
       Outcome::kFinite},
      {"wrong size", [](CameraInfo& l, CameraInfo& r) { l.width = r.width = 640; }, "left/camera_info: size 640x480",
       Outcome::kFinite},
      {"empty size", [](CameraInfo&, CameraInfo& r) { r.height = 0; }, "right/camera_info: width, height",
       Outcome::kFinite},
      {"ROI outside the image",
       [](CameraInfo& l, CameraInfo&) {
         l.roi.x_offset = 700;
         l.roi.width = 200;
         l.roi.height = 100;
       },
       "left/camera_info: roi", Outcome::kFinite},
      {"left Tx non-zero", [](CameraInfo& l, CameraInfo&) { l.P[3] = 10.0; }, "left/camera_info: P: Tx",
       Outcome::kFinite},
      {"right Tx zero (no baseline)", [](CameraInfo&, CameraInfo& r) { r.P[3] = 0.0; }, "right/camera_info: P: Tx",
       Outcome::kFinite},
      {"unsupported distortion model", [](CameraInfo& l, CameraInfo&) { l.distortion_model = "equidistant"; },
       "left/camera_info: distortion_model", Outcome::kFinite},
      {"3 plumb_bob coefficients", [](CameraInfo&, CameraInfo& r) { r.D.resize(3); },
       "right/camera_info: D:", Outcome::kFinite},
      {"P last row", [](CameraInfo& l, CameraInfo&) { l.P[10] = 2.0; }, "left/camera_info: P: not a projection",
       Outcome::kFinite},
      {"frame ids differ", [](CameraInfo&, CameraInfo& r) { r.header.frame_id = "other"; },
       "right/camera_info: frame id", Outcome::kAborted},
  };
}

std::vector<Case> refusedCases() {
  std::vector<Case> cases = disagreeingOrOffImageCases();
  for (Case& c : unusableFieldCases()) cases.push_back(std::move(c));
  return cases;
}

}  // namespace

TEST(CameraInfoCheck, ValidPairIsAcceptedAndImageGeometryAgrees) {
  const auto [left, right] = validPair();
  EXPECT_EQ(consumerChecks(left, right), "");
  EXPECT_EQ(inImageGeometry(left, right), Outcome::kFinite);
  // A full-image ROI, binning 1, rational_polynomial: accepted too.
  CameraInfo l = left, r = right;
  l.roi.width = r.roi.width = kWidth;
  l.roi.height = r.roi.height = kHeight;
  l.binning_x = l.binning_y = 1;
  r.distortion_model = "rational_polynomial";
  r.D.resize(8, 0.0);
  EXPECT_EQ(consumerChecks(l, r), "");
  EXPECT_EQ(inImageGeometry(l, r), Outcome::kFinite);
}

// Each defect is refused naming the topic and the field.
TEST(CameraInfoCheck, EachDefectIsRefusedNamingTopicAndField) {
  for (const Case& c : refusedCases()) {
    auto [left, right] = validPair();
    c.mutate(left, right);
    const std::string problem = consumerChecks(left, right);
    EXPECT_NE(problem.find(c.needle), std::string::npos) << c.name << ": got \"" << problem << "\"";
  }
}

// The controls: image_geometry, in the child, aborts on the P mismatches, the one-sided
// binning, the all-zero P and the frame ids, and gives NaN for NaN in P: the harness sees what
// the checks guard against. The other refusals are harmless to image_geometry but wrong for
// the rectification or the depth.
TEST(CameraInfoCheck, RefusedPairsAbortOrBreakImageGeometry) {
  int aborted = 0;
  for (const Case& c : refusedCases()) {
    auto [left, right] = validPair();
    c.mutate(left, right);
    const Outcome outcome = inImageGeometry(left, right);
    aborted += outcome == Outcome::kAborted;
    EXPECT_EQ(outcome, c.in_image_geometry) << c.name;
    std::printf("  %-44s image_geometry: %s\n", c.name.c_str(),
                outcome == Outcome::kAborted     ? "ABORT"
                : outcome == Outcome::kNonFinite ? "non-finite"
                                                 : "finite");
  }
  EXPECT_EQ(aborted, 7);
}

// The principal points' margin: a quarter of the image beyond each edge is accepted, beyond
// it refused, for K and P alike.
TEST(CameraInfoCheck, PrincipalPointsWithinTheMarginAreAccepted) {
  for (const double fraction : {-0.24, 1.24, -0.26, 1.26}) {
    const bool inside = fraction > -kPrincipalPointMargin && fraction < 1 + kPrincipalPointMargin;
    for (const int index : {2, 5}) {
      auto [left, right] = validPair();
      left.K[index] = fraction * (index == 2 ? kWidth : kHeight);
      EXPECT_EQ(consumerChecks(left, right).empty(), inside) << "K[" << index << "] at " << fraction;
    }
    for (const int index : {2, 6}) {
      auto [left, right] = validPair();
      left.P[index] = fraction * (index == 2 ? kWidth : kHeight);
      right.P[index] = left.P[index];
      EXPECT_EQ(consumerChecks(left, right).empty(), inside) << "P[" << index << "] at " << fraction;
    }
  }
}

// Real lenses and rectifications pass: a strong barrel lens (k1 -0.35, k2 0.12, as wide-angle
// machine-vision lenses), a rational model, rectifications with alpha 0 and 1 of a head toed in
// by 5 degrees. The refusals start past the documented limits: R turned until the image's centre
// leaves the margin, P scaled past kRectifiedScaleLimit.
TEST(CameraInfoCheck, RealLensesAndRectificationsPassTheLimitsRefuse) {
  {
    auto [left, right] = validPair();
    left.D = {-0.35, 0.12, 0.0, 0.0, -0.02};
    EXPECT_EQ(consumerChecks(left, right), "") << "strong barrel";
  }
  for (const double alpha : {0.0, 1.0}) {
    core::StereoRig rig;
    for (core::PinholeCamera* c : {&rig.left, &rig.right}) {
      c->width = kWidth;
      c->height = kHeight;
      c->fx = c->fy = 650.0;
      c->cx = 376.0;
      c->cy = 240.0;
      c->dist = {{-0.2, 0.05, 0.0, 0.0, 0.0}};
    }
    rig.right_from_left.linear() = Eigen::AngleAxisd(5 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
    rig.right_from_left.translation() = Eigen::Vector3d(-0.12, 0.0, 0.0);
    auto pair = toStereoCameraInfo(rig, alpha);
    pair.first.header.frame_id = pair.second.header.frame_id = "f";
    EXPECT_EQ(consumerChecks(pair.first, pair.second), "") << "toed in 5 degrees, alpha " << alpha;
  }
  // The margins: scale 1.9 passes and 2.1 is refused; the centre's ray turned 30 degrees passes,
  // 45 degrees (beyond the image and its margin at fx' 650) is refused.
  for (const double scale : {1.9, 2.1}) {
    auto [left, right] = validPair();
    left.P[0] = scale * left.K[0];
    EXPECT_EQ(checkCameraInfo(left, "l", kWidth, kHeight).empty(), scale < kRectifiedScaleLimit) << scale;
  }
  for (const double degrees : {30.0, 45.0}) {
    auto [left, right] = validPair();
    const Eigen::Matrix3d turn = Eigen::AngleAxisd(degrees * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> R(left.R.data());
    R = (turn * R).eval();
    EXPECT_EQ(checkCameraInfo(left, "l", kWidth, kHeight).empty(), degrees < 40) << degrees;
  }
}

// Focal lengths against the device's nominal ones: a unit 5 % off its drawing and a 3 % zoom
// pass; 1.2x passes and 1.3x (or 1/1.3x) is refused, naming the field, the ratio and the limit.
TEST(CameraInfoCheck, FocalLengthsNearTheNominalPassFarOnesAreRefused) {
  const auto [left, right] = validPair();
  const double fx = left.K[0], fy = left.K[4];
  for (const double scale : {1.0, 1.05, 1 / 1.05, 1.2, 1 / 1.2})
    EXPECT_EQ(checkNominalFocal(left, "l", fx / scale, fy / scale), "") << scale;
  for (const double scale : {1.3, 1 / 1.3, 3.0}) {
    const std::string problem = checkNominalFocal(left, "l", fx / scale, fy / scale);
    EXPECT_NE(problem.find("l: K: fx (K[0])"), std::string::npos) << scale << ": " << problem;
    EXPECT_NE(problem.find("1.25"), std::string::npos) << problem;
  }
  // fy alone far off.
  EXPECT_NE(checkNominalFocal(left, "l", fx, fy / 1.4).find("fy (K[4])"), std::string::npos);
}

// Round-off between the two P (a file written with fewer digits) is accepted; image_geometry
// compares exactly and aborts on it, which alignRectifiedPair prevents.
TEST(CameraInfoCheck, RoundOffIsAcceptedAndAligned) {
  auto [left, right] = validPair();
  right.P[0] += 1e-7;
  right.P[6] -= 2e-4;
  EXPECT_EQ(consumerChecks(left, right), "");
  EXPECT_EQ(inImageGeometry(left, right), Outcome::kAborted) << "control: image_geometry compares exactly";
  CameraInfo aligned = right;
  alignRectifiedPair(left, &aligned);
  EXPECT_EQ(inImageGeometry(left, aligned), Outcome::kFinite);
  right.P[0] += 2 * kRectifiedPairTolerancePx;
  EXPECT_NE(consumerChecks(left, right), "") << "beyond the tolerance";
}

// Random corruption of every numeric field: whatever the checks accept is safe in
// image_geometry (aligned as the Disparity aligns it).
TEST(CameraInfoCheck, RandomCorruptionsNeverReachAnAssertion) {
  std::mt19937 rng(20240611);
  const double specials[] = {kNaN, INFINITY, -INFINITY, 0.0, -1.0, 1e12, 1e-12};
  int accepted = 0, tried = 0;
  for (int trial = 0; trial < 400; ++trial) {
    auto [left, right] = validPair();
    CameraInfo& target = rng() % 2 ? left : right;
    const int which = static_cast<int>(rng() % 6);
    double* field = nullptr;
    switch (which) {
      case 0:
        field = &target.K[rng() % 9];
        break;
      case 1:
        field = &target.R[rng() % 9];
        break;
      case 2:
        field = &target.P[rng() % 12];
        break;
      case 3:
        field = &target.D[rng() % target.D.size()];
        break;
      case 4:
        target.binning_x = rng() % 4;
        target.binning_y = rng() % 4;
        break;
      default:
        target.roi.x_offset = rng() % 3;
        target.roi.width = rng() % 2 ? kWidth : 0;
        break;
    }
    if (field) {
      const int kind = static_cast<int>(rng() % 3);
      if (kind == 0)
        *field = specials[rng() % 7];
      else if (kind == 1)
        *field += std::uniform_real_distribution<double>(-1e-4, 1e-4)(rng);  // round-off
      else
        *field *= std::uniform_real_distribution<double>(0.5, 1.5)(rng);
    }
    ++tried;
    expectSafeIfAccepted(left, right, "trial " + std::to_string(trial), &accepted);
  }
  std::printf("  %d of %d corrupted pairs accepted (round-off and harmless fields), all safe\n", accepted, tried);
  EXPECT_GT(accepted, 20) << "the property is only tested on accepted pairs";
  EXPECT_LT(accepted, tried - 100);
}
