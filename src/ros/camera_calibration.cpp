#include "embedded_calibration_stereo/ros/camera_calibration.h"

#include <cmath>
#include <cstdio>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/set_camera_info_answer.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"

namespace embedded_calibration_stereo {

namespace {

std::string resolve(const StereoCalibration::Camera& camera) {
  std::string path, error;
  if (!resolveCalibrationUrl(camera.url, camera.name, &path, &error)) throw core::ConfigError(camera.parameter, error);
  return path;
}

const char* sideName(bool left) { return left ? "left" : "right"; }

// Whether `info` keeps the rectification (R and P) of `in_force`, its camera's calibration in
// force: a change of K and D alone (that camera's intrinsics) keeps the pair rectified; any
// change of R or P moves the rectified pair, so the other camera must change with it.
bool keepsRectification(const sensor_msgs::CameraInfo& info, const sensor_msgs::CameraInfo& in_force) {
  constexpr double kRotationTolerance = 1e-9;  // round-off of a file; far below any calibration
  for (size_t i = 0; i < info.R.size(); ++i)
    if (!(std::abs(info.R[i] - in_force.R[i]) <= kRotationTolerance)) return false;
  for (size_t i = 0; i < info.P.size(); ++i)
    if (!(std::abs(info.P[i] - in_force.P[i]) <= kRectifiedPairTolerancePx)) return false;
  return true;
}

// What a calibration of one camera alone looks like (camera_calibration's monocular calibrator):
// no rectifying rotation (R the identity) and no baseline (Tx zero), where the camera in force
// (`in_force`) has a rectifying R. The first half of a stereo calibration of a perfectly aligned
// rig looks the same: such a call is staged like any other, and taken as monocular only when no
// other camera's call completes it within the pair timeout.
bool isMonocular(const sensor_msgs::CameraInfo& info, const sensor_msgs::CameraInfo& in_force) {
  constexpr double kTolerance = 1e-9;
  const auto identity = [&](const sensor_msgs::CameraInfo::_R_type& R) {
    for (size_t i = 0; i < R.size(); ++i)
      if (!(std::abs(R[i] - (i % 4 == 0 ? 1.0 : 0.0)) <= kTolerance)) return false;
    return true;
  };
  return identity(info.R) && std::abs(info.P[3]) <= kTolerance && !identity(in_force.R);
}

}  // namespace

StereoCalibration::StereoCalibration(const Camera& left, const Camera& right, uint32_t width, uint32_t height,
                                     double pair_timeout_s, std::optional<core::StereoRig> nominal)
    : left_camera_(left),
      right_camera_(right),
      width_(width),
      height_(height),
      pair_timeout_(pair_timeout_s),
      nominal_(std::move(nominal)),
      store_(resolve(left), resolve(right), left.name, right.name) {
  if (store_.leftPath() == store_.rightPath())
    throw core::ConfigError(right.parameter, "resolves to '" + store_.rightPath() + "', the same file as " +
                                                left.parameter + ": each camera needs its own file");
}

std::string StereoCalibration::checkOne(bool left, const sensor_msgs::CameraInfo& info, const std::string& name) const {
  std::string problem = checkCameraInfo(info, name, width_, height_);
  if (!problem.empty()) return problem;
  if (nominal_) {
    const core::PinholeCamera& camera = left ? nominal_->left : nominal_->right;
    problem = checkNominalFocal(info, name, camera.fx, camera.fy);
    if (!problem.empty()) return problem;
  }
  // The OnlineCalibrator models plumb_bob only: it would not read any other calibration back.
  core::PinholeCamera camera;
  std::string error;
  if (!fromCameraInfo(info, &camera, &error)) return name + ": " + error;
  return "";
}

std::string StereoCalibration::checkPair(const sensor_msgs::CameraInfo& left, const std::string& left_name,
                                         const sensor_msgs::CameraInfo& right, const std::string& right_name) const {
  std::string problem = checkOne(true, left, left_name);
  if (problem.empty()) problem = checkOne(false, right, right_name);
  if (problem.empty()) problem = checkRectifiedPair(left, left_name, right, right_name);
  return problem;
}

std::string StereoCalibration::readGeneration(const CalibrationPairStore::Generation& g, sensor_msgs::CameraInfo* left,
                                              sensor_msgs::CameraInfo* right) const {
  std::string error;
  if (!readCalibrationFile(g.left_file, nullptr, left, &error)) return error;
  if (!readCalibrationFile(g.right_file, nullptr, right, &error)) return error;
  return checkPair(*left, "'" + g.left_file + "'", *right, "'" + g.right_file + "'");
}

void StereoCalibration::setProblem(const std::string& problem) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  problem_ = problem;
}

