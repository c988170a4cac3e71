#include "embedded_calibration_stereo/core/calibration/calibration_monitor.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

#include "embedded_calibration_stereo/core/calibration/stereo_accuracy.h"

namespace embedded_calibration_stereo::core {

namespace {

// The change the monitor fits, relative to the calibration in force: a rotation of the right
// camera about its own x, y, z axes (deg; the new right frame is the old one turned by
// rotationFromVectorDeg(w), so points map with its transpose - the simulator's drift
// convention) and the focal scales of the left and right cameras minus 1.
constexpr int kChange = 5;
using Change = Eigen::Matrix<double, kChange, 1>;
using ChangeMatrix = Eigen::Matrix<double, kChange, kChange>;
constexpr double kDegToRad = M_PI / 180.0;

StereoRig observedRig(const StereoRig& in_force, const Change& c) {
  StereoRig rig = in_force;
  rig.left = in_force.left.withFocalScale(1.0 + c(3));
  rig.right = in_force.right.withFocalScale(1.0 + c(4));
  Eigen::Isometry3d turn = Eigen::Isometry3d::Identity();
  turn.linear() = rotationFromVectorDeg(c.head<3>()).transpose();
  rig.right_from_left = turn * in_force.right_from_left;
  return rig;
}

// Squared accuracy figures of the change c (stereo_accuracy.h): misalignment RMS, disparity bias
// RMS, depth error RMS at each of kHealthDepthsM.
constexpr int kFigures = 2 + static_cast<int>(kHealthDepthsM.size());
using Figures = Eigen::Matrix<double, kFigures, 1>;

Figures squaredFigures(const StereoRig& in_force, const Change& c, const StereoAccuracyOptions& options) {
  const StereoAccuracy a = evaluateStereoAccuracy(in_force, observedRig(in_force, c), options);
  Figures f;
  f(0) = a.misalignment_px.rms * a.misalignment_px.rms;
  f(1) = a.disparity_bias_px.rms * a.disparity_bias_px.rms;
  for (size_t i = 0; i < kHealthDepthsM.size(); ++i) {
    const double e = a.at_depth.at(i).depth_error_pct.rms;
    f(2 + static_cast<int>(i)) = e * e;
  }
  return f;
}

double quadratic(const ChangeMatrix& a, const Change& c) { return std::sqrt(std::max(0.0, c.dot(a * c))); }

// The level of one signal with hysteresis: a level is entered above its threshold and kept until
// the value falls below threshold * (1 - hysteresis).
CalibrationHealth levelOf(CalibrationHealth previous, double value, double degraded, double bad, double hysteresis) {
  const double keep = 1.0 - hysteresis;
  if (value > bad || (previous == CalibrationHealth::kBad && value > bad * keep)) return CalibrationHealth::kBad;
  if (value > degraded || (previous >= CalibrationHealth::kDegraded && value > degraded * keep))
    return CalibrationHealth::kDegraded;
  return CalibrationHealth::kGood;
}

double rmsOf(const std::vector<double>& squares) {
  if (squares.empty()) return 0.0;
  double s = 0.0;
  for (double v : squares) s += v;
  return std::sqrt(s / static_cast<double>(squares.size()));
}

cv::Mat toGray(const cv::Mat& image, const char* which) {
  if (image.type() == CV_8UC1) return image;
  if (image.type() == CV_8UC3) {
    cv::Mat gray;
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
    return gray;
  }
  throw std::invalid_argument(std::string("CalibrationMonitor: the ") + which +
                              " image must be 8-bit grey or colour (CV_8UC1 / CV_8UC3)");
}

std::string fixed(double v, int digits) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(digits);
  s << v;
  return s.str();
}

}  // namespace

const char* toString(CalibrationHealth health) {
  switch (health) {
    case CalibrationHealth::kGood: return "GOOD";
    case CalibrationHealth::kDegraded: return "DEGRADED";
    case CalibrationHealth::kBad: return "BAD";
    case CalibrationHealth::kUnknown: break;
  }
  return "UNKNOWN";
}

std::string CalibrationMonitorOptions::validate() const { return problem().text(); }

namespace {

// A degraded limit above zero and a bad limit above it; the problem names the degraded one.
ConfigProblem checkLimits(const char* degraded_name, double degraded, const char* bad_name, double bad) {
  if (std::isfinite(degraded) && degraded > 0.0 && bad > degraded) return {};
  return {degraded_name, std::string("must be > 0 and ") + bad_name + " above it"};
}

}  // namespace

