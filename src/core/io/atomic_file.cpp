#include "embedded_calibration_stereo/core/io/atomic_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace embedded_calibration_stereo::core {

namespace {

std::string systemError(const std::string& what) { return what + ": " + std::strerror(errno); }

}  // namespace

void writeFileAtomically(const std::string& path, const std::string& content) {
  // Same directory as the target: rename() is atomic only within one file system.
  std::string temp = path + ".tmp.XXXXXX";
  const int fd = ::mkstemp(temp.data());
  if (fd < 0)
    throw std::runtime_error(systemError("cannot create a temporary file for '" + path + "'"));
  size_t written = 0;
  while (written < content.size()) {
    const ssize_t n = ::write(fd, content.data() + written, content.size() - written);
    if (n < 0) {
      if (errno == EINTR) continue;
      const std::string reason = systemError("cannot write '" + temp + "'");
      ::close(fd);
      ::unlink(temp.c_str());
      throw std::runtime_error(reason);
    }
    written += static_cast<size_t>(n);
  }
  // mkstemp creates 0600; a calibration file is meant to be shared like any other output.
  const mode_t mask = ::umask(0);
  ::umask(mask);
  ::fchmod(fd, 0666 & ~mask);
  const bool synced = ::fsync(fd) == 0;
  if (::close(fd) != 0 || !synced) {
    const std::string reason = systemError("cannot flush '" + temp + "'");
    ::unlink(temp.c_str());
    throw std::runtime_error(reason);
  }
  if (::rename(temp.c_str(), path.c_str()) != 0) {
    const std::string reason = systemError("cannot rename '" + temp + "' to '" + path + "'");
    ::unlink(temp.c_str());
    throw std::runtime_error(reason);
  }
  // Persist the directory entry too; a failure here cannot be undone, the file is complete.
  const size_t slash = path.find_last_of('/');
  const std::string dir = slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash));
  const int dir_fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (dir_fd >= 0) {
    ::fsync(dir_fd);
    ::close(dir_fd);
  }
}

}  // namespace embedded_calibration_stereo::core
