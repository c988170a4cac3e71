#include "embedded_calibration_stereo/core/calibration/board_calibration.h"

#include <ceres/ceres.h>
#include <ceres/manifold.h>
#include <ceres/product_manifold.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "embedded_calibration_stereo/core/calibration/calibration_initializer.h"
#include "embedded_calibration_stereo/core/calibration/quality_gate.h"
#include "embedded_calibration_stereo/core/calibration/reprojection_cost.h"

namespace embedded_calibration_stereo::core {

std::string ChessboardSpec::validate() const {
  if (cols < 2 || rows < 2) return "the board needs at least 2x2 inner corners";
  if (cols == rows)
    return "square grids (cols == rows) are ambiguous in orientation: use a board with different "
           "numbers of inner corners across and down, e.g. 9x6";
  if (!(square_m > 0) || !std::isfinite(square_m)) return "the square size must be > 0 metres";
  return "";
}

VirtualBoard ChessboardSpec::virtualBoard() const {
  VirtualBoard b;
  b.cols = cols;
  b.rows = rows;
  b.square = square_m;
  return b;
}

std::vector<cv::Point3f> ChessboardSpec::objectPoints() const {
  const VirtualBoard b = virtualBoard();
  std::vector<cv::Point3f> points;
  for (int id = 0; id < b.cornerCount(); ++id) {
    const Eigen::Vector3d p = b.cornerInBoard(id);
    points.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), 0.0f);
  }
  return points;
}

bool parseBoardSize(const std::string& text, int* cols, int* rows, std::string* error) {
  int c = 0, r = 0;
  char tail = 0;
  if (std::sscanf(text.c_str(), "%dx%d%c", &c, &r, &tail) != 2 || c < 2 || r < 2) {
    *error = "board size '" + text + "' must be COLSxROWS inner corners, e.g. 9x6";
    return false;
  }
  *cols = c;
  *rows = r;
  return true;
}

bool detectChessboard(const cv::Mat& image, int cols, int rows, CornerDetector detector,
                      std::vector<cv::Point2f>* corners) {
  cv::Mat grey = image;
  if (image.channels() == 3) cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  if (image.channels() == 4) cv::cvtColor(image, grey, cv::COLOR_BGRA2GRAY);
  if (grey.depth() != CV_8U || grey.channels() != 1) return false;
  corners->clear();
  const cv::Size pattern(cols, rows);
  if (detector == CornerDetector::kSectorBased)
    return cv::findChessboardCornersSB(grey, pattern, *corners, cv::CALIB_CB_ACCURACY) &&
           static_cast<int>(corners->size()) == cols * rows;
  // The classic detector on a global threshold is fast but misses some boards (its
  // adaptive-threshold modes miss as many and are far slower); the slower sector-based one
  // finds them, so it is the fallback. Either way cornerSubPix places the corners.
  const bool found = cv::findChessboardCorners(grey, pattern, *corners, 0) ||
                     cv::findChessboardCornersSB(grey, pattern, *corners);
  if (!found || static_cast<int>(corners->size()) != cols * rows) return false;
  // Window half-size: 0.4 of the smallest corner spacing (so no window reaches a neighbouring
  // corner), 2..6 px.
  double spacing = std::numeric_limits<double>::infinity();
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const cv::Point2f& p = (*corners)[r * cols + c];
      if (c + 1 < cols) spacing = std::min(spacing, cv::norm(p - (*corners)[r * cols + c + 1]));
      if (r + 1 < rows) spacing = std::min(spacing, cv::norm(p - (*corners)[(r + 1) * cols + c]));
    }
  const int half = std::clamp(static_cast<int>(0.4 * spacing), 2, 6);
  cv::cornerSubPix(grey, *corners, cv::Size(half, half), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS | cv::TermCriteria::COUNT, 50, 1e-3));
  return true;
}

