#include "embedded_calibration_stereo/core/calibration/calibration_initializer.h"

#include <algorithm>
#include <map>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

namespace embedded_calibration_stereo::core {

namespace {

std::vector<cv::Point3f> objectPoints(const BoardView& view, const VirtualBoard& board) {
  std::vector<cv::Point3f> points;
  points.reserve(view.size());
  for (int id : view.corner_ids) {
    const Eigen::Vector3d p = board.cornerInBoard(id);
    points.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), 0.0f);
  }
  return points;
}

std::vector<cv::Point2f> imagePoints(const BoardView& view) {
  std::vector<cv::Point2f> points;
  points.reserve(view.size());
  for (const Eigen::Vector2d& p : view.pixels)
    points.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
  return points;
}

Eigen::Isometry3d poseFromOpenCv(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat r;
  cv::Rodrigues(rvec, r);
  Eigen::Matrix3d rotation;
  Eigen::Vector3d translation;
  cv::cv2eigen(r, rotation);
  cv::cv2eigen(tvec.reshape(1, 3), translation);
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = rotation;
  pose.translation() = translation;
  return pose;
}

// Zhang's closed form for one camera on the given views; fills the camera and, per board index,
// camera_from_board.
bool calibrateOneCamera(const std::vector<const BoardView*>& views,
                        const std::vector<VirtualBoard>& boards, int width, int height,
                        PinholeCamera* camera, std::map<int, Eigen::Isometry3d>* poses,
                        std::string* message) {
  std::vector<std::vector<cv::Point3f>> object;
  std::vector<std::vector<cv::Point2f>> image;
  for (const BoardView* v : views) {
    object.push_back(objectPoints(*v, boards[v->board]));
    image.push_back(imagePoints(*v));
  }
  // Zhang's closed form on the boards' homographies (principal point at the image centre,
  // no distortion). OpenCV's full calibrateCamera refinement is left out on purpose: the
  // bundle adjustment refines everything from here, so it would be paid for twice.
  cv::Mat k;
  std::vector<cv::Mat> rvecs(views.size()), tvecs(views.size());
  try {
    k = cv::initCameraMatrix2D(object, image, cv::Size(width, height), 0.0);
    for (size_t i = 0; i < views.size(); ++i)
      if (!cv::solvePnP(object[i], image[i], k, cv::noArray(), rvecs[i], tvecs[i], false,
                        cv::SOLVEPNP_IPPE)) {
        *message = "Zhang initialisation: no pose for a board";
        return false;
      }
  } catch (const cv::Exception& e) {
    *message = std::string("Zhang initialisation failed in OpenCV: ") + e.what();
    return false;
  }
  camera->width = width;
  camera->height = height;
  camera->fx = k.at<double>(0, 0);
  camera->fy = k.at<double>(1, 1);
  camera->cx = k.at<double>(0, 2);
  camera->cy = k.at<double>(1, 2);
  camera->skew = 0.0;
  camera->dist = {{0.0, 0.0, 0.0, 0.0, 0.0}};
  const std::string problem = camera->validate();
  if (!problem.empty()) {
    *message = "Zhang initialisation gave an unusable camera: " + problem;
    return false;
  }
  for (size_t i = 0; i < views.size(); ++i)
    (*poses)[views[i]->board] = poseFromOpenCv(rvecs[i], tvecs[i]);
  return true;
}

}  // namespace