ConfigProblem CalibrationMonitorOptions::problem() const {
  auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  for (const ConfigProblem& p :
       {checkLimits("misalignment_degraded_px", misalignment_degraded_px, "misalignment_bad_px", misalignment_bad_px),
        checkLimits("disparity_bias_degraded_px", disparity_bias_degraded_px, "disparity_bias_bad_px",
                    disparity_bias_bad_px),
        checkLimits("board_residual_degraded_px", board_residual_degraded_px, "board_residual_bad_px",
                    board_residual_bad_px)})
    if (!p.ok()) return p;
  if (!(hysteresis >= 0.0 && hysteresis < 1.0)) return {"hysteresis", "must be in [0, 1)"};
  if (depth_frame_stride < 1) return {"depth_frame_stride", "must be >= 1"};
  if (!positive(smoothing_time_s)) return {"smoothing_time_s", "must be > 0"};
  if (!positive(band_half_height_px)) return {"band_half_height_px", "must be > 0"};
  ConfigProblem matching_problem = matching.problem();
  if (!matching_problem.ok()) return {"matching." + matching_problem.parameter, matching_problem.problem};
  if (min_matches < 5) return {"min_matches", "must be >= 5"};
  if (!positive(huber_px)) return {"huber_px", "must be > 0"};
  if (!positive(max_depth_age_s)) return {"max_depth_age_s", "must be > 0"};
  if (!positive(verification_period_s)) return {"verification_period_s", "must be > 0"};
  if (min_board_corners < 4) return {"min_board_corners", "must be >= 4"};
  if (min_corners < 6) return {"min_corners", "must be >= 6"};
  if (!positive(max_verification_age_s)) return {"max_verification_age_s", "must be > 0"};
  return {};
}

namespace {

// Depth mode: the matches' row offsets after rectification with the calibration in force, and
// each offset's derivative with respect to a rotation of the right camera about x and z (deg).
struct RowOffsets {
  std::vector<double> offsets;
  std::vector<Eigen::Vector2d> jacobians;
  size_t size() const { return offsets.size(); }
};

// The depth frame's images must have the calibration's size and be 8-bit grey or colour.
void checkDepthFrame(const StereoRig& rig, const cv::Mat& left_raw, const cv::Mat& right_raw) {
  const cv::Size size(rig.left.width, rig.left.height);
  if (left_raw.size() != size || right_raw.size() != size)
    throw std::invalid_argument("CalibrationMonitor: depth frame of " + std::to_string(left_raw.cols) + "x" +
                                std::to_string(left_raw.rows) + " for a calibration of " +
                                std::to_string(size.width) + "x" + std::to_string(size.height));
  for (const cv::Mat* image : {&left_raw, &right_raw})
    if (image->type() != CV_8UC1 && image->type() != CV_8UC3)
      throw std::invalid_argument("CalibrationMonitor: depth frame images must be 8-bit grey or colour "
                                  "(CV_8UC1 / CV_8UC3)");
}

// Robust fit offset = J w (w: tilt, roll in deg) from `start`: Huber weights inside the band
// around the model's row. Returns the matches used (0 when the step is not finite); normal: the
// weighted normal equations of the last iteration.
int fitTiltRoll(const RowOffsets& rows, const CalibrationMonitorOptions& options, const Eigen::Vector2d& start,
                Eigen::Vector2d* w, Eigen::Matrix2d* normal) {
  *w = start;
  int used = 0;
  for (int iteration = 0; iteration < 8; ++iteration) {
    normal->setZero();
    Eigen::Vector2d rhs = Eigen::Vector2d::Zero();
    used = 0;
    for (size_t i = 0; i < rows.size(); ++i) {
      const double r = rows.offsets[i] - rows.jacobians[i].dot(*w);
      if (std::abs(r) > options.band_half_height_px) continue;
      const double weight = std::abs(r) <= options.huber_px ? 1.0 : options.huber_px / std::abs(r);
      *normal += weight * rows.jacobians[i] * rows.jacobians[i].transpose();
      rhs += weight * rows.jacobians[i] * r;
      ++used;
    }
    if (used < options.min_matches) return used;
    const Eigen::Vector2d step = normal->ldlt().solve(rhs);
    if (!step.allFinite()) return 0;
    *w += step;
    if (step.norm() < 1e-6) break;
  }
  return used;
}

// The median offset taken as a tilt: the start when the smoothed estimate finds too few matches
// near its rows (a knock larger than the band since the last frame).
Eigen::Vector2d medianStart(const RowOffsets& rows) {
  std::vector<double> sorted = rows.offsets, jx;
  for (const auto& j : rows.jacobians) jx.push_back(j(0));
  const size_t mid = sorted.size() / 2;
  std::nth_element(sorted.begin(), sorted.begin() + mid, sorted.end());
  std::nth_element(jx.begin(), jx.begin() + mid, jx.end());
  return Eigen::Vector2d(std::abs(jx[mid]) > 1e-9 ? sorted[mid] / jx[mid] : 0.0, 0.0);
}

// Covariance of the fit w: the residuals' robust spread (MAD) through the weighted normal equations.
Eigen::Matrix2d tiltRollCovariance(const RowOffsets& rows, double band_half_height_px, const Eigen::Vector2d& w,
                                   const Eigen::Matrix2d& normal) {
  std::vector<double> abs_residuals;
  for (size_t i = 0; i < rows.size(); ++i) {
    const double r = std::abs(rows.offsets[i] - rows.jacobians[i].dot(w));
    if (r <= band_half_height_px) abs_residuals.push_back(r);
  }
  const size_t mid = abs_residuals.size() / 2;
  std::nth_element(abs_residuals.begin(), abs_residuals.begin() + mid, abs_residuals.end());
  const double scale = 1.4826 * abs_residuals[mid];
  return scale * scale * normal.inverse();
}

// Verification: a board corner the change is fitted to.
struct FitCorner {
  Eigen::Vector3d in_left;  // the corner in the left optical frame
  Eigen::Vector2d pixel;
  int camera;  // 0 left, 1 right
};

// What the boards of one verification show: the corners to fit and the squared reprojection
// errors of each camera alone and of the right camera against the left's board poses.
struct BoardErrors {
  std::vector<FitCorner> fit_corners;
  std::vector<double> sq_left, sq_right, sq_stereo;
};

const BoardCorners* findCorners(const std::vector<BoardCorners>& list, int id) {
  for (const auto& b : list)
    if (b.board_id == id) return &b;
  return nullptr;
}

// Pose of a board in a camera from its corners (PnP on undistorted rays).
bool solvePose(const VirtualBoard& board, const BoardCorners& corners, const PinholeCamera& camera,
               Eigen::Isometry3d* camera_from_board) {
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  for (size_t i = 0; i < corners.size(); ++i) {
    const Eigen::Vector3d p = board.cornerInBoard(corners.corner_ids[i]);
    const Eigen::Vector2d n = camera.pixelToNormalized(Eigen::Vector2d(corners.u[i], corners.v[i]));
    object.emplace_back(p.x(), p.y(), p.z());
    image.emplace_back(n.x(), n.y());
  }
  cv::Vec3d rvec, tvec;
  if (!cv::solvePnP(object, image, cv::Matx33d::eye(), cv::noArray(), rvec, tvec, false, cv::SOLVEPNP_IPPE))
    return false;
  cv::solvePnPRefineLM(object, image, cv::Matx33d::eye(), cv::noArray(), rvec, tvec);
  cv::Matx33d R;
  cv::Rodrigues(rvec, R);
  camera_from_board->setIdentity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) camera_from_board->linear()(r, c) = R(r, c);
    camera_from_board->translation()(r) = tvec(r);
  }
  return camera_from_board->translation().z() > 0;
}

