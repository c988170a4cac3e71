// Head and mover trajectories of the simulated world: pure functions of the scene time.
#include "embedded_calibration_stereo/core/sim/trajectory.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <initializer_list>
#include <cstdio>

namespace embedded_calibration_stereo::core {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDegToRad = kPi / 180.0;
// Limits: a simulation of a robot head or a hand-held one, not arbitrary motion.
constexpr double kMaxSpeed = 20.0;           // m/s
constexpr double kMaxYawRateDegS = 180.0;    // deg/s
constexpr double kMaxVibrationM = 0.2;       // m
constexpr double kMaxVibrationDeg = 10.0;    // deg
constexpr double kMaxHandheldM = 2.0;        // m
constexpr double kMaxHandheldDeg = 45.0;     // deg
constexpr double kMinPeriod = 0.01, kMaxPeriod = 3600.0;  // s

Eigen::Matrix3d axisRotation(int axis, double angle_rad) {
  return Eigen::AngleAxisd(angle_rad, Eigen::Vector3d::Unit(axis)).toRotationMatrix();
}

// t reduced to [0, loop) (unchanged without a loop).
double wrap(double t, double loop) { return loop > 0 ? t - std::floor(t / loop) * loop : t; }

// Heading (rad) of the drive at path time s.
double driveHeading(const SimTrajectory& c, double s) {
  const double amplitude = c.yaw_rate_amplitude_deg_s * kDegToRad * c.yaw_period_s / (2 * kPi);
  return amplitude * std::sin(2 * kPi * s / c.yaw_period_s);
}

// Position after driving for path time s: integral of speed * (sin h, 0, cos h), composite
// 4-point Gauss-Legendre on steps of at most 50 ms (the heading is smooth on that scale).
Eigen::Vector3d drivePosition(const SimTrajectory& c, double s) {
  if (s == 0.0 || c.speed_m_s == 0.0) return Eigen::Vector3d::Zero();
  const int steps = std::max(1, static_cast<int>(std::ceil(std::abs(s) / 0.05)));
  const double h = s / steps;
  const double nodes[4] = {-0.8611363115940526, -0.3399810435848563, 0.3399810435848563, 0.8611363115940526};
  const double weights[4] = {0.3478548451374538, 0.6521451548625461, 0.6521451548625461, 0.3478548451374538};
  double x = 0, z = 0;
  for (int i = 0; i < steps; ++i) {
    const double mid = (i + 0.5) * h;
    for (int k = 0; k < 4; ++k) {
      const double heading = driveHeading(c, mid + 0.5 * h * nodes[k]);
      x += weights[k] * std::sin(heading);
      z += weights[k] * std::cos(heading);
    }
  }
  return Eigen::Vector3d(x, 0.0, z) * (0.5 * h * c.speed_m_s);
}

// Deterministic vibration of unit amplitude: two incommensurate sinusoids, zero at t = 0.
double vibration(double t, double period, double phase) {
  const double w = 2 * kPi / period;
  return 0.7 * (std::sin(w * t + phase) - std::sin(phase)) +
         0.3 * (std::sin(2.17 * w * t + 2 * phase) - std::sin(2 * phase));
}

// Hand-held offset along one axis, zero at t = 0, |value| <= 2 * amplitude.
double handheldOffset(double t, double amplitude, double period, double phase) {
  if (amplitude == 0.0) return 0.0;
  const double w = 2 * kPi / period;
  return amplitude * (0.8 * (std::sin(w * t + phase) - std::sin(phase)) +
                      0.2 * (std::sin(3 * w * t + 2 * phase) - std::sin(2 * phase)));
}

Eigen::Isometry3d drivePose(const SimTrajectory& c, double t) {
  double s = t;
  if (c.loop_s > 0) {
    const double u = wrap(t, c.loop_s);
    s = u <= 0.5 * c.loop_s ? u : c.loop_s - u;  // forward, then back along the same path
  }
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  const double pitch = c.pitch_amplitude_deg * kDegToRad * vibration(t, c.bump_period_s, 0.9);
  const double roll = c.roll_amplitude_deg * kDegToRad * vibration(t, c.bump_period_s, 2.1);
  pose.linear() = axisRotation(1, driveHeading(c, s)) * axisRotation(0, pitch) * axisRotation(2, roll);
  pose.translation() = drivePosition(c, s) +
                       Eigen::Vector3d(0.0, c.bump_amplitude_m * vibration(t, c.bump_period_s, 0.0), 0.0);
  return pose;
}

Eigen::Isometry3d handheldPose(const SimTrajectory& c, double t) {
  const double phases[6] = {0.0, 2.1, 4.2, 1.0, 3.1, 5.2};
  Eigen::Vector3d translation, rotation;
  for (int i = 0; i < 3; ++i) {
    translation[i] = handheldOffset(t, c.translation_amplitude_m[i], c.translation_period_s[i], phases[i]);
    rotation[i] = handheldOffset(t, c.rotation_amplitude_deg[i] * kDegToRad, c.rotation_period_s[i], phases[3 + i]);
  }
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  const double angle = rotation.norm();
  if (angle > 0) pose.linear() = Eigen::AngleAxisd(angle, rotation / angle).toRotationMatrix();
  pose.translation() = translation;
  return pose;
}

Eigen::Isometry3d waypointPose(const SimTrajectory& c, double t) {
  const std::vector<SimWaypoint>& w = c.waypoints;
  if (w.empty()) return Eigen::Isometry3d::Identity();
  if (t <= w.front().t_s) return w.front().pose;
  if (t >= w.back().t_s) return w.back().pose;
  const size_t i = static_cast<size_t>(
      std::upper_bound(w.begin(), w.end(), t, [](double v, const SimWaypoint& p) { return v < p.t_s; }) -
      w.begin() - 1);
  const double a = (t - w[i].t_s) / (w[i + 1].t_s - w[i].t_s);
  const Eigen::Vector3d p1 = w[i].pose.translation(), p2 = w[i + 1].pose.translation();
  Eigen::Vector3d p;
  if (c.spline) {
    // Catmull-Rom through the waypoints; the end segments repeat their end point.
    const Eigen::Vector3d p0 = i > 0 ? Eigen::Vector3d(w[i - 1].pose.translation()) : p1;
    const Eigen::Vector3d p3 = i + 2 < w.size() ? Eigen::Vector3d(w[i + 2].pose.translation()) : p2;
    const double a2 = a * a, a3 = a2 * a;
    p = 0.5 * (2 * p1 + (p2 - p0) * a + (2 * p0 - 5 * p1 + 4 * p2 - p3) * a2 + (3 * p1 - p0 - 3 * p2 + p3) * a3);
  } else {
    p = (1 - a) * p1 + a * p2;
  }
  const Eigen::Quaterniond q1(w[i].pose.linear()), q2(w[i + 1].pose.linear());
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = q1.slerp(a, q2).toRotationMatrix();
  pose.translation() = p;
  return pose;
}

bool finite(const Eigen::Isometry3d& pose) { return pose.matrix().allFinite(); }

std::string number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%g", v);
  return buf;
}

