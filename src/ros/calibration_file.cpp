#include "embedded_calibration_stereo/ros/calibration_file.h"

#include "embedded_calibration_stereo/core/geometry/atomic_file.h"

#include <camera_calibration_parsers/parse.h>
#include <camera_calibration_parsers/parse_ini.h>
#include <camera_calibration_parsers/parse_yml.h>
#include <fcntl.h>
#include <ros/package.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <vector>

namespace embedded_calibration_stereo {
namespace {

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

bool startsWithNoCase(const std::string& s, const std::string& prefix) {
  return s.size() >= prefix.size() && lower(s.substr(0, prefix.size())) == prefix;
}

std::string rosHome() {
  if (const char* home = std::getenv("ROS_HOME")) return home;
  if (const char* home = std::getenv("HOME")) return std::string(home) + "/.ros";
  return ".ros";
}

// One pass over ${...} variables, like camera_info_manager::resolveURL.
std::string substituteVariables(const std::string& url, const std::string& camera_name) {
  std::string out;
  size_t pos = 0;
  while (pos < url.size()) {
    const size_t start = url.find("${", pos);
    if (start == std::string::npos) break;
    const size_t end = url.find('}', start);
    if (end == std::string::npos) break;
    out += url.substr(pos, start - pos);
    const std::string name = url.substr(start + 2, end - start - 2);
    if (name == "NAME") {
      out += camera_name;
    } else if (name == "ROS_HOME") {
      out += rosHome();
    } else {
      out += url.substr(start, end - start + 1);  // unknown: kept literally
    }
    pos = end + 1;
  }
  return out + url.substr(pos);
}

std::string errnoText(const std::string& what) { return what + ": " + std::strerror(errno); }

std::string directoryOf(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

// mkdir -p; returns false with errno set on failure.
bool makeDirectories(const std::string& dir) {
  struct stat st;
  if (stat(dir.c_str(), &st) == 0) {
    if (S_ISDIR(st.st_mode)) return true;
    errno = ENOTDIR;
    return false;
  }
  const std::string parent = directoryOf(dir);
  if (parent != dir && !makeDirectories(parent)) return false;
  return mkdir(dir.c_str(), 0755) == 0 || errno == EEXIST;
}

}  // namespace

bool resolveCalibrationUrl(const std::string& url, const std::string& camera_name,
                           std::string* path, std::string* error) {
  const std::string resolved =
      substituteVariables(url.empty() ? "file://${ROS_HOME}/camera_info/${NAME}.yaml" : url,
                          camera_name);
  if (startsWithNoCase(resolved, "file://")) {
    *path = resolved.substr(7);
    if (path->empty() || (*path)[0] != '/') {
      if (error) *error = "file:// URL needs an absolute path: '" + url + "'";
      return false;
    }
    return true;
  }
  if (startsWithNoCase(resolved, "package://")) {
    const std::string rest = resolved.substr(10);
    const size_t slash = rest.find('/');
    const std::string package = rest.substr(0, slash);
    const std::string root = package.empty() ? "" : ros::package::getPath(package);
    if (slash == std::string::npos || root.empty()) {
      if (error) *error = "unknown package in URL '" + url + "'";
      return false;
    }
    *path = root + rest.substr(slash);
    return true;
  }
  if (error) *error = "unsupported camera_info URL '" + url + "' (use file:// or package://)";
  return false;
}

bool writeCalibrationFileAtomic(const std::string& path, const std::string& camera_name,
                                const sensor_msgs::CameraInfo& info, std::string* error) {
  auto fail = [error](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  std::ostringstream text;
  const bool ini = path.size() > 4 && lower(path.substr(path.size() - 4)) == ".ini";
  const bool serialised = ini ? camera_calibration_parsers::writeCalibrationIni(text, camera_name, info)
                              : camera_calibration_parsers::writeCalibrationYml(text, camera_name, info);
  if (!serialised) return fail("could not serialise the calibration of '" + camera_name + "'");

  const std::string dir = directoryOf(path);
  if (!makeDirectories(dir)) return fail(errnoText("cannot create directory '" + dir + "'"));
  try {
    ecs::writeFileAtomically(path, text.str());
  } catch (const std::exception& e) {
    return fail(e.what());
  }
  return true;
}

bool readCalibrationFile(const std::string& path, std::string* camera_name,
                         sensor_msgs::CameraInfo* info, std::string* error) {
  if (access(path.c_str(), R_OK) != 0) {
    if (error) *error = errnoText("cannot read '" + path + "'");
    return false;
  }
  std::string name;
  sensor_msgs::CameraInfo parsed;
  if (!camera_calibration_parsers::readCalibration(path, name, parsed)) {
    if (error) *error = "cannot parse calibration file '" + path + "'";
    return false;
  }
  if (camera_name) *camera_name = name;
  *info = parsed;
  return true;
}

}  // namespace embedded_calibration_stereo