ZhangInitialization initializeWithZhang(const std::vector<BoardView>& views,
                                        const std::vector<VirtualBoard>& boards, int image_width,
                                        int image_height, int min_views) {
  ZhangInitialization out;
  std::map<int, size_t> corners_per_frame;
  for (const BoardView& v : views) corners_per_frame[v.frame] += v.size();
  int best_frame = -1;
  size_t best = 0;
  for (const auto& [frame, count] : corners_per_frame)
    if (count > best) best = count, best_frame = frame;
  if (best_frame < 0) {
    out.message = "Zhang initialisation: no usable board view";
    return out;
  }
  std::vector<const BoardView*> left, right;
  for (const BoardView& v : views)
    if (v.frame == best_frame) (v.camera == CameraSide::kLeft ? left : right).push_back(&v);
  if (static_cast<int>(left.size()) < min_views || static_cast<int>(right.size()) < min_views) {
    out.message = "Zhang initialisation needs at least " + std::to_string(min_views) +
                  " boards per camera in one frame, got " + std::to_string(left.size()) +
                  " left and " + std::to_string(right.size()) + " right";
    return out;
  }
  std::map<int, Eigen::Isometry3d> left_from_board, right_from_board;
  if (!calibrateOneCamera(left, boards, image_width, image_height, &out.rig.left, &left_from_board,
                          &out.message) ||
      !calibrateOneCamera(right, boards, image_width, image_height, &out.rig.right,
                          &right_from_board, &out.message))
    return out;

  // Average right_from_left over the common boards: quaternions with aligned signs, then
  // normalised (accurate for the nearly identical estimates expected here).
  Eigen::Vector4d quaternion_sum = Eigen::Vector4d::Zero();
  Eigen::Vector3d translation_sum = Eigen::Vector3d::Zero();
  int common = 0;
  Eigen::Quaterniond reference = Eigen::Quaterniond::Identity();
  for (const auto& [board, l] : left_from_board) {
    const auto r = right_from_board.find(board);
    if (r == right_from_board.end()) continue;
    const Eigen::Isometry3d right_from_left = r->second * l.inverse();
    Eigen::Quaterniond q(right_from_left.linear());
    if (common == 0) reference = q;
    if (q.coeffs().dot(reference.coeffs()) < 0) q.coeffs() *= -1.0;
    quaternion_sum += q.coeffs();
    translation_sum += right_from_left.translation();
    ++common;
  }
  if (common == 0) {
    out.message = "Zhang initialisation: no board seen by both cameras in frame " +
                  std::to_string(best_frame);
    return out;
  }
  Eigen::Quaterniond mean;
  mean.coeffs() = quaternion_sum.normalized();
  out.rig.right_from_left = Eigen::Isometry3d::Identity();
  out.rig.right_from_left.linear() = mean.toRotationMatrix();
  out.rig.right_from_left.translation() = translation_sum / common;
  out.ok = true;
  return out;
}

bool estimateCameraFromBoard(const PinholeCamera& camera, const BoardView& view,
                             const VirtualBoard& board, Eigen::Isometry3d* camera_from_board) {
  if (view.size() < 4) return false;
  cv::Mat k, dist(1, 5, CV_64F), rvec, tvec;
  cv::eigen2cv(camera.K(), k);
  for (int i = 0; i < 5; ++i) dist.at<double>(i) = camera.dist[i];
  try {
    if (!cv::solvePnP(objectPoints(view, board), imagePoints(view), k, dist, rvec, tvec, false,
                      cv::SOLVEPNP_IPPE))
      return false;
  } catch (const cv::Exception&) {
    return false;
  }
  *camera_from_board = poseFromOpenCv(rvec, tvec);
  return camera_from_board->matrix().allFinite() && camera_from_board->translation().z() > 0;
}

bool estimateRigFromBoard(const StereoRig& rig, const BoardView& view, const VirtualBoard& board,
                          Eigen::Isometry3d* rig_from_board) {
  const bool left = view.camera == CameraSide::kLeft;
  Eigen::Isometry3d camera_from_board;
  if (!estimateCameraFromBoard(left ? rig.left : rig.right, view, board, &camera_from_board))
    return false;
  *rig_from_board = left ? camera_from_board : rig.right_from_left.inverse() * camera_from_board;
  return true;
}

std::map<std::pair<int, int>, Eigen::Isometry3d> initialBoardPoses(
    const StereoRig& rig, const std::vector<BoardView>& views,
    const std::vector<VirtualBoard>& boards, bool shared, bool from_layout,
    std::set<std::pair<int, int>>* failed) {
  std::map<std::pair<int, int>, std::vector<const BoardView*>> by_key;
  for (const BoardView& v : views) by_key[{shared ? -1 : v.frame, v.board}].push_back(&v);
  std::map<std::pair<int, int>, Eigen::Isometry3d> poses;
  for (auto& [key, list] : by_key) {
    std::sort(list.begin(), list.end(), [](const BoardView* a, const BoardView* b) {
      if (a->camera != b->camera) return a->camera == CameraSide::kLeft;
      return a->size() > b->size();
    });
    Eigen::Isometry3d rig_from_board = boards[key.second].rig_from_board;
    bool ok = from_layout;
    for (size_t i = 0; i < list.size() && !ok; ++i)
      ok = estimateRigFromBoard(rig, *list[i], boards[key.second], &rig_from_board);
    if (ok)
      poses[key] = rig_from_board;
    else
      failed->insert(key);
  }
  return poses;
}

}  // namespace embedded_calibration_stereo::core
