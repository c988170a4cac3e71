#include "embedded_calibration_stereo/ros/stereo_input_check.h"

#include <ros/time.h>
#include <sensor_msgs/distortion_models.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <tuple>

namespace embedded_calibration_stereo {

namespace {

std::string sizeText(uint32_t width, uint32_t height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

std::string num(double v) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.9g", v);
  return text;
}

bool allZero(const double* values, size_t n) {
  return std::all_of(values, values + n, [](double v) { return v == 0.0; });
}

// The index of the first non-finite value, or -1.
int firstNonFinite(const double* values, size_t n) {
  for (size_t i = 0; i < n; ++i)
    if (!std::isfinite(values[i])) return static_cast<int>(i);
  return -1;
}

std::string nonFiniteText(const char* field, int index, double value) {
  return std::string(field) + ": " + field + "[" + std::to_string(index) + "] is " + num(value) +
         " (every element must be finite)";
}

std::string distortionProblem(const sensor_msgs::CameraInfo& info) {
  namespace models = sensor_msgs::distortion_models;
  const std::string& model = info.distortion_model;
  const size_t nd = info.D.size();
  if (model.empty() || model == models::PLUMB_BOB) {
    if (nd != 0 && nd != 4 && nd != 5)
      return "D: plumb_bob takes 4 or 5 coefficients, not " + std::to_string(nd);
  } else if (model == models::RATIONAL_POLYNOMIAL) {
    if (nd != 8) return "D: rational_polynomial takes 8 coefficients, not " + std::to_string(nd);
  } else {
    return "distortion_model: '" + model + "' is not supported (plumb_bob or rational_polynomial)";
  }
  if (const int i = firstNonFinite(info.D.data(), nd); i >= 0) return nonFiniteText("D", i, info.D[i]);
  return "";
}

std::string cameraMatrixProblem(const sensor_msgs::CameraInfo::_K_type& K) {
  if (allZero(K.data(), K.size())) return "K: uncalibrated camera (K is all zero)";
  if (const int i = firstNonFinite(K.data(), K.size()); i >= 0) return nonFiniteText("K", i, K[i]);
  if (!(K[0] > 0 && K[4] > 0))
    return "K: focal lengths must be > 0 (fx " + num(K[0]) + ", fy " + num(K[4]) + ")";
  if (K[3] != 0 || K[6] != 0 || K[7] != 0 || K[8] != 1)
    return "K: not a camera matrix (its rows 2 and 3 must be [0 fy cy] and [0 0 1])";
  return "";
}

std::string rotationProblem(const sensor_msgs::CameraInfo::_R_type& R) {
  if (allZero(R.data(), R.size())) return "R: uncalibrated camera (R is all zero)";
  if (const int i = firstNonFinite(R.data(), R.size()); i >= 0) return nonFiniteText("R", i, R[i]);
  double worst = 0;  // largest element of R R^T - I
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      double dot = 0;
      for (int k = 0; k < 3; ++k) dot += R[3 * r + k] * R[3 * c + k];
      worst = std::max(worst, std::abs(dot - (r == c ? 1.0 : 0.0)));
    }
  const double det = R[0] * (R[4] * R[8] - R[5] * R[7]) - R[1] * (R[3] * R[8] - R[5] * R[6]) +
                     R[2] * (R[3] * R[7] - R[4] * R[6]);
  if (worst > 1e-5 || det < 0) return "R: not a rotation (R R^T - I up to " + num(worst) + ", det " + num(det) + ")";
  return "";
}

std::string projectionProblem(const sensor_msgs::CameraInfo::_P_type& P) {
  if (allZero(P.data(), P.size())) return "P: uncalibrated camera (P is all zero)";
  if (const int i = firstNonFinite(P.data(), P.size()); i >= 0) return nonFiniteText("P", i, P[i]);
  if (!(P[0] > 0 && P[5] > 0))
    return "P: focal lengths must be > 0 (fx' " + num(P[0]) + ", fy' " + num(P[5]) + ")";
  if (P[4] != 0 || P[8] != 0 || P[9] != 0 || P[10] != 1 || P[11] != 0)
    return "P: not a projection matrix of a rectified camera (its rows 2 and 3 must be [0 fy' cy' Ty] and "
           "[0 0 1 0])";
  return "";
}

// A lens's axis meets its sensor near the centre, and a rectified camera's principal point
// stays near its image: one far past the edges is a corrupt calibration (its depth would be
// empty), whatever else agrees with it.
std::string principalPointProblem(const sensor_msgs::CameraInfo& info) {
  const struct {
    const char* field;
    double value, size;
  } points[] = {{"K: cx (K[2])", info.K[2], static_cast<double>(info.width)},
                {"K: cy (K[5])", info.K[5], static_cast<double>(info.height)},
                {"P: cx' (P[2])", info.P[2], static_cast<double>(info.width)},
                {"P: cy' (P[6])", info.P[6], static_cast<double>(info.height)}};
  for (const auto& p : points) {
    const double margin = kPrincipalPointMargin * p.size;
    if (!(p.value >= -margin && p.value <= p.size + margin))
      return std::string(p.field) + " " + num(p.value) + " lies outside the image: a principal point lies within [" +
             num(-margin) + ", " + num(p.size + margin) + "] (the image and " +
             num(100 * kPrincipalPointMargin) + " % of its size beyond each edge)";
  }
  return "";
}

// P must fit K and R: the rectified camera sees the raw camera's field at a similar scale, and
// the raw image's centre lands near the rectified image. A P from another camera, or an R turned
// far from the lens's axis, maps the image out of view (its depth would be empty).
std::string rectificationProblem(const sensor_msgs::CameraInfo& info) {
  const auto& K = info.K;
  const auto& R = info.R;
  const auto& P = info.P;
  for (const auto& [field, scale] : {std::pair<const char*, double>{"fx'", P[0] / K[0]}, {"fy'", P[5] / K[4]}})
    if (!(scale >= 1.0 / kRectifiedScaleLimit && scale <= kRectifiedScaleLimit))
      return std::string("P: ") + field + " is " + num(scale) + " times K's (P must fit K: within a factor of " +
             num(kRectifiedScaleLimit) + ")";
  // The ray of the raw image's centre (the principal point: no distortion there), rotated by R.
  const double x = R[2], y = R[5], z = R[8];
  const double u = P[0] * x / z + P[2], v = P[5] * y / z + P[6];
  const double mx = kPrincipalPointMargin * info.width, my = kPrincipalPointMargin * info.height;
  if (!(z > 0 && u >= -mx && u <= info.width + mx && v >= -my && v <= info.height + my))
    return "R, P: the raw image's centre lands at (" + num(u) + ", " + num(v) + ")" +
           (z > 0 ? "" : " behind the rectified camera") + " of the rectified image, beyond " +
           num(100 * kPrincipalPointMargin) + " % of its size past its edges (R and P do not fit K)";
  return "";
}

// The lens's radial distortion must map the undistorted field onto the image without folding
// over: the distorted radius grows with the true radius until it reaches the image's farthest
// corner, within kDistortionFieldLimit times that corner's radius. Coefficients that fold
// earlier rectify the corners from the wrong side of the fold (mirrored, smeared images).
std::string distortionFieldProblem(const sensor_msgs::CameraInfo& info) {
  const auto& D = info.D;
  if (D.empty()) return "";
  const bool rational = D.size() == 8;
  const double k1 = D[0], k2 = D[1], k3 = D.size() > 4 ? D[4] : 0.0;
  const double k4 = rational ? D[5] : 0.0, k5 = rational ? D[6] : 0.0, k6 = rational ? D[7] : 0.0;
  const auto distorted = [&](double r) {
    const double r2 = r * r;
    return r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)));
  };
  const double K0 = info.K[0], K4 = info.K[4], cx = info.K[2], cy = info.K[5];
  const double corner = std::hypot(std::max(cx, info.width - cx) / K0, std::max(cy, info.height - cy) / K4);
  constexpr int kSteps = 400;
  const double step = kDistortionFieldLimit * corner / kSteps;
  double previous = 0.0;
  for (int i = 1; i <= kSteps; ++i) {
    const double r = i * step, rd = distorted(r);
    if (!(rd > previous))
      return "D: the distortion folds over at radius " + num(r) + " (normalised), before the image's corners (at " +
             num(corner) + "): the corners cannot be rectified";
    if (rd >= corner) return "";
    previous = rd;
  }
  return "D: the image's corners (radius " + num(corner) + ", normalised) come from beyond " +
         num(kDistortionFieldLimit) + " times that radius: a field of view no lens of this pipeline has";
}

