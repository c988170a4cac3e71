// Atomicity of writeFileAtomically: the target is replaced by a rename of a complete temporary
// file, never rewritten in place. What tells the two apart from outside: a descriptor or a hard
// link held on the old file still reads the old content afterwards (rename swaps the directory
// entry; an in-place write changes the inode they share), the target is a new inode, a reader
// never sees a partial file, no temporary file is left, and a write that fails leaves the old
// file as it was and says why.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "embedded_calibration_stereo/core/io/atomic_file.h"

namespace embedded_calibration_stereo::core {
namespace {

namespace fs = std::filesystem;

// A fresh directory per test, removed at the end.
struct TempDir {
  fs::path path;
  explicit TempDir(const std::string& name)
      : path(fs::temp_directory_path() / (name + "_" + std::to_string(::getpid()))) {
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
  std::vector<std::string> entries() const {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(path)) names.push_back(e.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
  }
};

std::string readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// Everything a descriptor opened earlier reads from the start of its file.
std::string readDescriptor(int fd) {
  std::string out;
  char buffer[4096];
  off_t offset = 0;
  for (;;) {
    const ssize_t n = ::pread(fd, buffer, sizeof buffer, offset);
    if (n <= 0) break;
    out.append(buffer, static_cast<size_t>(n));
    offset += n;
  }
  return out;
}

ino_t inode(const fs::path& path) {
  struct stat st {};
  EXPECT_EQ(::stat(path.c_str(), &st), 0) << path;
  return st.st_ino;
}

TEST(AtomicFile, ReplacesTheDirectoryEntryAndNeverRewritesTheOldFile) {
  const TempDir dir("ecs_atomic_replace");
  const fs::path target = dir.path / "calibration.yaml";
  const std::string old_content = "old calibration, longer than the new one\n";
  writeFileAtomically(target.string(), old_content);
  ASSERT_EQ(readFile(target), old_content);

  // Hold the old file by a descriptor and by a hard link before replacing it.
  const int old_fd = ::open(target.c_str(), O_RDONLY);
  ASSERT_GE(old_fd, 0);
  const fs::path link = dir.path / "held_link";
  fs::create_hard_link(target, link);
  const ino_t old_inode = inode(target);

  writeFileAtomically(target.string(), "new\n");
  EXPECT_EQ(readFile(target), "new\n");
  EXPECT_NE(inode(target), old_inode) << "the target was rewritten in place, not replaced";
  EXPECT_EQ(readDescriptor(old_fd), old_content) << "a reader of the old file saw it change";
  EXPECT_EQ(readFile(link), old_content) << "the old inode was modified";
  ::close(old_fd);

  // Only the target and the link: no temporary file left behind.
  EXPECT_EQ(dir.entries(), (std::vector<std::string>{"calibration.yaml", "held_link"}));
  // 0666 minus the umask, like any other output (the temporary file starts at 0600).
  const mode_t mask = ::umask(0);
  ::umask(mask);
  EXPECT_EQ(fs::status(target).permissions(),
            static_cast<fs::perms>(0666 & ~mask) & fs::perms::all);
}

TEST(AtomicFile, AConcurrentReaderSeesTheOldOrTheNewFileWholeNeverAMix) {
  const TempDir dir("ecs_atomic_reader");
  const fs::path target = dir.path / "prior.yaml";
  // Two contents of different lengths and letters: a partial or mixed read shows.
  const std::string a(300000, 'a'), b(200000, 'b');
  writeFileAtomically(target.string(), a);
  std::atomic<bool> done{false};
  std::atomic<int> reads{0}, torn{0};
  std::thread reader([&] {
    while (!done) {
      const std::string seen = readFile(target);
      ++reads;
      if (seen != a && seen != b) ++torn;
    }
  });
  for (int i = 0; i < 100; ++i) writeFileAtomically(target.string(), i % 2 ? a : b);
  // At least a few reads overlap the writes (the reader runs while they go on).
  while (reads < 20) std::this_thread::yield();
  done = true;
  reader.join();
  EXPECT_EQ(torn, 0) << "of " << reads << " reads";
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"prior.yaml"});
}

// A write that fails part way (the file size limit, the same failure as a full disk, and one
// root cannot bypass) leaves the old file untouched, no temporary file, and a reason.
TEST(AtomicFile, AFailedWriteLeavesTheOldFileIntactAndSaysWhy) {
  const TempDir dir("ecs_atomic_failure");
  const fs::path target = dir.path / "left.yaml";
  const std::string old_content = "old\n";
  writeFileAtomically(target.string(), old_content);
  const ino_t old_inode = inode(target);

  struct rlimit saved {};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &saved), 0);
  struct rlimit limited = saved;
  limited.rlim_cur = 1024;
  // Past the limit write() fails with EFBIG instead of raising SIGXFSZ.
  const auto previous = ::signal(SIGXFSZ, SIG_IGN);
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &limited), 0);
  std::string error;
  try {
    writeFileAtomically(target.string(), std::string(4096, 'x'));
  } catch (const std::runtime_error& e) {
    error = e.what();
  }
  ::setrlimit(RLIMIT_FSIZE, &saved);
  ::signal(SIGXFSZ, previous);

  EXPECT_FALSE(error.empty()) << "a failed write must throw";
  EXPECT_NE(error.find(target.string()), std::string::npos) << error;
  EXPECT_NE(error.find(std::strerror(EFBIG)), std::string::npos) << error;
  EXPECT_EQ(readFile(target), old_content);
  EXPECT_EQ(inode(target), old_inode);
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"left.yaml"}) << "temporary file left behind";
}

// The rename itself fails (the target is a directory): that directory stays, the temporary
// file goes, and the error names both.
TEST(AtomicFile, AFailedRenameLeavesTheTargetAndNoTemporaryFile) {
  const TempDir dir("ecs_atomic_rename");
  const fs::path target = dir.path / "out";
  fs::create_directories(target / "kept");
  std::string error;
  try {
    writeFileAtomically(target.string(), "content");
  } catch (const std::runtime_error& e) {
    error = e.what();
  }
  EXPECT_NE(error.find("cannot rename"), std::string::npos) << error;
  EXPECT_NE(error.find("'" + target.string() + "'"), std::string::npos) << error;
  EXPECT_TRUE(fs::is_directory(target / "kept"));
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"out"}) << "temporary file left behind";
}

TEST(AtomicFile, AMissingDirectoryIsReportedByPath) {
  const TempDir dir("ecs_atomic_missing");
  const fs::path target = dir.path / "missing" / "right.yaml";
  std::string error;
  try {
    writeFileAtomically(target.string(), "x");
  } catch (const std::runtime_error& e) {
    error = e.what();
  }
  EXPECT_NE(error.find(target.string()), std::string::npos) << error;
  EXPECT_NE(error.find(std::strerror(ENOENT)), std::string::npos) << error;
  EXPECT_FALSE(fs::exists(dir.path / "missing"));
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
