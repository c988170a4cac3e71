#include "embedded_calibration_stereo/test_support/cramer_rao.h"

#include <Eigen/Eigenvalues>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

namespace embedded_calibration_stereo::core {

CramerRaoBound freePoseCramerRaoBound(const StereoRig& truth, const std::vector<VirtualBoard>& boards,
                                      const StereoObservation& visible, int frames, double sigma_px) {
  const int kCams = 12, kExtr = 6, n = kCams + kExtr + 6 * static_cast<int>(boards.size());
  Eigen::MatrixXd info = Eigen::MatrixXd::Zero(n, n);
  cv::Mat r_rl;
  cv::eigen2cv(Eigen::Matrix3d(truth.right_from_left.linear()), r_rl);
  cv::Rodrigues(r_rl.clone(), r_rl);
  const Eigen::Vector3d t_rl_e = truth.right_from_left.translation();
  const cv::Mat t_rl = (cv::Mat_<double>(3, 1) << t_rl_e.x(), t_rl_e.y(), t_rl_e.z());
  for (int side = 0; side < 2; ++side) {
    const PinholeCamera& cam = side == 0 ? truth.left : truth.right;
    const cv::Matx33d K(cam.fx, cam.skew, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1);
    const cv::Mat D(cv::Matx<double, 1, 5>(cam.dist.data()), true);
    for (const BoardCorners& seen : side == 0 ? visible.left : visible.right) {
      int b = 0;
      while (b < static_cast<int>(boards.size()) && boards[b].virtual_id != seen.board_id) ++b;
      if (b == static_cast<int>(boards.size())) continue;  // not a board of this layout
      const VirtualBoard& vb = boards[b];
      std::vector<cv::Point3d> object;
      for (int id : seen.corner_ids) {
        const Eigen::Vector3d p = vb.cornerInBoard(id);
        object.emplace_back(p.x(), p.y(), p.z());
      }
      cv::Mat r_b;
      cv::eigen2cv(Eigen::Matrix3d(vb.rig_from_board.linear()), r_b);
      cv::Rodrigues(r_b.clone(), r_b);
      const Eigen::Vector3d t_b_e = vb.rig_from_board.translation();
      const cv::Mat t_b = (cv::Mat_<double>(3, 1) << t_b_e.x(), t_b_e.y(), t_b_e.z());
      // Board pose in this camera, and its derivatives w.r.t. the board pose and the extrinsics.
      cv::Mat r_c = r_b, t_c = t_b;
      Eigen::Matrix<double, 6, 6> dcam_dboard = Eigen::Matrix<double, 6, 6>::Identity();
      Eigen::Matrix<double, 6, 6> dcam_dextr = Eigen::Matrix<double, 6, 6>::Zero();
      if (side == 1) {
        cv::Mat dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2;
        cv::composeRT(r_b, t_b, r_rl, t_rl, r_c, t_c, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2,
                      dt3dt2);
        const auto block = [](const cv::Mat& m) {
          Eigen::Matrix3d e;
          cv::cv2eigen(m, e);
          return e;
        };
        dcam_dboard << block(dr3dr1), block(dr3dt1), block(dt3dr1), block(dt3dt1);
        dcam_dextr << block(dr3dr2), block(dr3dt2), block(dt3dr2), block(dt3dt2);
      }
      std::vector<cv::Point2d> projected;
      cv::Mat jac;  // 2N x 15: rvec, tvec, fx, fy, cx, cy, k1, k2, p1, p2, k3
      cv::projectPoints(object, r_c, t_c, K, D, projected, jac);
      Eigen::MatrixXd J_proj;
      cv::cv2eigen(jac, J_proj);
      Eigen::MatrixXd J = Eigen::MatrixXd::Zero(J_proj.rows(), n);
      J.block(0, 6 * side, J_proj.rows(), 6) = J_proj.block(0, 6, J_proj.rows(), 6);  // fx .. k2
      const Eigen::MatrixXd J_pose = J_proj.leftCols(6);
      J.block(0, kCams + kExtr + 6 * b, J_proj.rows(), 6) = J_pose * dcam_dboard;
      if (side == 1) J.block(0, kCams, J_proj.rows(), 6) = J_pose * dcam_dextr;
      info += J.transpose() * J;
    }
  }
  const Eigen::MatrixXd cov = (info * (frames / (sigma_px * sigma_px))).inverse();
  const auto sd = [&](int i) { return std::sqrt(cov(i, i)); };
  CramerRaoBound out;
  for (int c = 0; c < 2; ++c) {
    CameraStddev& s = c == 0 ? out.left_stddev : out.right_stddev;
    s.fx = sd(6 * c), s.fy = sd(6 * c + 1), s.cx = sd(6 * c + 2), s.cy = sd(6 * c + 3);
    s.dist[0] = sd(6 * c + 4), s.dist[1] = sd(6 * c + 5);
  }
  const Eigen::Vector3d dir = t_rl_e.normalized();
  out.baseline_stddev_m = std::sqrt(dir.dot(cov.block<3, 3>(kCams + 3, kCams + 3) * dir));
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov.block<3, 3>(kCams, kCams));
  out.rotation_stddev_deg = std::sqrt(eig.eigenvalues().maxCoeff()) * 180.0 / M_PI;
  return out;
}

}  // namespace embedded_calibration_stereo::core
