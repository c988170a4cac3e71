#include "embedded_calibration_stereo/test_support/flat_board_images.h"

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <random>

#include "sim/camera_rays.h"
#include "sim/device_renderer.h"

namespace embedded_calibration_stereo::core {

namespace {

cv::Mat renderOneCamera(const PinholeCamera& camera, const VirtualBoard& board,
                        const Eigen::Isometry3d& rig_from_camera,
                        const FlatBoardImageOptions& options, uint64_t seed) {
  const sim::CameraRays rays = sim::computeCameraRays(camera);
  cv::Mat radiance;
  sim::renderDevice({board}, rays, rig_from_camera, options.white, options.black, &radiance);
  if (options.psf_sigma_px > 0)
    cv::GaussianBlur(radiance, radiance, cv::Size(), options.psf_sigma_px, 0, cv::BORDER_REPLICATE);
  cv::Mat grey = radiance * 255.0;
  if (options.noise_sigma > 0) {
    cv::Mat noise(grey.size(), CV_32F);
    cv::RNG rng(seed);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, options.noise_sigma);
    grey += noise;
  }
  cv::Mat out;
  grey.convertTo(out, CV_8U);  // rounds and saturates
  return out;
}

BoardCorners visibleCorners(const PinholeCamera& camera, const VirtualBoard& board,
                            const Eigen::Isometry3d& camera_from_rig) {
  BoardCorners corners;
  corners.board_id = board.virtual_id;
  for (int id = 0; id < board.cornerCount(); ++id) {
    Eigen::Vector2d pixel;
    if (!camera.project(camera_from_rig * board.cornerInRig(id), &pixel) || !camera.inImage(pixel))
      continue;
    corners.corner_ids.push_back(id);
    corners.u.push_back(static_cast<float>(pixel.x()));
    corners.v.push_back(static_cast<float>(pixel.y()));
  }
  return corners;
}

// True when the board's outline (margin included), sampled along its edges, projects inside
// the camera with `margin` pixels to spare.
bool outlineInside(const PinholeCamera& camera, const Eigen::Isometry3d& camera_from_board,
                   int cols, int rows, double square, double margin) {
  const double x0 = -2.0 * square, x1 = (cols + 1) * square;
  const double y0 = -2.0 * square, y1 = (rows + 1) * square;
  constexpr int kSamples = 8;
  for (int i = 0; i <= kSamples; ++i) {
    const double t = static_cast<double>(i) / kSamples;
    const Eigen::Vector3d points[4] = {{x0 + t * (x1 - x0), y0, 0},
                                       {x0 + t * (x1 - x0), y1, 0},
                                       {x0, y0 + t * (y1 - y0), 0},
                                       {x1, y0 + t * (y1 - y0), 0}};
    for (const Eigen::Vector3d& p : points) {
      Eigen::Vector2d pixel;
      if (!camera.project(camera_from_board * p, &pixel) || !camera.inImage(pixel, margin))
        return false;
    }
  }
  return true;
}

}  // namespace

FlatBoardImagePair renderFlatBoardPair(const StereoRig& rig, const VirtualBoard& board,
                                       const FlatBoardImageOptions& options, uint64_t noise_seed) {
  FlatBoardImagePair pair;
  pair.left =
      renderOneCamera(rig.left, board, Eigen::Isometry3d::Identity(), options, noise_seed * 2 + 1);
  pair.right = renderOneCamera(rig.right, board, rig.leftFromRight(), options, noise_seed * 2 + 2);
  pair.truth.left.push_back(visibleCorners(rig.left, board, Eigen::Isometry3d::Identity()));
  pair.truth.right.push_back(visibleCorners(rig.right, board, rig.right_from_left));
  return pair;
}

std::vector<Eigen::Isometry3d> flatBoardCalibrationPoses(const StereoRig& rig, int cols, int rows,
                                                         double square,
                                                         const FlatBoardPoseOptions& options,
                                                         uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const auto uniform = [&](double lo, double hi) { return lo + (hi - lo) * unit(rng); };
  // Image positions of the board centre, visited in turn: centre, edges, corners of the
  // region both cameras share (the right camera sees the board shifted left by the disparity).
  const double fractions[3] = {0.3, 0.5, 0.7};
  const Eigen::Vector3d centre_in_board((cols - 1) * square / 2.0, (rows - 1) * square / 2.0, 0);
  // The renderer draws a board's +z side: facing the camera means z toward it (x right, y up).
  const Eigen::AngleAxisd facing_camera(M_PI, Eigen::Vector3d::UnitX());
  std::vector<Eigen::Isometry3d> poses;
  const int max_attempts = options.count * 400;
  for (int attempt = 0; attempt < max_attempts && static_cast<int>(poses.size()) < options.count;
       ++attempt) {
    const int cell = static_cast<int>(poses.size()) % 9;
    const Eigen::Vector2d target(
        fractions[cell % 3] * rig.left.width + uniform(-0.06, 0.06) * rig.left.width,
        fractions[cell / 3] * rig.left.height + uniform(-0.06, 0.06) * rig.left.height);
    const Eigen::Vector2d xn = rig.left.pixelToNormalized(target);
    const double distance = uniform(options.min_distance_m, options.max_distance_m);
    const Eigen::Vector3d centre = Eigen::Vector3d(xn.x(), xn.y(), 1.0).normalized() * distance;
    const double axis_angle = uniform(0.0, 2.0 * M_PI);
    const double tilt = uniform(options.min_tilt_deg, options.max_tilt_deg) * M_PI / 180.0;
    const double roll = uniform(-20.0, 20.0) * M_PI / 180.0;
    Eigen::Isometry3d rig_from_board = Eigen::Isometry3d::Identity();
    rig_from_board.linear() =
        (Eigen::AngleAxisd(tilt, Eigen::Vector3d(std::cos(axis_angle), std::sin(axis_angle), 0)) *
         Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) * facing_camera)
            .toRotationMatrix();
    rig_from_board.translation() = centre - rig_from_board.linear() * centre_in_board;
    if (outlineInside(rig.left, rig_from_board, cols, rows, square, options.image_margin_px) &&
        outlineInside(rig.right, rig.right_from_left * rig_from_board, cols, rows, square,
                      options.image_margin_px))
      poses.push_back(rig_from_board);
  }
  return poses;
}

}  // namespace embedded_calibration_stereo::core
