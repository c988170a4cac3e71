#include "embedded_calibration_stereo/ros/calibration_file.h"

#include "embedded_calibration_stereo/core/io/atomic_file.h"

#include <camera_calibration_parsers/parse.h>
#include <camera_calibration_parsers/parse_ini.h>
#include <camera_calibration_parsers/parse_yml.h>
#include <dirent.h>
#include <fcntl.h>
#include <ros/package.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>
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

void makeDirectoriesOrThrow(const std::string& dir) {
  if (!makeDirectories(dir)) throw std::runtime_error(errnoText("cannot create directory '" + dir + "'"));
}

std::string baseName(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

// ".yaml" of "stereo_left.yaml"; ".yaml" when the name has no extension.
std::string extensionOf(const std::string& path) {
  const std::string name = baseName(path);
  const size_t dot = name.find_last_of('.');
  return dot == std::string::npos || dot == 0 ? ".yaml" : name.substr(dot);
}

std::string stemOf(const std::string& path) {
  const std::string name = baseName(path);
  const size_t dot = name.find_last_of('.');
  return dot == std::string::npos || dot == 0 ? name : name.substr(0, dot);
}

// Persists a directory entry (a rename, a new link) across a power loss; a SIGKILL alone
// cannot lose it. Best effort: the entry itself is already in place.
void syncDirectory(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd >= 0) {
    ::fsync(fd);
    ::close(fd);
  }
}

// Replaces `path` (whatever it is, or nothing) by a symbolic link to `target` in one rename.
void replaceWithSymlink(const std::string& path, const std::string& target) {
  static std::atomic<unsigned> counter{0};
  const std::string temp = path + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(counter++);
  ::unlink(temp.c_str());
  if (::symlink(target.c_str(), temp.c_str()) != 0)
    throw std::runtime_error(errnoText("cannot create the link '" + temp + "'"));
  if (::rename(temp.c_str(), path.c_str()) != 0) {
    const std::string reason = errnoText("cannot rename '" + temp + "' to '" + path + "'");
    ::unlink(temp.c_str());
    throw std::runtime_error(reason);
  }
  syncDirectory(directoryOf(path));
}

bool readBytes(const std::string& path, std::string* bytes) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  std::ostringstream text;
  text << in.rdbuf();
  *bytes = text.str();
  return !in.bad();
}

std::string generationName(unsigned number) {
  char name[32];
  std::snprintf(name, sizeof(name), "g%06u", number);
  return name;
}

// The number of a generation folder name ("g000012" -> 12), 0 when it is none.
unsigned generationNumber(const std::string& name) {
  if (name.size() < 2 || name[0] != 'g') return 0;
  unsigned number = 0;
  for (size_t i = 1; i < name.size(); ++i) {
    if (name[i] < '0' || name[i] > '9' || number > 100000000u) return 0;
    number = number * 10 + static_cast<unsigned>(name[i] - '0');
  }
  return number;
}

// The test hook of CalibrationPairStore::commit (see calibration_file.h): SIGKILL after the
// `crash_at`-th step; inert when the environment variable is not set.
class CrashHook {
 public:
  CrashHook() {
    const char* at = std::getenv("ECS_TEST_CRASH_COMMIT_AT");
    crash_at_ = at ? std::atoi(at) : 0;
  }
  void stepDone() {
    if (++step_ == crash_at_) ::kill(::getpid(), SIGKILL);
  }

 private:
  int crash_at_ = 0;
  int step_ = 0;
};

void removeQuietly(const std::string& dir) {
  std::error_code ignored;
  std::filesystem::remove_all(dir, ignored);
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
    core::writeFileAtomically(path, text.str());
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
  bool parsed_ok = false;
  try {  // the parsers catch yaml-cpp's exceptions, but a broken file must never escape as one
    parsed_ok = camera_calibration_parsers::readCalibration(path, name, parsed);
  } catch (const std::exception&) {
    parsed_ok = false;
  }
  if (!parsed_ok) {
    if (error) *error = "cannot parse calibration file '" + path + "'";
    return false;
  }
  if (camera_name) *camera_name = name;
  *info = parsed;
  return true;
}