namespace {

std::vector<cv::Point2f> flippedGrid(const std::vector<cv::Point2f>& corners, int cols, int rows,
                                     bool flip_rows, bool flip_cols) {
  std::vector<cv::Point2f> out(corners.size());
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
      out[r * cols + c] =
          corners[(flip_rows ? rows - 1 - r : r) * cols + (flip_cols ? cols - 1 - c : c)];
  return out;
}

}  // namespace

void orientConsistently(StereoBoardDetection* d, int cols, int rows) {
  const size_t n = static_cast<size_t>(cols * rows);
  if (cols < 2 || rows < 2 || d->left.size() != n || d->right.size() != n) return;
  if (d->left.front().y > d->left.back().y) std::reverse(d->left.begin(), d->left.end());
  // Directions along a row and down a column; the right grid is flipped until both agree.
  const auto along = [&](const std::vector<cv::Point2f>& c) { return c[cols - 1] - c[0]; };
  const auto down = [&](const std::vector<cv::Point2f>& c) { return c[(rows - 1) * cols] - c[0]; };
  const auto unit = [](cv::Point2f v) {
    return v * (1.0f / std::max(1e-6f, std::hypot(v.x, v.y)));
  };
  double best_score = -1e9;
  std::vector<cv::Point2f> best;
  for (int flips = 0; flips < 4; ++flips) {
    std::vector<cv::Point2f> candidate = flippedGrid(d->right, cols, rows, flips & 1, flips & 2);
    const double score = unit(along(candidate)).dot(unit(along(d->left))) +
                         unit(down(candidate)).dot(unit(down(d->left)));
    if (score > best_score) {
      best_score = score;
      best = std::move(candidate);
    }
  }
  d->right = std::move(best);
}

int openCvDistortionFlags(const BoardCalibrationOptions& o) {
  int flags = 0;
  if (!o.estimate_tangential) flags |= cv::CALIB_ZERO_TANGENT_DIST;
  if (!o.estimate_k3) flags |= cv::CALIB_FIX_K3;
  return flags;
}