std::string StereoCalibration::load(const sensor_msgs::CameraInfo& left_fallback,
                                    const sensor_msgs::CameraInfo& right_fallback) {
  std::lock_guard<std::mutex> write_lock(write_mutex_);
  sensor_msgs::CameraInfo infos[2];
  CalibrationFileState states[2];
  std::string errors[2];
  const Camera* cameras[2] = {&left_camera_, &right_camera_};
  const std::string paths[2] = {store_.leftPath(), store_.rightPath()};
  for (int i = 0; i < 2; ++i) states[i] = readCalibrationFileIfPresent(paths[i], &infos[i], &errors[i]);
  const auto named = [&](int i) { return cameras[i]->parameter + " '" + paths[i] + "'"; };

  std::string problem, source;
  sensor_msgs::CameraInfo left = left_fallback, right = right_fallback;
  unsigned generation = 0;
  if (states[0] == CalibrationFileState::kMissing && states[1] == CalibrationFileState::kMissing) {
    source = "no calibration files yet (" + paths[0] + ", " + paths[1] + ")";
  } else {
    for (int i = 0; i < 2 && problem.empty(); ++i) {
      if (states[i] == CalibrationFileState::kBroken) problem = named(i) + ": " + errors[i];
      if (states[i] == CalibrationFileState::kMissing)
        problem = named(i) + ": missing while " + named(1 - i) + " exists (half a stereo calibration)";
    }
    if (problem.empty()) problem = checkPair(infos[0], named(0), infos[1], named(1));
    if (problem.empty()) {
      left = infos[0];
      right = infos[1];
      generation = store_.linkedGeneration();
      source = "files '" + paths[0] + "' and '" + paths[1] + "'";
    } else {
      // The previous calibration: the newest valid generation verified GOOD, else the newest
      // valid one.
      source = "";
      for (const bool verified_only : {true, false}) {
        for (const auto& g : store_.generations()) {
          sensor_msgs::CameraInfo gl, gr;
          if ((verified_only && !g.verified) || !readGeneration(g, &gl, &gr).empty()) continue;
          left = gl;
          right = gr;
          generation = g.number;
          source = "generation " + std::to_string(g.number) + (g.verified ? " (verified GOOD)" : "") + " in '" +
                   store_.directory() + "'";
          break;
        }
        if (!source.empty()) break;
      }
      if (source.empty()) source = "the nominal calibration (no valid calibration found)";
      problem = "calibration files rejected: " + problem + "; running on " + source;
    }
  }
  alignRectifiedPair(left, &right);  // exact fx', fy', cy' for image_geometry (a no-op on fallbacks)
  std::lock_guard<std::mutex> lock(state_mutex_);
  in_force_.left = left;
  in_force_.right = right;
  in_force_.generation = generation;
  problem_ = problem;
  source_ = source;
  return source;
}

std::vector<StereoCalibration::SetResult> StereoCalibration::applyStagedMonocular() {
  std::lock_guard<std::mutex> write_lock(write_mutex_);
  std::vector<SetResult> results;
  for (const bool left : {true, false}) {
    std::optional<Staged>& staged = left ? staged_left_ : staged_right_;
    if (!staged || !staged->monocular || Clock::now() - staged->since < pair_timeout_) continue;
    const sensor_msgs::CameraInfo info = staged->info;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      staged.reset();
    }
    SetResult result = setMonocularLocked(left, info, inForce());
    result.message = "staged " + std::string(sideName(left)) + " calibration, no " + sideName(!left) +
                     "/set_camera_info within the pair timeout: " + result.message;
    results.push_back(std::move(result));
  }
  return results;
}