ConfigProblem checkRange(const std::string& key, double value, double lo, double hi, const char* unit) {
  if (std::isfinite(value) && value >= lo && value <= hi) return {};
  return {key, "must be in [" + number(lo) + ", " + number(hi) + "] " + unit + ", got " + number(value)};
}

ConfigProblem checkPeriod(const std::string& key, double value) {
  if (std::isfinite(value) && value >= kMinPeriod && value <= kMaxPeriod) return {};
  return {key, "must be in [" + number(kMinPeriod) + ", " + number(kMaxPeriod) + "] s, got " + number(value)};
}

// The first problem of a list of checks (each evaluated only when the ones before it pass).
ConfigProblem firstOf(std::initializer_list<std::function<ConfigProblem()>> checks) {
  for (const auto& check : checks) {
    ConfigProblem p = check();
    if (!p.ok()) return p;
  }
  return {};
}

ConfigProblem driveProblem(const SimTrajectory& t) {
  return firstOf({[&] { return checkRange("speed_m_s", t.speed_m_s, -kMaxSpeed, kMaxSpeed, "m/s"); },
                  [&] {
                    return checkRange("yaw_rate_amplitude_deg_s", t.yaw_rate_amplitude_deg_s, 0, kMaxYawRateDegS,
                                      "deg/s");
                  },
                  [&] { return checkPeriod("yaw_period_s", t.yaw_period_s); },
                  [&] { return checkRange("bump_amplitude_m", t.bump_amplitude_m, 0, kMaxVibrationM, "m"); },
                  [&] { return checkRange("pitch_amplitude_deg", t.pitch_amplitude_deg, 0, kMaxVibrationDeg, "deg"); },
                  [&] { return checkRange("roll_amplitude_deg", t.roll_amplitude_deg, 0, kMaxVibrationDeg, "deg"); },
                  [&] { return checkPeriod("bump_period_s", t.bump_period_s); }});
}