namespace {

PinholeCamera cameraFromOpenCv(const cv::Mat& k, const cv::Mat& d, const cv::Size& size) {
  PinholeCamera c;
  c.width = size.width;
  c.height = size.height;
  c.fx = k.at<double>(0, 0);
  c.fy = k.at<double>(1, 1);
  c.cx = k.at<double>(0, 2);
  c.cy = k.at<double>(1, 2);
  const cv::Mat flat = d.reshape(1, 1);
  for (int i = 0; i < 5 && i < flat.cols; ++i) c.dist[i] = flat.at<double>(i);
  return c;
}

BoardView boardView(int frame, CameraSide side, const std::vector<cv::Point2f>& corners) {
  BoardView v;
  v.frame = frame;
  v.camera = side;
  for (size_t i = 0; i < corners.size(); ++i) {
    v.corner_ids.push_back(static_cast<int>(i));
    v.pixels.emplace_back(corners[i].x, corners[i].y);
  }
  return v;
}

BoardCorners boardCorners(const std::vector<cv::Point2f>& corners) {
  BoardCorners b;
  for (size_t i = 0; i < corners.size(); ++i) {
    b.corner_ids.push_back(static_cast<int>(i));
    b.u.push_back(corners[i].x);
    b.v.push_back(corners[i].y);
  }
  return b;
}

std::unique_ptr<ceres::LossFunction> makeLoss(RobustLoss loss, double scale) {
  if (loss == RobustLoss::kHuber) return std::make_unique<ceres::HuberLoss>(scale);
  if (loss == RobustLoss::kCauchy) return std::make_unique<ceres::CauchyLoss>(scale);
  return nullptr;
}
// The rig's parameter blocks as the adjustment lays them out, held in the pose fit.
struct RigBlocks {
  std::array<double, kIntrinsicsSize> left, right;
  std::array<double, kExtrinsicsSize> extrinsics;
};

RigBlocks rigBlocks(const StereoRig& rig) {
  auto block = [](const PinholeCamera& c) {
    return std::array<double, kIntrinsicsSize>{
        {c.fx, c.fy, c.cx, c.cy, c.dist[0], c.dist[1], c.dist[2], c.dist[3], c.dist[4]}};
  };
  RigBlocks b;
  b.left = block(rig.left);
  b.right = block(rig.right);
  const Eigen::Vector3d r = rotationVector(rig.right_from_left.linear()), t = rig.right_from_left.translation();
  b.extrinsics = {{r.x(), r.y(), r.z(), t.x(), t.y(), t.z()}};
  return b;
}

// One pair's board as both cameras saw it.
struct PairViews {
  BoardView left, right;
};

// The pose to start from: PnP in the left camera, else in the right, else the identity.
std::array<double, kBoardPoseSize> startPose(const StereoRig& rig, const PairViews& views,
                                             const VirtualBoard& board) {
  Eigen::Isometry3d rig_from_board;
  if (!estimateRigFromBoard(rig, views.left, board, &rig_from_board) &&
      !estimateRigFromBoard(rig, views.right, board, &rig_from_board))
    rig_from_board = Eigen::Isometry3d::Identity();
  const Eigen::Quaterniond q(rig_from_board.linear());
  return {{q.x(), q.y(), q.z(), q.w(), rig_from_board.translation().x(), rig_from_board.translation().y(),
           rig_from_board.translation().z()}};
}

// Fits the board pose (x y z w quaternion, translation) to both views with the rig held.
void fitBoardPose(const PairViews& views, const VirtualBoard& board, const BoardCalibrationOptions& options,
                  RigBlocks* rig, std::array<double, kBoardPoseSize>* pose) {
  ceres::Problem::Options po;
  po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  const std::unique_ptr<ceres::LossFunction> loss = makeLoss(options.loss, options.loss_scale_px);
  for (const BoardView* v : {&views.left, &views.right}) {
    for (size_t i = 0; i < v->size(); ++i) {
      const Eigen::Vector3d corner = board.cornerInBoard(v->corner_ids[i]);
      if (v->camera == CameraSide::kLeft)
        problem.AddResidualBlock(LeftCornerReprojectionCost::Create(corner, v->pixels[i]),
                                 loss.get(), rig->left.data(), pose->data());
      else
        problem.AddResidualBlock(RightCornerReprojectionCost::Create(corner, v->pixels[i]),
                                 loss.get(), rig->right.data(), pose->data(), rig->extrinsics.data());
    }
  }
  for (double* b : {rig->left.data(), rig->right.data(), rig->extrinsics.data()})
    if (problem.HasParameterBlock(b)) problem.SetParameterBlockConstant(b);
  problem.SetManifold(
      pose->data(),
      new ceres::ProductManifold<ceres::EigenQuaternionManifold, ceres::EuclideanManifold<3>>());
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.logging_type = ceres::SILENT;
  so.function_tolerance = 1e-12;
  so.parameter_tolerance = 1e-12;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
}

// One camera's residuals (predicted - observed) and observed pixels; returns their RMS.
double viewResiduals(const BoardView& v, const PinholeCamera& camera, const Eigen::Isometry3d& camera_from_board,
                     const VirtualBoard& board, std::vector<Eigen::Vector2d>* residuals) {
  double sum_sq = 0.0;
  for (size_t i = 0; i < v.size(); ++i) {
    Eigen::Vector2d predicted;
    if (!camera.project(camera_from_board * board.cornerInBoard(v.corner_ids[i]), &predicted))
      predicted = Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
    residuals->push_back(predicted - v.pixels[i]);
    sum_sq += residuals->back().squaredNorm();
  }
  return v.size() ? std::sqrt(sum_sq / v.size()) : 0.0;
}

// The board pose of one pair re-fitted on the final rig (held), with the adjustment's loss:
// the per-frame pose of the adjustment's optimum, whose residuals the report shows per image.
PairResiduals pairResiduals(const StereoRig& rig, const VirtualBoard& board,
                            const StereoBoardDetection& d, int frame,
                            const BoardCalibrationOptions& options) {
  PairResiduals out;
  out.name = d.name;
  const PairViews views{boardView(frame, CameraSide::kLeft, d.left), boardView(frame, CameraSide::kRight, d.right)};
  std::array<double, kBoardPoseSize> pose = startPose(rig, views, board);
  RigBlocks blocks = rigBlocks(rig);
  fitBoardPose(views, board, options, &blocks, &pose);

  Eigen::Isometry3d fitted = Eigen::Isometry3d::Identity();
  fitted.linear() =
      Eigen::Quaterniond(pose[3], pose[0], pose[1], pose[2]).normalized().toRotationMatrix();
  fitted.translation() = Eigen::Vector3d(pose[4], pose[5], pose[6]);
  out.rms_left_px = viewResiduals(views.left, rig.left, Eigen::Isometry3d::Identity() * fitted, board, &out.left);
  out.left_pixels = views.left.pixels;
  out.rms_right_px = viewResiduals(views.right, rig.right, rig.right_from_left * fitted, board, &out.right);
  out.right_pixels = views.right.pixels;
  const double n_left = static_cast<double>(views.left.size());
  const double n_right = static_cast<double>(views.right.size());
  out.rms_px = std::sqrt(
      (out.rms_left_px * out.rms_left_px * n_left + out.rms_right_px * out.rms_right_px * n_right) /
      std::max(1.0, n_left + n_right));
  return out;
}

// What calibrateStereoBoard calibrates from.
struct BoardProblem {
  const ChessboardSpec& board;
  cv::Size image_size;
  const std::vector<StereoBoardDetection>& detections;
  const BoardCalibrationOptions& options;
};

// Why the detections cannot be calibrated from; empty when they can.
std::string inputProblem(const BoardProblem& p) {
  const std::string board_problem = p.board.validate();
  if (!board_problem.empty()) return board_problem;
  if (p.image_size.width <= 0 || p.image_size.height <= 0) return "invalid image size";
  const size_t corner_count = static_cast<size_t>(p.board.cols * p.board.rows);
  for (const StereoBoardDetection& d : p.detections)
    if (d.left.size() != corner_count || d.right.size() != corner_count)
      return "pair '" + d.name + "' does not have all " + std::to_string(corner_count) + " corners in both images";
  if (static_cast<int>(p.detections.size()) < std::max(p.options.min_pairs, 3))
    return std::to_string(p.detections.size()) + " usable image pair(s), at least " +
           std::to_string(std::max(p.options.min_pairs, 3)) + " needed";
  return "";
}

// 1. OpenCV start: each camera alone, then R, T with the intrinsics held. Sets *start and
// out->opencv_initial_rms_px; returns why it failed, empty when it did not.
std::string openCvStart(const BoardProblem& p, StereoRig* start, BoardCalibrationResult* out) {
  const std::vector<std::vector<cv::Point3f>> object(p.detections.size(), p.board.objectPoints());
  std::vector<std::vector<cv::Point2f>> left_points, right_points;
  for (const StereoBoardDetection& d : p.detections) {
    left_points.push_back(d.left);
    right_points.push_back(d.right);
  }
  const int flags = openCvDistortionFlags(p.options);
  cv::Mat k_left, d_left, k_right, d_right, rotation, translation, essential, fundamental;
  try {
    cv::calibrateCamera(object, left_points, p.image_size, k_left, d_left, cv::noArray(),
                        cv::noArray(), flags);
    cv::calibrateCamera(object, right_points, p.image_size, k_right, d_right, cv::noArray(),
                        cv::noArray(), flags);
    out->opencv_initial_rms_px = cv::stereoCalibrate(
        object, left_points, right_points, k_left, d_left, k_right, d_right, p.image_size, rotation,
        translation, essential, fundamental, flags | cv::CALIB_FIX_INTRINSIC);
  } catch (const cv::Exception& e) {
    return std::string("OpenCV initialisation failed: ") + e.what();
  }
  start->left = cameraFromOpenCv(k_left, d_left, p.image_size);
  start->right = cameraFromOpenCv(k_right, d_right, p.image_size);
  Eigen::Matrix3d r;
  Eigen::Vector3d t;
  cv::cv2eigen(rotation, r);
  cv::cv2eigen(translation.reshape(1, 3), t);
  start->right_from_left.linear() = r;
  start->right_from_left.translation() = t;
  const std::string start_problem = start->validate();
  if (!start_problem.empty()) return "OpenCV initialisation is unusable: " + start_problem;
  return "";
}

// 2. Joint refinement with a free board pose per pair, and covariance: sets out->summary (and,
// when it succeeded, out->rig and out->rms_px); false when it failed.
bool jointRefinement(const BoardProblem& p, const StereoRig& start, const std::vector<VirtualBoard>& layout,
                     BoardCalibrationResult* out) {
  std::vector<StereoObservation> frames;
  for (size_t i = 0; i < p.detections.size(); ++i) {
    StereoObservation o;
    o.stamp = static_cast<double>(i);
    o.left.push_back(boardCorners(p.detections[i].left));
    o.right.push_back(boardCorners(p.detections[i].right));
    frames.push_back(std::move(o));
  }
  BundleAdjustmentOptions ba_options;
  ba_options.board_pose_mode = BoardPoseMode::kPerFrame;
  ba_options.initialization = InitializationMode::kFromInForce;
  ba_options.loss = p.options.loss;
  ba_options.loss_scale_px = p.options.loss_scale_px;
  ba_options.max_iterations = 200;
  BundleAdjustmentConfig config;
  config.estimate_tangential = p.options.estimate_tangential;
  config.estimate_k3 = p.options.estimate_k3;
  CalibrationInput input;
  input.frames = &frames;
  input.boards = &layout;
  input.image_width = p.image_size.width;
  input.image_height = p.image_size.height;
  input.in_force = start;
  out->summary = BundleAdjuster(ba_options, config).Solve(input);
  if (!out->summary.success) return false;
  out->rig = out->summary.rig;
  out->rms_px = combinedRms(out->summary);
  return true;
}

}  // namespace