bool squaredError(const PinholeCamera& camera, const Eigen::Vector3d& p, float u, float v, double* sq) {
  Eigen::Vector2d pixel;
  if (!camera.project(p, &pixel)) return false;
  *sq = (pixel - Eigen::Vector2d(u, v)).squaredNorm();
  return true;
}

bool usableCorners(const VirtualBoard& board, const BoardCorners* c, int min_board_corners) {
  if (!c || static_cast<int>(c->size()) < min_board_corners) return false;
  for (int id : c->corner_ids)
    if (id < 0 || id >= board.cornerCount()) return false;
  return c->u.size() == c->size() && c->v.size() == c->size();
}

// The corners' pixel offsets from where the rig changed by c projects them.
void changeResiduals(const StereoRig& rig, const std::vector<FitCorner>& corners, const Change& c,
                     Eigen::VectorXd* r) {
  const StereoRig o = observedRig(rig, c);
  r->resize(2 * corners.size());
  for (size_t i = 0; i < corners.size(); ++i) {
    const FitCorner& k = corners[i];
    Eigen::Vector2d pixel;
    const bool ok = k.camera == 0 ? o.left.project(k.in_left, &pixel)
                                  : o.right.project(o.right_from_left * k.in_left, &pixel);
    const Eigen::Vector2d d = ok ? Eigen::Vector2d(k.pixel - pixel) : Eigen::Vector2d::Zero();
    r->segment<2>(2 * i) = d;
  }
}