// Binning and region of interest: this pipeline works at full resolution.
std::string layoutProblem(const sensor_msgs::CameraInfo& info) {
  if (info.binning_x > 1 || info.binning_y > 1)
    return "binning_x, binning_y: " + std::to_string(info.binning_x) + ", " + std::to_string(info.binning_y) +
           ": binned images are not supported (binning 0 or 1: this pipeline works at full resolution)";
  const auto& roi = info.roi;
  const bool no_roi = roi.x_offset == 0 && roi.y_offset == 0 && roi.width == 0 && roi.height == 0;
  const bool full_roi = roi.x_offset == 0 && roi.y_offset == 0 && roi.width == info.width && roi.height == info.height;
  if (!no_roi && !full_roi)
    return "roi: " + sizeText(roi.width, roi.height) + " at (" + std::to_string(roi.x_offset) + ", " +
           std::to_string(roi.y_offset) + ") is not the full " + sizeText(info.width, info.height) +
           " image (regions of interest are not supported)";
  return "";
}

// The problem of one CameraInfo's fields (without the topic), or "": the first of the checks
// above, in the order of the fields.
std::string cameraInfoProblem(const sensor_msgs::CameraInfo& info) {
  if (info.width == 0 || info.height == 0)
    return "width, height: the size " + sizeText(info.width, info.height) + " is empty";
  std::string problem = distortionProblem(info);
  if (problem.empty()) problem = cameraMatrixProblem(info.K);
  if (problem.empty()) problem = rotationProblem(info.R);
  if (problem.empty()) problem = projectionProblem(info.P);
  if (problem.empty()) problem = principalPointProblem(info);
  if (problem.empty()) problem = rectificationProblem(info);
  if (problem.empty()) problem = distortionFieldProblem(info);
  if (problem.empty()) problem = layoutProblem(info);
  return problem;
}

}  // namespace