BoardCalibrationResult calibrateStereoBoard(const ChessboardSpec& board, const cv::Size& image_size,
                                            std::vector<StereoBoardDetection> detections,
                                            const BoardCalibrationOptions& options) {
  BoardCalibrationResult out;
  const auto fail = [&](const std::string& why) {
    out.ok = false;
    out.message = why;
    return out;
  };
  const BoardProblem problem{board, image_size, detections, options};
  const std::string input_problem = inputProblem(problem);
  if (!input_problem.empty()) return fail(input_problem);
  for (StereoBoardDetection& d : detections) orientConsistently(&d, board.cols, board.rows);

  StereoRig start;
  const std::string start_problem = openCvStart(problem, &start, &out);
  if (!start_problem.empty()) return fail(start_problem);
  const std::vector<VirtualBoard> layout = {board.virtualBoard()};
  if (!jointRefinement(problem, start, layout, &out))
    return fail("bundle adjustment failed: " + out.summary.message);

  // 3. Per-pair residuals and rectification.
  for (size_t i = 0; i < detections.size(); ++i)
    out.pairs.push_back(
        pairResiduals(out.rig, layout[0], detections[i], static_cast<int>(i), options));
  try {
    out.rectification = computeRectificationGeometry(out.rig, options.rectification);
  } catch (const std::exception& e) {
    return fail(std::string("rectification failed: ") + e.what());
  }
  out.ok = true;
  return out;
}

}  // namespace embedded_calibration_stereo::core