StereoCalibration::SetResult StereoCalibration::setMonocularLocked(bool left, const sensor_msgs::CameraInfo& info,
                                                                  const InForce& in_force) {
  SetResult result;
  const std::string name = std::string(sideName(left)) + "/set_camera_info";
  core::StereoRig rig;
  core::PinholeCamera camera;
  std::string error;
  if (!fromStereoCameraInfo(in_force.left, in_force.right, &rig, &error) || !fromCameraInfo(info, &camera, &error)) {
    result.message = "rejected: " + name + ": a calibration of this camera alone (R the identity, Tx 0), and " + error;
    return result;
  }
  (left ? rig.left : rig.right) = camera;
  std::pair<sensor_msgs::CameraInfo, sensor_msgs::CameraInfo> pair;
  try {
    pair = toStereoCameraInfo(rig, kMonocularRectificationAlpha);
  } catch (const std::invalid_argument& e) {
    result.message = std::string("rejected: ") + name + ": its camera with the other one does not rectify: " + e.what();
    return result;
  }
  const std::string problem = checkPair(pair.first, "left (rectified again)", pair.second, "right (rectified again)");
  if (!problem.empty()) {
    result.message = "rejected: " + name + ": " + problem;
    return result;
  }
  std::string where;
  error = commitLocked(pair.first, pair.second, 1, &where);
  if (!error.empty()) {
    result.message = "not stored: " + error;
    setProblem("calibration not stored: " + error);
    return result;
  }
  result.success = true;
  result.message = "stored: a calibration of the " + std::string(sideName(left)) +
                   " camera alone (R the identity, Tx 0): its K and D with the stereo extrinsics in force, both "
                   "cameras rectified again, in " + where;
  return result;
}

std::string StereoCalibration::markVerified(uint32_t epoch, bool* marked) {
  if (marked) *marked = false;
  std::lock_guard<std::mutex> write_lock(write_mutex_);  // no commit replaces the generation meanwhile
  const InForce in_force = inForce();
  if (in_force.epoch != epoch || in_force.generation == 0) return "";
  for (const auto& existing : store_.generations()) {
    if (existing.number != in_force.generation) continue;
    if (existing.verified) return "";
    try {
      store_.markVerified(existing.number, "verified GOOD by the calibration health");
    } catch (const std::exception& e) {
      return e.what();
    }
    if (marked) *marked = true;
    return "";
  }
  return "";
}

std::optional<StereoCalibration::Verified> StereoCalibration::newestVerified() const {
  for (const auto& g : store_.generations()) {
    Verified verified;
    if (!g.verified || !readGeneration(g, &verified.left, &verified.right).empty()) continue;
    verified.generation = g.number;
    return verified;
  }
  return std::nullopt;
}

std::string StereoCalibration::discardStagedLocked(const std::string& why) {
  std::string text;
  std::lock_guard<std::mutex> lock(state_mutex_);
  for (auto* staged : {&staged_left_, &staged_right_}) {
    if (!*staged) continue;
    text += std::string(text.empty() ? "" : "; ") + "staged " + sideName(staged == &staged_left_) +
            " calibration discarded: " + why;
    staged->reset();
  }
  if (!text.empty()) problem_ = text;
  return text;
}

std::string StereoCalibration::expireStaged() {
  // Called by the capture thread every frame: never wait for a commit writing to disk (a
  // staged calibration expires a frame later instead).
  std::unique_lock<std::mutex> write_lock(write_mutex_, std::try_to_lock);
  if (!write_lock.owns_lock()) return "";
  std::string text;
  const auto now = Clock::now();
  std::lock_guard<std::mutex> lock(state_mutex_);
  for (auto* staged : {&staged_left_, &staged_right_}) {
    if (!*staged || (*staged)->monocular || now - (*staged)->since < pair_timeout_) continue;
    const bool left = staged == &staged_left_;
    char seconds[32];
    std::snprintf(seconds, sizeof(seconds), "%.1f", pair_timeout_.count());
    text += std::string(text.empty() ? "" : "; ") + "staged " + sideName(left) +
            " calibration discarded: no " + sideName(!left) + "/set_camera_info with a matching P within " + seconds +
            " s (pair_timeout_s); the calibration in force is unchanged";
    staged->reset();
  }
  if (!text.empty()) problem_ = text;
  return text;
}

std::string StereoCalibration::commitLocked(sensor_msgs::CameraInfo left, sensor_msgs::CameraInfo right,
                                            uint32_t calls, std::string* where) {
  alignRectifiedPair(left, &right);  // image_geometry compares fx', fy', cy' exactly
  unsigned generation = 0;
  try {
    generation = store_.commit(left, right, [this](const CalibrationPairStore::Generation& g) {
      sensor_msgs::CameraInfo l, r;
      return readGeneration(g, &l, &r).empty();
    });
  } catch (const std::exception& e) {
    return e.what();
  }
  *where = "'" + store_.leftPath() + "' and '" + store_.rightPath() + "' (generation " + std::to_string(generation) +
           ")";
  std::lock_guard<std::mutex> lock(state_mutex_);
  in_force_.left = left;
  in_force_.right = right;
  in_force_.epoch += calls;
  in_force_.generation = generation;
  problem_.clear();
  source_ = "set_camera_info, stored in " + *where;
  return "";
}