// One Gauss-Newton step of the change c (numeric derivatives of the active parameters, Huber
// weights) given its residuals r; returns the step of the active parameters.
Eigen::VectorXd changeStep(const StereoRig& rig, const std::vector<FitCorner>& corners, const std::vector<int>& active,
                           const Change& c, const Eigen::VectorXd& r) {
  const double step[kChange] = {1e-3, 1e-3, 1e-3, 1e-5, 1e-5};
  const double huber = 1.0;
  Eigen::MatrixXd J(r.size(), active.size());
  for (size_t a = 0; a < active.size(); ++a) {
    Change cs = c;
    cs(active[a]) += step[active[a]];
    Eigen::VectorXd rs;
    changeResiduals(rig, corners, cs, &rs);
    J.col(a) = -(rs - r) / step[active[a]];  // derivative of the prediction
  }
  Eigen::VectorXd weights(r.size());
  for (int i = 0; i < r.size(); i += 2) {
    const double e = r.segment<2>(i).norm();
    weights(i) = weights(i + 1) = e <= huber ? 1.0 : huber / e;
  }
  const Eigen::MatrixXd JtW = J.transpose() * weights.asDiagonal();
  return (JtW * J).ldlt().solve(JtW * r);
}

// Fits the change to the corners (Gauss-Newton, numeric derivatives, Huber weights). Without
// board poses the boards sit where the left camera puts them, so the left focal scale is held.
// r: the residuals of the fitted change.
Change fitChange(const StereoRig& rig, const std::vector<FitCorner>& corners, bool boards_posed,
                 Eigen::VectorXd* r) {
  const int n = static_cast<int>(kChange);
  std::vector<int> active;
  for (int k = 0; k < n; ++k)
    if (k != 3 || boards_posed) active.push_back(k);
  Change c = Change::Zero();
  for (int iteration = 0; iteration < 6; ++iteration) {
    changeResiduals(rig, corners, c, r);
    const Eigen::VectorXd delta = changeStep(rig, corners, active, c, *r);
    if (!delta.allFinite()) break;
    for (size_t a = 0; a < active.size(); ++a) c(active[a]) += delta(a);
    if (delta.norm() < 1e-7) break;
  }
  changeResiduals(rig, corners, c, r);
  return c;
}

}  // namespace

struct CalibrationMonitor::Impl {
  CalibrationMonitorOptions options;

  // The calibration in force.
  bool has_calibration = false;
  StereoRig rig;
  int epoch = 0;
  std::vector<VirtualBoard> boards;
  bool boards_posed = false;
  Eigen::Matrix3d H1, H2;  // normalised ray -> homogeneous rectified pixel (K' R)
  // Accuracy figures as quadratic forms of the change (figure^2 = c^T A c), linearised once
  // per calibration: misalignment, disparity bias, depth error per depth.
  std::array<ChangeMatrix, kFigures> forms;

  double now = -std::numeric_limits<double>::infinity();

  // Depth mode.
  bool has_depth = false;
  double depth_time = 0.0;
  Eigen::Vector2d tilt_roll = Eigen::Vector2d::Zero();  // smoothed right rotation about x, z (deg)
  Eigen::Matrix2d tilt_roll_cov = Eigen::Matrix2d::Zero();
  Eigen::Matrix2d frame_cov = Eigen::Matrix2d::Zero();  // observed spread of one frame's estimate
  double first_depth_time = 0.0;
  long depth_count = 0;
  int matches = 0;
  long depth_calls = 0;
  std::string depth_note;  // why the last depth frame gave no measurement

  // Verification.
  bool has_verification = false;
  double verification_time = 0.0;
  Change verified_change = Change::Zero();
  double rms_left = 0, rms_right = 0, stereo_consistency = 0, residual = 0;
  std::string verification_note;

  // Signal levels (hysteresis state).
  CalibrationHealth depth_level = CalibrationHealth::kGood;
  CalibrationHealth board_misalignment_level = CalibrationHealth::kGood;
  CalibrationHealth bias_level = CalibrationHealth::kGood;
  CalibrationHealth residual_level = CalibrationHealth::kGood;

  // Buffers reused from frame to frame.
  SceneMatchBuffers buffers;

  void advance(double t) { now = std::max(now, t); }
  // The depth mode counts once its smoothing has seen one time constant of frames (its first
  // frames alone are noisy) and while its last measurement is recent.
  bool depthFresh() const {
    return has_depth && depth_time - first_depth_time >= options.smoothing_time_s &&
           now - depth_time <= options.max_depth_age_s;
  }
  bool verificationFresh() const {
    return has_verification && now - verification_time <= options.max_verification_age_s;
  }
  Change depthChange() const {
    Change c = Change::Zero();
    c(0) = tilt_roll(0);
    c(2) = tilt_roll(1);
    return c;
  }
  double depthMisalignment() const { return quadratic(forms[0], depthChange()); }
  // The change as best known now: pan and zoom from the verification, tilt and roll from the
  // depth mode while it is fresh.
  Change combinedChange() const {
    Change c = verificationFresh() ? verified_change : Change::Zero();
    if (depthFresh()) {
      c(0) = tilt_roll(0);
      c(2) = tilt_roll(1);
    }
    return c;
  }