CalibrationFileState readCalibrationFileIfPresent(const std::string& path, sensor_msgs::CameraInfo* info,
                                                  std::string* error) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) {
    if (errno == ENOENT || errno == ENOTDIR) return CalibrationFileState::kMissing;
    if (error) *error = errnoText("cannot read '" + path + "'");
    return CalibrationFileState::kBroken;
  }
  if (S_ISDIR(st.st_mode)) {
    if (error) *error = "'" + path + "' is a directory";
    return CalibrationFileState::kBroken;
  }
  return readCalibrationFile(path, nullptr, info, error) ? CalibrationFileState::kLoaded
                                                         : CalibrationFileState::kBroken;
}

CalibrationPairStore::CalibrationPairStore(std::string left_path, std::string right_path,
                                           std::string left_camera_name, std::string right_camera_name)
    : left_path_(std::move(left_path)),
      right_path_(std::move(right_path)),
      left_camera_name_(std::move(left_camera_name)),
      right_camera_name_(std::move(right_camera_name)),
      directory_(directoryOf(left_path_) + "/." + stemOf(left_path_) + "+" + stemOf(right_path_) + ".generations"),
      left_extension_(extensionOf(left_path_)),
      right_extension_(extensionOf(right_path_)) {}

CalibrationPairStore::Generation CalibrationPairStore::generation(unsigned number) const {
  Generation g;
  g.number = number;
  g.directory = directory_ + "/" + generationName(number);
  g.left_file = g.directory + "/left" + left_extension_;
  g.right_file = g.directory + "/right" + right_extension_;
  g.verified_file = g.directory + "/verified";
  struct stat st;
  g.verified = ::stat(g.verified_file.c_str(), &st) == 0;
  return g;
}

std::vector<CalibrationPairStore::Generation> CalibrationPairStore::generations() const {
  std::vector<unsigned> numbers;
  if (DIR* dir = ::opendir(directory_.c_str())) {
    while (const dirent* entry = ::readdir(dir)) {
      const unsigned number = generationNumber(entry->d_name);
      struct stat st;
      const std::string path = directory_ + "/" + entry->d_name;
      if (number > 0 && ::lstat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode)) numbers.push_back(number);
    }
    ::closedir(dir);
  }
  std::sort(numbers.rbegin(), numbers.rend());
  std::vector<Generation> result;
  for (const unsigned n : numbers) result.push_back(generation(n));
  return result;
}

unsigned CalibrationPairStore::currentGeneration() const {
  char target[256];
  const ssize_t n = ::readlink((directory_ + "/current").c_str(), target, sizeof(target) - 1);
  if (n <= 0) return 0;
  target[n] = '\0';
  return generationNumber(target);
}

unsigned CalibrationPairStore::linkedGeneration() const {
  return isOurLink(true) && isOurLink(false) ? currentGeneration() : 0;
}

void CalibrationPairStore::markVerified(unsigned number, const std::string& note) const {
  core::writeFileAtomically(generation(number).verified_file, note + "\n");
}

std::string CalibrationPairStore::linkTarget(bool left) const {
  const std::string& url_file = left ? left_path_ : right_path_;
  const std::string file = std::string(left ? "left" : "right") + (left ? left_extension_ : right_extension_);
  // Relative when the URL file sits beside the store: the folder can then be moved or copied.
  if (directoryOf(url_file) == directoryOf(directory_)) return baseName(directory_) + "/current/" + file;
  return directory_ + "/current/" + file;
}

bool CalibrationPairStore::isOurLink(bool left) const {
  const std::string& path = left ? left_path_ : right_path_;
  std::vector<char> target(4096);
  const ssize_t n = ::readlink(path.c_str(), target.data(), target.size() - 1);
  return n > 0 && std::string(target.data(), static_cast<size_t>(n)) == linkTarget(left);
}

void CalibrationPairStore::makeCurrent(unsigned number) const {
  replaceWithSymlink(directory_ + "/current", generationName(number));
}

void CalibrationPairStore::linkUrlFile(bool left) const {
  const std::string& path = left ? left_path_ : right_path_;
  makeDirectoriesOrThrow(directoryOf(path));
  replaceWithSymlink(path, linkTarget(left));
}

