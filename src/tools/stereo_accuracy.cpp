// The accuracy for depth of a stereo calibration against a reference (the simulator's truth, or
// another calibration), in the terms of core/calibration/stereo_accuracy.h, for scripts that
// hold CameraInfo messages (scripts/demo_monitor.py). ROS-free.
//
//   stereo_accuracy [--alpha A]
// Reads one request per line on stdin, answers one line per request on stdout (flushed):
//   request:  WIDTH HEIGHT, then for the estimate's left and right camera and the reference's
//             left and right camera: K (9) D (5: k1 k2 p1 p2 k3) R (9) P (12) of its CameraInfo
//             (2 + 4 x 35 numbers, whitespace separated)
//   answer:   "ok MIS_RMS MIS_MAX BIAS_RMS BIAS_MAX E1 E2 E5 E10" - vertical misalignment and
//             disparity bias (px, RMS and max |.| over the field of view and every depth) and the
//             depth error RMS (%) at 1, 2, 5 and 10 m; or "error WHY" for an unusable request.
// --alpha: the rectification alpha the estimate is rectified with (the calibrator's
// rectification_alpha, default 0). Exit code 0 at the end of the input, 2 on a usage error.
#include <cstdio>
#include <cstring>
#include <iostream>
#include <sstream>
#include <string>

#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"

using namespace embedded_calibration_stereo::core;

namespace {

struct Info {
  double K[9], D[5], R[9], P[12];
};

Eigen::Matrix3d matrix(const double* m) {
  Eigen::Matrix3d out;
  out << m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8];
  return out;
}

PinholeCamera camera(const Info& info, int width, int height) {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = info.K[0];
  c.skew = info.K[1];
  c.cx = info.K[2];
  c.fy = info.K[4];
  c.cy = info.K[5];
  for (int i = 0; i < 5; ++i) c.dist[i] = info.D[i];
  return c;
}

// The rig a pair of rectified CameraInfo describes: p_rect_right = R1 p_left + t_rect (t_rect
// from the right P) and p_right = R2^T p_rect_right.
StereoRig rig(const Info& left, const Info& right, int width, int height) {
  StereoRig r;
  r.left = camera(left, width, height);
  r.right = camera(right, width, height);
  const double fx = right.P[0], fy = right.P[5];
  if (!(fx > 0.0) || !(fy > 0.0)) throw std::invalid_argument("right P has no positive focal length");
  const Eigen::Vector3d t_rect(right.P[3] / fx, right.P[7] / fy, right.P[11]);
  const Eigen::Matrix3d r1 = matrix(left.R), r2 = matrix(right.R);
  r.right_from_left.linear() = r2.transpose() * r1;
  r.right_from_left.translation() = r2.transpose() * t_rect;
  return r;
}

bool read(std::istringstream& in, double* values, int n) {
  for (int i = 0; i < n; ++i)
    if (!(in >> values[i])) return false;
  return true;
}

std::string answer(const std::string& line, const StereoAccuracyOptions& options) {
  std::istringstream in(line);
  int width = 0, height = 0;
  if (!(in >> width >> height) || width <= 0 || height <= 0) return "error: WIDTH HEIGHT expected first";
  Info info[4];
  for (Info& i : info)
    if (!read(in, i.K, 9) || !read(in, i.D, 5) || !read(in, i.R, 9) || !read(in, i.P, 12))
      return "error: 2 + 4 x 35 numbers expected (K D R P of four cameras)";
  std::string extra;
  if (in >> extra) return "error: more than 2 + 4 x 35 numbers";
  try {
    const StereoRig estimate = rig(info[0], info[1], width, height);
    const StereoRig reference = rig(info[2], info[3], width, height);
    const StereoAccuracy a = evaluateStereoAccuracy(estimate, reference, options);
    char out[256];
    std::snprintf(out, sizeof(out), "ok %.5f %.5f %.5f %.5f %.5f %.5f %.5f %.5f", a.misalignment_px.rms,
                  a.misalignment_px.max, a.disparity_bias_px.rms, a.disparity_bias_px.max,
                  a.at_depth[0].depth_error_pct.rms, a.at_depth[1].depth_error_pct.rms,
                  a.at_depth[2].depth_error_pct.rms, a.at_depth[3].depth_error_pct.rms);
    return out;
  } catch (const std::exception& e) {
    return std::string("error: ") + e.what();
  }
}

}  // namespace

int main(int argc, char** argv) {
  StereoAccuracyOptions options;  // depths 1, 2, 5, 10 m and infinity
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--alpha") == 0 && i + 1 < argc) {
      options.rectification.alpha = std::atof(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: stereo_accuracy [--alpha A] < requests (see the source's header)\n");
      return 2;
    }
  }
  std::string line;
  while (std::getline(std::cin, line)) {
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    std::cout << answer(line, options) << std::endl;  // flushed: the caller waits for it
  }
  return 0;
}