  void setCalibration(const StereoRig& r, int e, const std::vector<VirtualBoard>& b, bool posed);
  bool addDepthFrame(double t, const cv::Mat& left_raw, const cv::Mat& right_raw);
  bool addVerification(double t, const StereoObservation& observation);
  HealthReport report() const;
  void updateLevels();

 private:
  // The stages of addDepthFrame and addVerification.
  bool noDepthMeasurement(const std::string& why);  // depth_note = why; false
  RowOffsets rowOffsets(const std::vector<SceneMatch>& found) const;
  void smoothDepth(double t, const Eigen::Vector2d& w, const Eigen::Matrix2d& covariance);
  void addBoardErrors(const VirtualBoard& board, const StereoObservation& observation, BoardErrors* e) const;
  void addLeftErrors(const VirtualBoard& board, const BoardCorners& left, const Eigen::Isometry3d& pose,
                     BoardErrors* e) const;
  void addRightErrors(const VirtualBoard& board, const BoardCorners& right, const Eigen::Isometry3d* left_from_board,
                      BoardErrors* e) const;
};

void CalibrationMonitor::Impl::setCalibration(const StereoRig& r, int e, const std::vector<VirtualBoard>& b,
                                              bool posed) {
  const std::string invalid = r.validate();
  if (!invalid.empty()) throw std::invalid_argument("CalibrationMonitor: calibration in force: " + invalid);
  const RectificationGeometry g = computeRectificationGeometry(r, options.rectification);
  Eigen::Matrix3d h1, h2;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double a1 = 0, a2 = 0;
      for (int k = 0; k < 3; ++k) {
        a1 += g.P1(i, k) * g.R1(k, j);
        a2 += g.P2(i, k) * g.R2(k, j);
      }
      h1(i, j) = a1;
      h2(i, j) = a2;
    }
  // Linearise the accuracy figures around the calibration (polarisation of the quadratic form
  // from evaluations at one step per parameter and per pair of parameters).
  StereoAccuracyOptions accuracy;
  accuracy.rectification = options.rectification;
  accuracy.depths_m.assign(kHealthDepthsM.begin(), kHealthDepthsM.end());
  accuracy.depths_m.push_back(std::numeric_limits<double>::infinity());
  const double step[kChange] = {0.02, 0.02, 0.02, 2e-4, 2e-4};
  std::array<Figures, kChange> single;
  for (int i = 0; i < kChange; ++i) {
    Change c = Change::Zero();
    c(i) = step[i];
    single[i] = squaredFigures(r, c, accuracy);
  }
  std::array<ChangeMatrix, kFigures> new_forms;
  for (auto& f : new_forms) f.setZero();
  for (int i = 0; i < kChange; ++i) {
    for (int f = 0; f < kFigures; ++f) new_forms[f](i, i) = single[i](f) / (step[i] * step[i]);
    for (int j = i + 1; j < kChange; ++j) {
      Change c = Change::Zero();
      c(i) = step[i];
      c(j) = step[j];
      const Figures both = squaredFigures(r, c, accuracy);
      for (int f = 0; f < kFigures; ++f)
        new_forms[f](i, j) = new_forms[f](j, i) = (both(f) - single[i](f) - single[j](f)) / (2.0 * step[i] * step[j]);
    }
  }
  // Nothing above changed the monitor: a refused calibration leaves the previous one in force.
  H1 = h1;
  H2 = h2;
  forms = new_forms;
  rig = r;
  epoch = e;
  boards = b;
  boards_posed = posed;
  has_calibration = true;
  has_depth = has_verification = false;
  tilt_roll.setZero();
  tilt_roll_cov.setZero();
  frame_cov.setZero();
  depth_count = 0;
  verified_change.setZero();
  matches = 0;
  depth_calls = 0;
  rms_left = rms_right = stereo_consistency = residual = 0.0;
  depth_note.clear();
  verification_note.clear();
  depth_level = board_misalignment_level = bias_level = residual_level = CalibrationHealth::kGood;
}

bool CalibrationMonitor::Impl::noDepthMeasurement(const std::string& why) {
  depth_note = why;
  updateLevels();
  return false;
}