std::string checkImagePair(const sensor_msgs::Image& left, const std::string& left_topic,
                           const sensor_msgs::Image& right, const std::string& right_topic,
                           const std::vector<std::string>& accepted) {
  std::string list;
  for (const auto& e : accepted) list += (list.empty() ? "" : ", ") + e;
  for (const auto* side : {&left, &right}) {
    if (std::find(accepted.begin(), accepted.end(), side->encoding) == accepted.end())
      return (side == &left ? left_topic : right_topic) + ": unsupported encoding '" + side->encoding +
             "' (accepted: " + list + ")";
  }
  if (left.encoding != right.encoding)
    return right_topic + ": encoding '" + right.encoding + "' differs from " + left_topic + "'s '" +
           left.encoding + "'";
  if (left.width != right.width || left.height != right.height)
    return right_topic + ": size " + sizeText(right.width, right.height) + " differs from " + left_topic +
           "'s " + sizeText(left.width, left.height);
  if (left.width == 0 || left.height == 0) return left_topic + ": empty image";
  return "";
}

std::string checkCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& info_topic, uint32_t width,
                            uint32_t height) {
  const std::string problem = cameraInfoProblem(info);
  if (!problem.empty()) return info_topic + ": " + problem;
  if (info.width != width || info.height != height)
    return info_topic + ": size " + sizeText(info.width, info.height) + " differs from the image's " +
           sizeText(width, height);
  return "";
}

std::string checkCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& info_topic,
                            const sensor_msgs::Image& image) {
  return checkCameraInfo(info, info_topic, image.width, image.height);
}