ConfigProblem handheldProblem(const SimTrajectory& t) {
  for (int i = 0; i < 3; ++i) {
    const std::string axis = "[" + std::to_string(i) + "]";
    ConfigProblem p = firstOf(
        {[&] { return checkRange("translation_amplitude_m" + axis, t.translation_amplitude_m[i], 0, kMaxHandheldM, "m"); },
         [&] { return checkRange("rotation_amplitude_deg" + axis, t.rotation_amplitude_deg[i], 0, kMaxHandheldDeg, "deg"); },
         [&] { return checkPeriod("translation_period_s" + axis, t.translation_period_s[i]); },
         [&] { return checkPeriod("rotation_period_s" + axis, t.rotation_period_s[i]); }});
    if (!p.ok()) return p;
  }
  return {};
}

ConfigProblem waypointsProblem(const SimTrajectory& t) {
  if (t.waypoints.empty()) return {"waypoints", "must list at least one {t_s, rotation_deg, translation_m}"};
  for (size_t i = 0; i < t.waypoints.size(); ++i) {
    const std::string key = "waypoints[" + std::to_string(i) + "]";
    if (!std::isfinite(t.waypoints[i].t_s)) return {key + ".t_s", "must be finite"};
    if (i > 0 && !(t.waypoints[i].t_s > t.waypoints[i - 1].t_s))
      return {key + ".t_s", "must be later than the previous waypoint's"};
    if (!finite(t.waypoints[i].pose)) return {key, "pose must be finite"};
  }
  if (t.loop_s > 0 && t.loop_s < t.waypoints.back().t_s)
    return {"loop_s", "must be >= the last waypoint's t_s (or 0 = no loop)"};
  return {};
}

}  // namespace

const char* trajectoryKindName(SimTrajectory::Kind kind) {
  switch (kind) {
    case SimTrajectory::Kind::kStatic: return "static";
    case SimTrajectory::Kind::kDrive: return "drive";
    case SimTrajectory::Kind::kHandheld: return "handheld";
    case SimTrajectory::Kind::kWaypoints: return "waypoints";
  }
  return "?";
}

std::string SimTrajectory::validate() const {
  const ConfigProblem p = problem();
  return p.ok() ? std::string() : p.parameter + ": " + p.problem;
}

ConfigProblem SimTrajectory::problem() const {
  if (!finite(start) || !start.linear().isUnitary(1e-6)) return {"start", "must be a finite rigid pose"};
  if (!(std::isfinite(loop_s) && loop_s >= 0.0)) return {"loop_s", "must be >= 0 s (0 = no loop)"};
  switch (kind) {
    case Kind::kStatic: return {};
    case Kind::kDrive: return driveProblem(*this);
    case Kind::kHandheld: return handheldProblem(*this);
    case Kind::kWaypoints: return waypointsProblem(*this);
  }
  return {"kind", "unknown"};
}

Eigen::Isometry3d trajectoryPose(const SimTrajectory& c, double time_s) {
  Eigen::Isometry3d motion;
  switch (c.kind) {
    case SimTrajectory::Kind::kStatic:
      return c.start;
    case SimTrajectory::Kind::kDrive:
      motion = drivePose(c, time_s);
      break;
    case SimTrajectory::Kind::kHandheld:
      motion = handheldPose(c, wrap(time_s, c.loop_s));
      break;
    case SimTrajectory::Kind::kWaypoints:
      motion = waypointPose(c, wrap(time_s, c.loop_s));
      break;
  }
  return c.start * motion;
}

}  // namespace embedded_calibration_stereo::core