RowOffsets CalibrationMonitor::Impl::rowOffsets(const std::vector<SceneMatch>& found) const {
  RowOffsets rows;
  rows.offsets.reserve(found.size());
  rows.jacobians.reserve(found.size());
  for (const SceneMatch& m : found) {
    const Eigen::Vector3d hl = H1 * rig.left.pixelToNormalized(Eigen::Vector2d(m.left_u, m.left_v)).homogeneous();
    const Eigen::Vector3d ray = rig.right.pixelToNormalized(Eigen::Vector2d(m.right_u, m.right_v)).homogeneous();
    const Eigen::Vector3d hr = H2 * ray;
    if (hl.z() <= 0 || hr.z() <= 0) continue;
    const double disparity = hl.x() / hl.z() - hr.x() / hr.z();
    if (disparity < -1.0) continue;  // behind the rig: a wrong match
    rows.offsets.push_back(hl.y() / hl.z() - hr.y() / hr.z());
    Eigen::Vector2d j;
    for (int k = 0; k < 2; ++k) {
      const Eigen::Vector3d axis = k == 0 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitZ();
      const Eigen::Vector3d dh = H2 * (kDegToRad * axis.cross(ray));
      j(k) = (dh.y() * hr.z() - hr.y() * dh.z()) / (hr.z() * hr.z());
    }
    rows.jacobians.push_back(j);
  }
  return rows;
}

// Exponential smoothing over time; the first measurements are averaged (weight 1/n) until the
// exponential weight is the larger. The spread of a frame's estimate is taken as the larger of
// the fit's and the one observed from frame to frame (the scene's texture and slanted surfaces
// make frames disagree by more than their residuals say), and the smoothed estimate's
// variance is that of the weighted mean.
void CalibrationMonitor::Impl::smoothDepth(double t, const Eigen::Vector2d& w, const Eigen::Matrix2d& covariance) {
  const double alpha =
      has_depth ? std::max(1.0 / (depth_count + 1),
                           1.0 - std::exp(-std::max(t - depth_time, 1e-3) / options.smoothing_time_s))
                : 1.0;
  if (has_depth) {
    const Eigen::Vector2d innovation = w - tilt_roll;
    frame_cov += alpha * (innovation * innovation.transpose() - frame_cov);
  } else {
    frame_cov = covariance;
    first_depth_time = t;
  }
  tilt_roll += alpha * (w - tilt_roll);
  const Eigen::Matrix2d per_frame = frame_cov.trace() > covariance.trace() ? frame_cov : covariance;
  tilt_roll_cov = alpha / (2.0 - alpha) * per_frame;
  ++depth_count;
  has_depth = true;
  depth_time = std::max(depth_time, t);
}

bool CalibrationMonitor::Impl::addDepthFrame(double t, const cv::Mat& left_raw, const cv::Mat& right_raw) {
  if (!has_calibration) throw std::logic_error("CalibrationMonitor::addDepthFrame before setCalibration");
  checkDepthFrame(rig, left_raw, right_raw);
  advance(t);
  if (depth_calls++ % options.depth_frame_stride != 0) {
    updateLevels();
    return false;
  }
  const cv::Mat left = toGray(left_raw, "left"), right = toGray(right_raw, "right");

  int features = 0;
  const std::vector<SceneMatch> found = matchStereoScene(left, right, rig, options.matching, &buffers, &features);
  if (features < options.min_matches)
    return noDepthMeasurement("too few scene features (" + std::to_string(features) + ")");
  const RowOffsets rows = rowOffsets(found);
  if (static_cast<int>(rows.size()) < options.min_matches)
    return noDepthMeasurement("too few left-right matches (" + std::to_string(rows.size()) + ")");

  // The fit starts from the smoothed estimate and, when too few matches lie near the rows that
  // predicts (a knock larger than the band since the last frame), again from the median offset
  // taken as a tilt.
  Eigen::Vector2d w;
  Eigen::Matrix2d normal;
  int used = fitTiltRoll(rows, options, has_depth ? tilt_roll : medianStart(rows), &w, &normal);
  if (used < options.min_matches && has_depth) used = fitTiltRoll(rows, options, medianStart(rows), &w, &normal);
  if (used < options.min_matches)
    return noDepthMeasurement("too few matches near their rows (" + std::to_string(used) + ")");
  smoothDepth(t, w, tiltRollCovariance(rows, options.band_half_height_px, w, normal));
  matches = used;
  depth_note.clear();
  updateLevels();
  return true;
}

// The left camera's corners against the board at `pose` (the rig's pose of it, or the left
// camera's own PnP pose); with posed boards they are also fitted.
void CalibrationMonitor::Impl::addLeftErrors(const VirtualBoard& board, const BoardCorners& left,
                                             const Eigen::Isometry3d& pose, BoardErrors* e) const {
  for (size_t i = 0; i < left.size(); ++i) {
    const Eigen::Vector3d p = pose * board.cornerInBoard(left.corner_ids[i]);
    double sq;
    if (!squaredError(rig.left, p, left.u[i], left.v[i], &sq)) continue;
    e->sq_left.push_back(sq);
    if (boards_posed) e->fit_corners.push_back({p, Eigen::Vector2d(left.u[i], left.v[i]), 0});
  }
}

