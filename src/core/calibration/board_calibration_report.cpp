#include "embedded_calibration_stereo/core/calibration/board_calibration_report.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <sstream>

namespace embedded_calibration_stereo::core {

namespace {

std::string quoted(const std::string& text) {
  std::string out = "\"";
  for (char c : text) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out + "\"";
}

void writeCamera(std::ostringstream& s, const std::string& key, const PinholeCamera& c,
                 const CameraStddev& sd) {
  s << key << ":\n"
    << "  fx: " << c.fx << "\n  fy: " << c.fy << "\n  cx: " << c.cx << "\n  cy: " << c.cy
    << "\n  distortion: [" << c.dist[0] << ", " << c.dist[1] << ", " << c.dist[2] << ", "
    << c.dist[3] << ", " << c.dist[4] << "]\n"
    << "  stddev:\n    fx: " << sd.fx << "\n    fy: " << sd.fy << "\n    cx: " << sd.cx
    << "\n    cy: " << sd.cy << "\n    distortion: [" << sd.dist[0] << ", " << sd.dist[1] << ", "
    << sd.dist[2] << ", " << sd.dist[3] << ", " << sd.dist[4] << "]\n";
}

cv::Scalar pairColour(size_t index, size_t count) {
  const cv::Mat hsv(
      1, 1, CV_8UC3,
      cv::Scalar(static_cast<double>(150 * index) / std::max<size_t>(count, 1), 220, 230));
  cv::Mat bgr;
  cv::cvtColor(hsv, bgr, cv::COLOR_HSV2BGR);
  const cv::Vec3b v = bgr.at<cv::Vec3b>(0, 0);
  return cv::Scalar(v[0], v[1], v[2]);
}

// Smallest of 1, 2, 5 x 10^k at least `value`.
double niceCeiling(double value) {
  const double p = std::pow(10.0, std::floor(std::log10(std::max(value, 1e-6))));
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (m * p >= value) return m * p;
  return 10.0 * p;
}

}  // namespace

std::string boardCalibrationReportYaml(const BoardCalibrationResult& r, const ChessboardSpec& board,
                                       const std::vector<std::string>& skipped) {
  const BundleAdjustmentSummary& s = r.summary;
  std::ostringstream o;
  o.precision(10);
  const Eigen::Vector3d rotvec = rotationVector(r.rig.right_from_left.linear()) * 180.0 / M_PI;
  const Eigen::Vector3d t = r.rig.right_from_left.translation();
  o << "# calibrate_images report: pixels, metres, degrees. stddev = one standard deviation\n"
    << "# from the adjustment's covariance scaled by the residual variance.\n"
    << "rms_px: " << r.rms_px << "\nrms_left_px: " << s.rms_left_px
    << "\nrms_right_px: " << s.rms_right_px << "\nepipolar_rms_px: " << s.epipolar_rms_px
    << "\nresidual_sigma_px: " << s.residual_sigma_px
    << "\nopencv_initial_rms_px: " << r.opencv_initial_rms_px
    << "  # cv::stereoCalibrate, intrinsics held (the start)\n"
    << "converged: " << (s.converged ? "true" : "false") << "\niterations: " << s.iterations
    << "\nsolve_ms: " << s.solve_ms << "\ncovariance_ok: " << (s.covariance_ok ? "true" : "false")
    << "\nboard: {cols: " << board.cols << ", rows: " << board.rows
    << ", square_m: " << board.square_m << "}\npairs_used: " << r.pairs.size()
    << "\ncorners_used: " << s.corners_used << "\noutliers: " << s.outliers
    << "  # corners with a residual above " << BundleAdjustmentOptions().outlier_threshold_px
    << " px\n"
    << "baseline_m: " << r.rig.baseline() << "\nbaseline_stddev_m: " << s.baseline_stddev_m
    << "\nrotation_deg: " << rotvec.norm()
    << "\nrotation_stddev_deg: " << s.rotation_stddev_deg << "\nright_from_left:\n  rotation_deg: ["
    << rotvec.x() << ", " << rotvec.y() << ", " << rotvec.z()
    << "]  # rotation vector\n  translation_m: [" << t.x() << ", " << t.y() << ", " << t.z()
    << "]\n";
  writeCamera(o, "left", r.rig.left, s.left_stddev);
  writeCamera(o, "right", r.rig.right, s.right_stddev);
  o << "per_image:\n";
  for (const PairResiduals& p : r.pairs)
    o << "  - {name: " << quoted(p.name) << ", rms_px: " << p.rms_px
      << ", rms_left_px: " << p.rms_left_px << ", rms_right_px: " << p.rms_right_px << "}\n";
  o << "skipped:" << (skipped.empty() ? " []\n" : "\n");
  for (const std::string& why : skipped) o << "  - " << quoted(why) << "\n";
  return o.str();
}

cv::Mat residualPlot(const BoardCalibrationResult& r) {
  constexpr int kPanel = 420, kTop = 28;
  const int width = std::max(r.rig.left.width, 1), height = std::max(r.rig.left.height, 1);
  const double image_scale = static_cast<double>(kPanel) / width;
  const int image_panel_height = static_cast<int>(std::lround(height * image_scale));
  cv::Mat plot(kTop + kPanel + kTop + image_panel_height, 2 * kPanel, CV_8UC3,
               cv::Scalar(255, 255, 255));
  double max_residual = 0.0;
  for (const PairResiduals& p : r.pairs)
    for (const auto* list : {&p.left, &p.right})
      for (const Eigen::Vector2d& e : *list)
        if (e.allFinite()) max_residual = std::max(max_residual, e.cwiseAbs().maxCoeff());
  const double range = niceCeiling(max_residual);   // half-width of the scatter, px
  const double arrow_gain = 0.05 * kPanel / range;  // image-plane arrows: range -> 5 % of panel
  const cv::Scalar grey(180, 180, 180), black(0, 0, 0);
  for (int side = 0; side < 2; ++side) {
    const int x0 = side * kPanel;
    const cv::Point centre(x0 + kPanel / 2, kTop + kPanel / 2);
    const double px = (kPanel / 2 - 10) / range;  // plot pixels per residual pixel
    cv::rectangle(plot, cv::Rect(x0 + 10, kTop + 10, kPanel - 20, kPanel - 20), grey);
    cv::line(plot, {x0 + 10, centre.y}, {x0 + kPanel - 10, centre.y}, grey);
    cv::line(plot, {centre.x, kTop + 10}, {centre.x, kTop + kPanel - 10}, grey);
    std::ostringstream title;
    title.precision(3);
    title << (side ? "right" : "left") << " residuals, box +-" << range << " px, rms "
          << (side ? r.summary.rms_right_px : r.summary.rms_left_px) << " px";
    cv::putText(plot, title.str(), {x0 + 10, 20}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black, 1,
                cv::LINE_AA);
    const int y1 = kTop + kPanel + kTop;
    cv::rectangle(plot, cv::Rect(x0, y1, kPanel, image_panel_height), grey);
    std::ostringstream title2;
    title2.precision(3);
    title2 << (side ? "right" : "left") << " image plane, arrows x" << arrow_gain / image_scale;
    cv::putText(plot, title2.str(), {x0 + 10, y1 - 8}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black, 1,
                cv::LINE_AA);
    for (size_t i = 0; i < r.pairs.size(); ++i) {
      const PairResiduals& p = r.pairs[i];
      const auto& residuals = side ? p.right : p.left;
      const auto& pixels = side ? p.right_pixels : p.left_pixels;
      const cv::Scalar colour = pairColour(i, r.pairs.size());
      for (size_t k = 0; k < residuals.size(); ++k) {
        const Eigen::Vector2d& e = residuals[k];
        if (!e.allFinite()) continue;
        cv::circle(plot,
                   cv::Point(static_cast<int>(std::lround(centre.x + e.x() * px)),
                             static_cast<int>(std::lround(centre.y + e.y() * px))),
                   1, colour, cv::FILLED);
        const cv::Point2d at(x0 + pixels[k].x() * image_scale, y1 + pixels[k].y() * image_scale);
        cv::line(plot, at, at + cv::Point2d(e.x() * arrow_gain, e.y() * arrow_gain), colour, 1,
                 cv::LINE_AA);
      }
    }
  }
  return plot;
}

}  // namespace embedded_calibration_stereo::core