std::string checkNominalFocal(const sensor_msgs::CameraInfo& info, const std::string& info_topic, double nominal_fx,
                              double nominal_fy) {
  for (const auto& [field, value, nominal] : {std::tuple<const char*, double, double>{"fx (K[0])", info.K[0], nominal_fx},
                                              {"fy (K[4])", info.K[4], nominal_fy}}) {
    const double ratio = value / nominal;
    if (!(ratio >= 1.0 / kNominalFocalFactor && ratio <= kNominalFocalFactor))
      return info_topic + ": K: " + field + " " + num(value) + " is " + num(ratio) +
             " times the device's nominal " + num(nominal) + " (a calibration lies within a factor of " +
             num(kNominalFocalFactor) + " of it)";
  }
  return "";
}

std::string checkCalibrationPair(const sensor_msgs::CameraInfo& left, const std::string& left_topic,
                                 const sensor_msgs::CameraInfo& right, const std::string& right_topic,
                                 const std::optional<core::StereoRig>& nominal) {
  std::string problem = checkCameraInfo(left, left_topic, left.width, left.height);
  if (problem.empty()) problem = checkCameraInfo(right, right_topic, right.width, right.height);
  if (problem.empty()) problem = checkRectifiedPair(left, left_topic, right, right_topic);
  if (problem.empty() && nominal) problem = checkNominalFocal(left, left_topic, nominal->left.fx, nominal->left.fy);
  if (problem.empty() && nominal) problem = checkNominalFocal(right, right_topic, nominal->right.fx, nominal->right.fy);
  return problem;
}

std::string checkRectifiedPair(const sensor_msgs::CameraInfo& left, const std::string& left_topic,
                               const sensor_msgs::CameraInfo& right, const std::string& right_topic) {
  if (left.width != right.width || left.height != right.height)
    return right_topic + ": size " + sizeText(right.width, right.height) + " differs from " + left_topic + "'s " +
           sizeText(left.width, left.height);
  static const struct {
    int index;
    const char* name;
  } kShared[] = {{0, "fx' (P[0])"}, {5, "fy' (P[5])"}, {6, "cy' (P[6])"}};
  for (const auto& s : kShared) {
    if (std::abs(left.P[s.index] - right.P[s.index]) > kRectifiedPairTolerancePx)
      return right_topic + ": P: " + s.name + " " + num(right.P[s.index]) + " differs from " +
             num(left.P[s.index]) + " in " + left_topic +
             " (the two cameras of a rectified pair share fx', fy' and cy'; was only one camera calibrated?)";
  }
  if (left.P[3] != 0)
    return left_topic + ": P: Tx (P[3]) is " + num(left.P[3]) +
           ", must be 0 (the left camera is the reference of the rectified pair)";
  if (right.P[3] == 0)
    return right_topic + ": P: Tx (P[3]) is 0: no baseline (the right camera's P carries Tx = -fx' * baseline)";
  return "";
}

std::string checkSameFrame(const sensor_msgs::CameraInfo& left, const std::string& left_topic,
                           const sensor_msgs::CameraInfo& right, const std::string& right_topic) {
  if (left.header.frame_id == right.header.frame_id) return "";
  return right_topic + ": frame id '" + right.header.frame_id + "' differs from " + left_topic + "'s '" +
         left.header.frame_id + "' (stereo_image_proc convention: one frame id, see right_in_left_frame)";
}

void alignRectifiedPair(const sensor_msgs::CameraInfo& left, sensor_msgs::CameraInfo* right) {
  for (const int i : {0, 5, 6}) right->P[i] = left.P[i];
}

bool ErrorThrottle::shouldReport(const std::string& message) {
  const double now = ros::WallTime::now().toSec();
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = last_report_s_.find(message);
  if (it != last_report_s_.end() && now - it->second < period_s_) return false;
  last_report_s_[message] = now;
  if (last_report_s_.size() > 256) last_report_s_.clear();  // bounded: messages may carry sizes
  return true;
}

}  // namespace embedded_calibration_stereo