// The right camera's corners: against the rig's pose of the board (fitted) or the right camera's
// own PnP pose, and against the left camera's pose of it when there is one (left_from_board; the
// stereo consistency, fitted without posed boards).
void CalibrationMonitor::Impl::addRightErrors(const VirtualBoard& board, const BoardCorners& right,
                                              const Eigen::Isometry3d* left_from_board, BoardErrors* e) const {
  Eigen::Isometry3d right_from_board;
  const bool right_pose = !boards_posed && solvePose(board, right, rig.right, &right_from_board);
  for (size_t i = 0; i < right.size(); ++i) {
    const Eigen::Vector3d local = board.cornerInBoard(right.corner_ids[i]);
    double sq;
    if (boards_posed) {
      const Eigen::Vector3d p = board.rig_from_board * local;
      if (squaredError(rig.right, rig.right_from_left * p, right.u[i], right.v[i], &sq)) {
        e->sq_right.push_back(sq);
        e->fit_corners.push_back({p, Eigen::Vector2d(right.u[i], right.v[i]), 1});
      }
    } else if (right_pose && squaredError(rig.right, right_from_board * local, right.u[i], right.v[i], &sq)) {
      e->sq_right.push_back(sq);
    }
    if (left_from_board) {
      const Eigen::Vector3d p = *left_from_board * local;
      if (squaredError(rig.right, rig.right_from_left * p, right.u[i], right.v[i], &sq)) {
        e->sq_stereo.push_back(sq);
        if (!boards_posed) e->fit_corners.push_back({p, Eigen::Vector2d(right.u[i], right.v[i]), 1});
      }
    }
  }
}

void CalibrationMonitor::Impl::addBoardErrors(const VirtualBoard& board, const StereoObservation& observation,
                                              BoardErrors* e) const {
  const BoardCorners* left = findCorners(observation.left, board.virtual_id);
  const BoardCorners* right = findCorners(observation.right, board.virtual_id);
  const bool has_left = usableCorners(board, left, options.min_board_corners);
  const bool has_right = usableCorners(board, right, options.min_board_corners);
  Eigen::Isometry3d left_from_board;
  const bool left_pose = has_left && solvePose(board, *left, rig.left, &left_from_board);
  if (has_left && (boards_posed || left_pose))
    addLeftErrors(board, *left, boards_posed ? board.rig_from_board : left_from_board, e);
  if (has_right) addRightErrors(board, *right, left_pose ? &left_from_board : nullptr, e);
}

bool CalibrationMonitor::Impl::addVerification(double t, const StereoObservation& observation) {
  if (!has_calibration) throw std::logic_error("CalibrationMonitor::addVerification before setCalibration");
  advance(t);
  BoardErrors errors;
  for (const auto& board : boards) addBoardErrors(board, observation, &errors);
  if (static_cast<int>(errors.fit_corners.size()) < options.min_corners) {
    verification_note = "too few board corners (" + std::to_string(errors.fit_corners.size()) + ")";
    updateLevels();
    return false;
  }
  Eigen::VectorXd r;
  const Change c = fitChange(rig, errors.fit_corners, boards_posed, &r);

  verified_change = c;
  rms_left = rmsOf(errors.sq_left);
  rms_right = rmsOf(errors.sq_right);
  stereo_consistency = rmsOf(errors.sq_stereo);
  residual = std::sqrt(r.squaredNorm() / static_cast<double>(errors.fit_corners.size()));
  has_verification = true;
  verification_time = std::max(verification_time, t);
  verification_note.clear();
  updateLevels();
  return true;
}

void CalibrationMonitor::Impl::updateLevels() {
  const double h = options.hysteresis;
  if (depthFresh())
    depth_level = levelOf(depth_level, depthMisalignment(), options.misalignment_degraded_px,
                          options.misalignment_bad_px, h);
  if (verificationFresh()) {
    board_misalignment_level = levelOf(board_misalignment_level, quadratic(forms[0], verified_change),
                                       options.misalignment_degraded_px, options.misalignment_bad_px, h);
    bias_level = levelOf(bias_level, quadratic(forms[1], verified_change), options.disparity_bias_degraded_px,
                         options.disparity_bias_bad_px, h);
    residual_level = levelOf(residual_level, residual, options.board_residual_degraded_px,
                             options.board_residual_bad_px, h);
  }
}