void CalibrationPairStore::prune(unsigned newest, std::set<unsigned> keep,
                                 const std::function<bool(const Generation&)>& is_valid) const {
  const auto valid = [&](unsigned number) { return number > 0 && is_valid && is_valid(generation(number)); };
  const bool replaced_valid = std::any_of(keep.begin(), keep.end(), [&](unsigned n) { return n != newest && valid(n); });
  if (is_valid && !replaced_valid) {  // the previous calibration the driver falls back to
    for (const Generation& older : generations()) {
      if (older.number < newest && !keep.count(older.number) && is_valid(older)) {
        keep.insert(older.number);
        break;
      }
    }
  }
  for (const Generation& older : generations()) {  // the calibration a rollback goes back to
    if (older.number < newest && older.verified && (!is_valid || is_valid(older))) {
      keep.insert(older.number);
      break;
    }
  }
  for (const Generation& older : generations())
    if (!keep.count(older.number)) removeQuietly(older.directory);
  if (DIR* dir = ::opendir(directory_.c_str())) {
    std::vector<std::string> stale;
    while (const dirent* entry = ::readdir(dir))
      if (std::string(entry->d_name).rfind("current.tmp.", 0) == 0) stale.push_back(directory_ + "/" + entry->d_name);
    ::closedir(dir);
    for (const std::string& path : stale) ::unlink(path.c_str());
  }
}

unsigned CalibrationPairStore::commit(const sensor_msgs::CameraInfo& left, const sensor_msgs::CameraInfo& right,
                                      const std::function<bool(const Generation&)>& is_valid) {
  CrashHook hook;
  makeDirectoriesOrThrow(directory_);
  const std::vector<Generation> existing = generations();
  unsigned next = existing.empty() ? 1 : existing.front().number + 1;
  const unsigned old_current = currentGeneration();
  unsigned replaced = old_current;
  const auto newGeneration = [&](unsigned number) {
    const Generation g = generation(number);
    if (::mkdir(g.directory.c_str(), 0755) != 0)
      throw std::runtime_error(errnoText("cannot create directory '" + g.directory + "'"));
    return g;
  };

  // 1. URL files that are not yet our links become links, their content unchanged: a
  //    generation with exact copies of what they show is made current first.
  const bool left_linked = isOurLink(true), right_linked = isOurLink(false);
  if (left_linked && right_linked) {
    for (int i = 0; i < 5; ++i) hook.stepDone();
  } else {
    const Generation copy = newGeneration(next++);
    try {
      for (const bool is_left : {true, false}) {
        const std::string& url_file = is_left ? left_path_ : right_path_;
        struct stat st;
        if (::stat(url_file.c_str(), &st) == 0) {
          std::string bytes;
          if (!readBytes(url_file, &bytes)) throw std::runtime_error(errnoText("cannot read '" + url_file + "'"));
          core::writeFileAtomically(is_left ? copy.left_file : copy.right_file, bytes);
        } else if (errno != ENOENT && errno != ENOTDIR) {
          throw std::runtime_error(errnoText("cannot read '" + url_file + "'"));
        }
        hook.stepDone();
      }
    } catch (...) {
      removeQuietly(copy.directory);
      throw;
    }
    makeCurrent(copy.number);
    replaced = copy.number;
    hook.stepDone();
    if (!left_linked) linkUrlFile(true);
    hook.stepDone();
    if (!right_linked) linkUrlFile(false);
    hook.stepDone();
  }

  // 2. The new pair: a complete generation, then `current` moves to it in one rename.
  const Generation g = newGeneration(next);
  std::string error;
  if (!writeCalibrationFileAtomic(g.left_file, left_camera_name_, left, &error)) {
    removeQuietly(g.directory);
    throw std::runtime_error(error);
  }
  hook.stepDone();
  if (!writeCalibrationFileAtomic(g.right_file, right_camera_name_, right, &error)) {
    removeQuietly(g.directory);
    throw std::runtime_error(error);
  }
  hook.stepDone();
  makeCurrent(g.number);
  hook.stepDone();

  // 3. Keep the new generation, the ones it replaced, the newest verified valid one and, when
  //    neither of those it replaced is a valid pair (the driver fell back from a broken one), the
  //    newest valid one before them.
  //    Leftovers of crashed commits (unfinished generations, temporary links) go too.
  prune(g.number, {g.number, replaced, old_current}, is_valid);
  hook.stepDone();
  return g.number;
}

}  // namespace embedded_calibration_stereo
