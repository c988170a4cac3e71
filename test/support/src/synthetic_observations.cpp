#include "embedded_calibration_stereo/test_support/synthetic_observations.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace embedded_calibration_stereo::core {

namespace {

BoardCorners projectBoard(const PinholeCamera& camera, const Eigen::Isometry3d& camera_from_rig,
                          const VirtualBoard& board, const SyntheticObservationOptions& options,
                          std::mt19937_64* rng) {
  std::normal_distribution<double> noise(0.0, options.noise_sigma_px);
  BoardCorners out;
  out.board_id = board.virtual_id;
  const Eigen::Isometry3d camera_from_board = camera_from_rig * board.rig_from_board;
  const Eigen::Vector3d normal = camera_from_board.linear().col(2);
  for (int id = 0; id < board.cornerCount(); ++id) {
    const Eigen::Vector3d p = camera_from_board * board.cornerInBoard(id);
    // A board seen from behind: its front normal points away from the viewing ray's origin.
    if (options.cull_back_facing && normal.dot(p) >= 0.0) continue;
    Eigen::Vector2d pixel;
    if (!camera.project(p, &pixel) || !camera.inImage(pixel, options.margin_px)) continue;
    out.corner_ids.push_back(id);
    const double sigma = options.noise_sigma_px;
    out.u.push_back(static_cast<float>(pixel.x() + (sigma > 0 ? noise(*rng) : 0.0)));
    out.v.push_back(static_cast<float>(pixel.y() + (sigma > 0 ? noise(*rng) : 0.0)));
  }
  return out;
}

}  // namespace

std::vector<StereoObservation> generateSyntheticObservations(
    const StereoRig& rig, const std::vector<VirtualBoard>& boards,
    const SyntheticObservationOptions& options) {
  std::mt19937_64 rng(options.seed);
  std::vector<StereoObservation> frames;
  frames.reserve(static_cast<size_t>(std::max(options.frames, 0)));
  for (int f = 0; f < options.frames; ++f) {
    StereoObservation obs;
    obs.stamp = options.first_stamp_s + f * options.frame_period_s;
    for (const VirtualBoard& board : boards) {
      BoardCorners left =
          projectBoard(rig.left, Eigen::Isometry3d::Identity(), board, options, &rng);
      if (left.size() > 0) obs.left.push_back(std::move(left));
      BoardCorners right = projectBoard(rig.right, rig.right_from_left, board, options, &rng);
      if (right.size() > 0) obs.right.push_back(std::move(right));
    }
    frames.push_back(std::move(obs));
  }
  return frames;
}

std::vector<VirtualBoard> makeSpreadVirtualBoards(const PinholeCamera& left,
                                                  const SpreadBoardsOptions& options) {
  std::vector<VirtualBoard> boards;
  const int n = std::max(options.count, 0);
  if (n == 0) return boards;
  const double aspect = static_cast<double>(left.width) / std::max(left.height, 1);
  const int grid_cols = std::max(1, static_cast<int>(std::lround(std::sqrt(n * aspect))));
  const int grid_rows = (n + grid_cols - 1) / grid_cols;
  const auto gridCoordinate = [](int i, int count) {
    return count > 1 ? -1.0 + 2.0 * i / (count - 1) : 0.0;
  };
  const double tilt = options.tilt_deg * M_PI / 180.0;
  // Board frame facing the camera: x to the right, y up, z (front normal) toward the camera.
  const Eigen::Matrix3d facing = Eigen::Vector3d(1.0, -1.0, -1.0).asDiagonal();
  for (int i = 0; i < n; ++i) {
    VirtualBoard b;
    b.virtual_id = i;
    b.board_index = i % 3;
    b.copy_index = i / 3;
    b.cols = options.cols;
    b.rows = options.rows;
    b.square = options.square_m;
    b.mirrored = (i % 2) == 1;
    const int gx = i % grid_cols, gy = i / grid_cols;
    const Eigen::Vector2d centre_px(
        left.cx + options.spread * 0.5 * (left.width - 1) * gridCoordinate(gx, grid_cols),
        left.cy + options.spread * 0.5 * (left.height - 1) * gridCoordinate(gy, grid_rows));
    const Eigen::Vector2d ray = left.pixelToNormalized(centre_px);
    const Eigen::Vector3d centre(ray.x() * options.distance_m, ray.y() * options.distance_m,
                                 options.distance_m);
    // Alternate the tilt signs so neighbouring boards are seen at different orientations.
    const double sx = (i % 2 == 0) ? 1.0 : -1.0, sy = ((i / 2) % 2 == 0) ? 1.0 : -1.0;
    const Eigen::Matrix3d rotation = (Eigen::AngleAxisd(sx * tilt, Eigen::Vector3d::UnitX()) *
                                      Eigen::AngleAxisd(sy * tilt, Eigen::Vector3d::UnitY()) *
                                      Eigen::AngleAxisd(0.15 * i, Eigen::Vector3d::UnitZ()))
                                         .toRotationMatrix() *
                                     facing;
    b.rig_from_board.linear() = rotation;
    b.rig_from_board.translation() = Eigen::Vector3d::Zero();
    // Put the board's middle (local, including the mirrored y flip) at `centre`.
    const Eigen::Vector3d local_middle =
        0.5 * (b.cornerInBoard(0) + b.cornerInBoard(b.cornerCount() - 1));
    b.rig_from_board.translation() = centre - rotation * local_middle;
    boards.push_back(b);
  }
  return boards;
}