HealthReport CalibrationMonitor::Impl::report() const {
  HealthReport out;
  out.epoch = epoch;
  if (!has_calibration) {
    out.reason = "no calibration in force";
    return out;
  }
  const bool depth = depthFresh(), verification = verificationFresh();
  out.epipolar_age_s = has_depth ? now - depth_time : -1.0;
  out.board_age_s = has_verification ? now - verification_time : -1.0;
  out.matches = matches;
  if (has_depth) {
    out.misalignment_px = depthMisalignment();
    Eigen::Matrix2d a;
    a << forms[0](0, 0), forms[0](0, 2), forms[0](2, 0), forms[0](2, 2);
    out.misalignment_sd_px = std::sqrt(std::max(0.0, (a * tilt_roll_cov).trace()));
  }
  if (has_verification) {
    out.board_rms_left_px = rms_left;
    out.board_rms_right_px = rms_right;
    out.stereo_consistency_px = stereo_consistency;
    out.board_residual_px = residual;
  }
  const Change c = combinedChange();
  out.right_rotation_deg = c.head<3>();
  out.left_focal_scale = 1.0 + c(3);
  out.right_focal_scale = 1.0 + c(4);
  out.disparity_bias_px = quadratic(forms[1], c);
  for (size_t i = 0; i < kHealthDepthsM.size(); ++i)
    out.predicted_depth_error_pct[i] = quadratic(forms[2 + i], c);

  // The state: the worst fresh signal; its reasons, worst first.
  std::vector<std::pair<CalibrationHealth, std::string>> reasons;
  if (depth)
    reasons.emplace_back(depth_level, "scene rows misaligned by " + fixed(out.misalignment_px, 2) + " px (limit " +
                                          fixed(options.misalignment_degraded_px, 2) + " px)");
  if (verification) {
    reasons.emplace_back(board_misalignment_level, "boards show a misalignment of " +
                                                       fixed(quadratic(forms[0], verified_change), 2) + " px (limit " +
                                                       fixed(options.misalignment_degraded_px, 2) + " px)");
    reasons.emplace_back(bias_level, "boards show a disparity bias of " + fixed(quadratic(forms[1], verified_change), 2) +
                                         " px (limit " + fixed(options.disparity_bias_degraded_px, 2) +
                                         " px): right camera turned by (" + fixed(verified_change(0), 3) + ", " +
                                         fixed(verified_change(1), 3) + ", " + fixed(verified_change(2), 3) +
                                         ") deg, focal length changed by " + fixed(100.0 * verified_change(3), 2) +
                                         " % (left), " + fixed(100.0 * verified_change(4), 2) + " % (right)");
    reasons.emplace_back(residual_level, "board corners " + fixed(residual, 2) + " px from the calibration (limit " +
                                             fixed(options.board_residual_degraded_px, 2) + " px)");
  }
  if (reasons.empty()) {
    std::string why = has_depth && now - depth_time <= options.max_depth_age_s ? "depth mode settling"
                                                                               : "no recent measurement";
    if (!depth_note.empty()) why += "; depth: " + depth_note;
    if (!verification_note.empty()) why += "; boards: " + verification_note;
    out.reason = why;
    return out;
  }
  std::stable_sort(reasons.begin(), reasons.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  out.state = reasons.front().first;
  std::string why;
  for (const auto& reason : reasons) {
    if (out.state != CalibrationHealth::kGood && reason.first == CalibrationHealth::kGood) break;
    why += (why.empty() ? "" : "; ") + reason.second;
  }
  if (!depth && has_depth && now - depth_time <= options.max_depth_age_s)
    why += "; depth mode settling";
  else if (!depth)
    why += "; no recent depth-mode measurement" + (depth_note.empty() ? "" : " (" + depth_note + ")");
  if (!verification)
    why += "; no recent board verification" + (verification_note.empty() ? "" : " (" + verification_note + ")");
  out.reason = why;
  return out;
}

CalibrationMonitor::CalibrationMonitor(CalibrationMonitorOptions options) : impl_(new Impl) {
  const std::string invalid = options.validate();
  if (!invalid.empty()) throw std::invalid_argument("CalibrationMonitorOptions: " + invalid);
  impl_->options = std::move(options);
}
CalibrationMonitor::~CalibrationMonitor() = default;
CalibrationMonitor::CalibrationMonitor(CalibrationMonitor&&) noexcept = default;
CalibrationMonitor& CalibrationMonitor::operator=(CalibrationMonitor&&) noexcept = default;

void CalibrationMonitor::setCalibration(const StereoRig& rig, int epoch, const std::vector<VirtualBoard>& boards,
                                        bool boards_posed) {
  impl_->setCalibration(rig, epoch, boards, boards_posed);
}
bool CalibrationMonitor::hasCalibration() const { return impl_->has_calibration; }
bool CalibrationMonitor::addDepthFrame(double t, const cv::Mat& left_raw, const cv::Mat& right_raw) {
  return impl_->addDepthFrame(t, left_raw, right_raw);
}
bool CalibrationMonitor::addVerification(double t, const StereoObservation& observation) {
  return impl_->addVerification(t, observation);
}
HealthReport CalibrationMonitor::report() const { return impl_->report(); }

}  // namespace embedded_calibration_stereo::core