StereoCalibration::SetResult StereoCalibration::set(bool left, const sensor_msgs::CameraInfo& info) {
  std::lock_guard<std::mutex> write_lock(write_mutex_);
  SetResult result;
  const std::string name = std::string(sideName(left)) + "/set_camera_info";
  const std::string other_name = std::string(sideName(!left)) + "/set_camera_info";
  const std::string other_in_force_name = std::string("the ") + sideName(!left) + " calibration in force";
  const std::string problem = checkOne(left, info, name);
  if (!problem.empty()) {
    result.message = "rejected: " + problem;
    result.discarded = discardStagedLocked("the " + name + " that followed it was rejected");
    return result;
  }
  std::optional<Staged>& own = left ? staged_left_ : staged_right_;
  std::optional<Staged>& other = left ? staged_right_ : staged_left_;
  const auto pairWith = [&](const sensor_msgs::CameraInfo& o, const std::string& o_name) {
    return left ? checkRectifiedPair(info, name, o, o_name) : checkRectifiedPair(o, o_name, info, name);
  };
  sensor_msgs::CameraInfo own_in_force, other_in_force;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    own_in_force = left ? in_force_.left : in_force_.right;
    other_in_force = left ? in_force_.right : in_force_.left;
  }

  // With the staged other camera (both calls are committed), else with the other camera in
  // force, but only when this call keeps its camera's rectification: a new R or P (even cx' or
  // Tx alone, which still "match") is half of a new rectified pair and waits for the other half.
  std::optional<sensor_msgs::CameraInfo> partner;
  uint32_t calls = 1;
  std::string mismatch;
  if (other && pairWith(other->info, "the staged " + other_name).empty()) {
    partner = other->info;
    calls = 2;
  } else {
    mismatch = pairWith(other_in_force, other_in_force_name);
    if (mismatch.empty() && !keepsRectification(info, own_in_force))
      mismatch = name + " changes R or P, the rectification shared by both cameras";
    if (mismatch.empty()) partner = other_in_force;
  }
  if (!partner) {
    const bool monocular = isMonocular(info, own_in_force);
    std::lock_guard<std::mutex> lock(state_mutex_);
    own = Staged{info, Clock::now(), monocular};
    char seconds[32];
    std::snprintf(seconds, sizeof(seconds), "%.1f", pair_timeout_.count());
    result.success = true;
    result.message = stagedAnswer(mismatch + "; waiting up to " + seconds + " s for " + other_name +
                                  " with a matching P, the calibration in force is unchanged until then" +
                                  (monocular ? "; without one, it is taken as a calibration of this camera alone (R "
                                               "the identity, Tx 0): its K and D with the stereo extrinsics in force"
                                             : ""));
    return result;
  }
  std::string where;
  const std::string error =
      left ? commitLocked(info, *partner, calls, &where) : commitLocked(*partner, info, calls, &where);
  if (!error.empty()) {
    result.message = "not stored: " + error;
    result.discarded = discardStagedLocked("the pair could not be stored");
    setProblem("calibration not stored: " + error);
    return result;
  }
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    own.reset();
    if (calls == 2) other.reset();
  }
  result.success = true;
  result.message = std::string(calls == 2 ? "stored with the staged " + std::string(sideName(!left)) + " calibration"
                                          : "stored") +
                   " in " + where;
  return result;
}

StereoCalibration::InForce StereoCalibration::inForce() const {
  std::lock_guard<std::mutex> lock(state_mutex_);
  return in_force_;
}

std::string StereoCalibration::problem() const {
  std::lock_guard<std::mutex> lock(state_mutex_);
  return problem_;
}

std::string StereoCalibration::source() const {
  std::lock_guard<std::mutex> lock(state_mutex_);
  return source_;
}

std::string StereoCalibration::stagedText() const {
  std::lock_guard<std::mutex> lock(state_mutex_);
  std::string text;
  const auto now = Clock::now();
  for (const auto* staged : {&staged_left_, &staged_right_}) {
    if (!*staged) continue;
    char age[48];
    std::snprintf(age, sizeof(age), " (%.1f s)", std::chrono::duration<double>(now - (*staged)->since).count());
    text += std::string(text.empty() ? "" : ", ") + sideName(staged == &staged_left_) + age;
  }
  return text;
}

}  // namespace embedded_calibration_stereo