StereoRig makeSimLikeStereoRig() {
  StereoRig rig;
  PinholeCamera& l = rig.left;
  l.width = 752;
  l.height = 480;
  l.fx = 650.0;
  l.fy = 648.0;
  l.cx = 370.0;
  l.cy = 245.0;
  l.dist = {{-0.28, 0.07, 0.0, 0.0, 0.0}};
  PinholeCamera& r = rig.right;
  r = l;
  r.fx = 652.5;
  r.fy = 649.8;
  r.cx = 376.0;
  r.cy = 241.5;
  r.dist = {{-0.275, 0.068, 0.0, 0.0, 0.0}};
  rig.right_from_left.linear() = rotationFromVectorDeg(Eigen::Vector3d(0.2, 0.4, 0.2));
  rig.right_from_left.translation() = Eigen::Vector3d(-0.12, 0.0008, 0.0004).normalized() * 0.12;
  return rig;
}

CalibrationDevice perturbDevice(const CalibrationDevice& device, double position_m,
                                double angle_deg, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  const auto randomUnit = [&]() {
    Eigen::Vector3d v(gauss(rng), gauss(rng), gauss(rng));
    return v.normalized();
  };
  const double angle = angle_deg * M_PI / 180.0;
  CalibrationDevice out = device;
  out.rig_from_device.linear() =
      Eigen::AngleAxisd(angle, randomUnit()).toRotationMatrix() * device.rig_from_device.linear();
  out.rig_from_device.translation() += position_m * randomUnit();
  for (std::vector<MirrorPlane>& chain : out.copies)
    for (MirrorPlane& m : chain) {
      const Eigen::Vector3d n = m.normal.normalized();
      const double d = m.distance / m.normal.norm();
      const Eigen::Vector3d axis = n.cross(randomUnit()).normalized();  // in the plane
      m.normal = Eigen::AngleAxisd(angle, axis) * n;
      m.distance = d + (gauss(rng) < 0 ? -position_m : position_m);
    }
  return out;
}

CalibrationDevice perturbBoardPlacement(const CalibrationDevice& device, double position_m,
                                        double angle_deg, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  CalibrationDevice out = device;
  for (Chessboard& b : out.boards) {
    const Eigen::Vector3d turn(unit(rng), unit(rng), unit(rng));
    const Eigen::Vector3d shift(unit(rng), unit(rng), unit(rng));
    const Eigen::Vector3d rv = turn * angle_deg * M_PI / 180.0;
    b.device_from_board.linear() =
        Eigen::AngleAxisd(rv.norm(), rv.normalized()).toRotationMatrix() * b.device_from_board.linear();
    b.device_from_board.translation() += shift * position_m;
  }
  return out;
}

RigErrors compareRigs(const StereoRig& estimate, const StereoRig& truth) {
  RigErrors e;
  const PinholeCamera* est[2] = {&estimate.left, &estimate.right};
  const PinholeCamera* tru[2] = {&truth.left, &truth.right};
  for (int c = 0; c < 2; ++c) {
    e.fx_rel[c] = std::abs(est[c]->fx - tru[c]->fx) / tru[c]->fx;
    e.fy_rel[c] = std::abs(est[c]->fy - tru[c]->fy) / tru[c]->fy;
    e.cx_px[c] = std::abs(est[c]->cx - tru[c]->cx);
    e.cy_px[c] = std::abs(est[c]->cy - tru[c]->cy);
    e.k1[c] = std::abs(est[c]->dist[0] - tru[c]->dist[0]);
    e.k2[c] = std::abs(est[c]->dist[1] - tru[c]->dist[1]);
  }
  e.baseline_rel = std::abs(estimate.baseline() - truth.baseline()) / truth.baseline();
  e.rotation_deg =
      rotationAngleDeg(estimate.right_from_left.linear(), truth.right_from_left.linear());
  return e;
}

StereoRig driftedRig(const StereoRig& truth, double focal_scale,
                     const Eigen::Vector3d& rotation_deg) {
  StereoRig rig = truth;
  rig.left = rig.left.withFocalScale(focal_scale);
  rig.right = rig.right.withFocalScale(focal_scale);
  // About the right camera's centre: its translation turns with it.
  Eigen::Isometry3d turn = Eigen::Isometry3d::Identity();
  turn.linear() = rotationFromVectorDeg(rotation_deg);
  rig.right_from_left = turn * rig.right_from_left;
  return rig;
}

std::vector<SceneMatch> generateSyntheticSceneMatches(const StereoRig& rig, int count, double noise_px,
                                                      double wrong, uint64_t seed, int* wrong_count) {
  if (wrong_count) *wrong_count = 0;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, noise_px);
  std::vector<SceneMatch> matches;
  while (static_cast<int>(matches.size()) < count) {
    const Eigen::Vector2d left(uniform(rng) * rig.left.width, uniform(rng) * rig.left.height);
    const double z = 1.0 / (1.0 / 22.0 + uniform(rng) * (1.0 / 1.5 - 1.0 / 22.0));
    Eigen::Vector2d right;
    const Eigen::Vector3d p = z * rig.left.pixelToNormalized(left).homogeneous();
    if (!rig.right.project(rig.right_from_left * p, &right) || !rig.right.inImage(right)) continue;
    const Eigen::Vector2d l = left + Eigen::Vector2d(noise(rng), noise(rng));
    Eigen::Vector2d r = right + Eigen::Vector2d(noise(rng), noise(rng));
    if (uniform(rng) < wrong) {
      const double across = (1.0 + 2.0 * uniform(rng)) * (uniform(rng) < 0.5 ? -1.0 : 1.0);
      r += Eigen::Vector2d(20.0 * uniform(rng) - 10.0, across);
      if (wrong_count) ++*wrong_count;
    }
    matches.push_back({static_cast<float>(l.x()), static_cast<float>(l.y()), static_cast<float>(r.x()),
                       static_cast<float>(r.y())});
  }
  return matches;
}

}  // namespace embedded_calibration_stereo::core
