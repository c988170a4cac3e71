// The driver's calibration pair on disk (CalibrationPairStore) and in force (StereoCalibration),
// without a ROS master:
//  - a commit killed (SIGKILL, through the store's test hook) after each of its steps leaves
//    the two URL files showing both the old or both the new pair, read back with
//    camera_calibration_parsers as any reader would, from regular files, from no files and
//    from an existing store;
//  - generations kept: the current one and the previous valid one;
//  - start-up: corrupt, half-present or inconsistent files fall back to the newest valid
//    generation (or the nominal pair) with a problem naming the file;
//  - set(): refusals persist nothing, a P that does not match the other camera is staged and
//    committed with the other camera's matching set (epoch + 2), or discarded after the timeout.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <thread>

#include "embedded_calibration_stereo/rectified_pair.h"
#include "embedded_calibration_stereo/ros/calibration_file.h"
#include "embedded_calibration_stereo/ros/camera_calibration.h"
#include "embedded_calibration_stereo/ros/conversions.h"
#include "embedded_calibration_stereo/ros/stereo_input_check.h"
#include "embedded_calibration_stereo/temp_dir.h"

namespace core = embedded_calibration_stereo::core;

using namespace embedded_calibration_stereo;
using sensor_msgs::CameraInfo;

namespace {

constexpr uint32_t kWidth = test_support::kPairWidth, kHeight = test_support::kPairHeight;
constexpr int kCommitSteps = 9;  // calibration_file.h: the test hook's steps

// A fresh folder per test.
struct TempDir : test_support::TempDir {
  TempDir() : test_support::TempDir("ecs_pair_store") {}
};

using test_support::pairWithFocal;

std::string fileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// What a reader of the two URL files sees: fx' of each ("missing" as -1, broken as -2).
std::pair<double, double> shownFocals(const std::string& left_path, const std::string& right_path) {
  double focal[2];
  const std::string paths[2] = {left_path, right_path};
  for (int i = 0; i < 2; ++i) {
    CameraInfo info;
    std::string error;
    const CalibrationFileState state = readCalibrationFileIfPresent(paths[i], &info, &error);
    focal[i] = state == CalibrationFileState::kMissing  ? -1.0
               : state == CalibrationFileState::kBroken ? -2.0
                                                        : info.P[0];
  }
  return {focal[0], focal[1]};
}

void writeRegular(const std::string& path, const CameraInfo& info) {
  std::string error;
  ASSERT_TRUE(writeCalibrationFileAtomic(path, "cam", info, &error)) << error;
}

// Runs store.commit(pair) in a child process with the test hook at `step`; returns how the
// child ended: the signal, or 0 when it exited normally.
int commitInChild(CalibrationPairStore& store, const std::pair<CameraInfo, CameraInfo>& pair, int step) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::setenv("ECS_TEST_CRASH_COMMIT_AT", std::to_string(step).c_str(), 1);
    try {
      store.commit(pair.first, pair.second, nullptr);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "commit failed: %s\n", e.what());
      ::_exit(3);
    }
    ::_exit(0);
  }
  int status = 0;
  EXPECT_EQ(::waitpid(pid, &status, 0), pid);
  if (WIFSIGNALED(status)) return WTERMSIG(status);
  EXPECT_EQ(WEXITSTATUS(status), 0) << "the commit failed in the child";
  return 0;
}

enum class Start { kRegularFiles, kNoFiles, kStore };

// Kills a commit after each step from `start`, checks what the URL files show, then lets
// a commit finish from that state (the relaunch's next commit).
void killAtEveryStep(Start start) {
  const auto old_pair = pairWithFocal(600.0), new_pair = pairWithFocal(640.0), later = pairWithFocal(660.0);
  for (int step = 1; step <= kCommitSteps + 1; ++step) {
    SCOPED_TRACE("crash after step " + std::to_string(step));
    TempDir dir;
    const std::string left = dir.path + "/cal/stereo_left.yaml", right = dir.path + "/cal/stereo_right.yaml";
    CalibrationPairStore store(left, right, "stereo_left", "stereo_right");
    double old_focal = 600.0;
    if (start == Start::kRegularFiles) {
      writeRegular(left, old_pair.first);
      writeRegular(right, old_pair.second);
    } else if (start == Start::kStore) {
      store.commit(old_pair.first, old_pair.second, nullptr);
    } else {
      old_focal = -1.0;  // missing
    }
    ASSERT_EQ(shownFocals(left, right), std::make_pair(old_focal, old_focal));

    const int signal = commitInChild(store, new_pair, step);
    EXPECT_EQ(signal, step <= kCommitSteps ? SIGKILL : 0);
    const auto shown = shownFocals(left, right);
    const bool old_both = shown == std::make_pair(old_focal, old_focal);
    const bool new_both = shown == std::make_pair(640.0, 640.0);
    EXPECT_TRUE(old_both || new_both) << "the files show fx' " << shown.first << " and " << shown.second;
    // The new pair is in force exactly from the rename of `current` (step 8) on.
    EXPECT_EQ(new_both, step >= 8);

    // The next commit works from whatever the crash left.
    store.commit(later.first, later.second, nullptr);
    EXPECT_EQ(shownFocals(left, right), std::make_pair(660.0, 660.0));
  }
}

}  // namespace

TEST(CalibrationPairStore, KilledCommitFromRegularFilesLeavesAConsistentPair) { killAtEveryStep(Start::kRegularFiles); }
TEST(CalibrationPairStore, KilledCommitFromNoFilesLeavesAConsistentPair) { killAtEveryStep(Start::kNoFiles); }
TEST(CalibrationPairStore, KilledCommitFromAStoreLeavesAConsistentPair) { killAtEveryStep(Start::kStore); }

// The layout the documentation describes: links into `current`, the previous generation kept,
// older ones deleted; a user restores the previous one by pointing `current` at it.
TEST(CalibrationPairStore, KeepsTheCurrentAndThePreviousGeneration) {
  TempDir dir;
  const std::string left = dir.path + "/stereo_left.yaml", right = dir.path + "/other/stereo_right.yaml";
  CalibrationPairStore store(left, right, "stereo_left", "stereo_right");
  EXPECT_EQ(store.directory(), dir.path + "/.stereo_left+stereo_right.generations");
  const auto all_valid = [](const CalibrationPairStore::Generation&) { return true; };
  for (const double fx : {600.0, 610.0, 620.0, 630.0})
    store.commit(pairWithFocal(fx).first, pairWithFocal(fx).second, all_valid);
  const auto generations = store.generations();
  ASSERT_EQ(generations.size(), 2u);
  EXPECT_EQ(store.currentGeneration(), generations[0].number);
  EXPECT_EQ(shownFocals(generations[1].left_file, generations[1].right_file), std::make_pair(620.0, 620.0));
  EXPECT_EQ(shownFocals(left, right), std::make_pair(630.0, 630.0));
  EXPECT_EQ(std::filesystem::read_symlink(left).string(), ".stereo_left+stereo_right.generations/current/left.yaml");
  EXPECT_EQ(std::filesystem::read_symlink(right).string(), store.directory() + "/current/right.yaml");
  // What docs/calibration_files.md tells a user: point `current` at the previous generation.
  std::filesystem::remove(store.directory() + "/current");
  std::filesystem::create_directory_symlink(std::filesystem::path(generations[1].directory).filename(),
                                            store.directory() + "/current");
  EXPECT_EQ(shownFocals(left, right), std::make_pair(620.0, 620.0));
}

// A generation that is not a valid pair does not count as the previous calibration: the newest
// valid one older than it is kept too.
TEST(CalibrationPairStore, KeepsTheNewestValidGenerationWhenThePreviousIsBroken) {
  TempDir dir;
  const std::string left = dir.path + "/l.yaml", right = dir.path + "/r.yaml";
  CalibrationPairStore store(left, right, "l", "r");
  const auto valid = [](const CalibrationPairStore::Generation& g) {
    CameraInfo info;
    std::string error;
    return readCalibrationFile(g.right_file, nullptr, &info, &error);
  };
  store.commit(pairWithFocal(600).first, pairWithFocal(600).second, valid);
  store.commit(pairWithFocal(610).first, pairWithFocal(610).second, valid);
  const unsigned good = store.currentGeneration();
  store.commit(pairWithFocal(620).first, pairWithFocal(620).second, valid);
  { std::ofstream(store.generations()[0].right_file) << "camera_matrix: [truncated"; }
  store.commit(pairWithFocal(630).first, pairWithFocal(630).second, valid);
  std::vector<unsigned> numbers;
  for (const auto& g : store.generations()) numbers.push_back(g.number);
  EXPECT_EQ(numbers, (std::vector<unsigned>{good + 2, good + 1, good}));
}

namespace {

StereoCalibration makeCalibration(const std::string& dir, double pair_timeout_s = 10.0) {
  return StereoCalibration({"stereo_left", "file://" + dir + "/stereo_left.yaml", "left_camera_info_url"},
                           {"stereo_right", "file://" + dir + "/stereo_right.yaml", "right_camera_info_url"}, kWidth,
                           kHeight, pair_timeout_s);
}

const std::pair<CameraInfo, CameraInfo> kNominal = pairWithFocal(500.0);

double inForceFocal(const StereoCalibration& c, bool left) {
  const auto f = c.inForce();
  return (left ? f.left : f.right).P[0];
}

}  // namespace

TEST(StereoCalibrationLoad, NoFilesRunsOnTheNominalPairWithoutAProblem) {
  TempDir dir;
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  EXPECT_EQ(c.problem(), "");
  EXPECT_EQ(inForceFocal(c, true), 500.0);
}

TEST(StereoCalibrationLoad, CorruptCurrentFileFallsBackToThePreviousGeneration) {
  TempDir dir;
  {
    StereoCalibration c = makeCalibration(dir.path);
    c.load(kNominal.first, kNominal.second);
    for (const double fx : {600.0, 640.0}) {
      ASSERT_TRUE(c.set(true, pairWithFocal(fx).first).success);
      ASSERT_TRUE(c.set(false, pairWithFocal(fx).second).success);
    }
    EXPECT_EQ(c.inForce().epoch, 4u) << "two pairs, each staged left + matching right";
  }
  const std::string right_file = dir.path + "/stereo_right.yaml";
  const std::string text = fileBytes(right_file);
  { std::ofstream(right_file, std::ios::trunc) << text.substr(0, text.size() / 3); }  // truncated, through the link
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  EXPECT_EQ(inForceFocal(c, true), 600.0);
  EXPECT_EQ(inForceFocal(c, false), 600.0);
  EXPECT_NE(c.problem().find("right_camera_info_url"), std::string::npos) << c.problem();
  EXPECT_NE(c.problem().find("generation"), std::string::npos) << c.problem();
  std::printf("  problem: %s\n", c.problem().c_str());
}

// What camera_calibration's mono calibrator leaves when it rewrites one camera's file: a P of
// its own. The pair is inconsistent: the previous generation runs.
TEST(StereoCalibrationLoad, OneCameraRecalibratedFallsBackToThePreviousGeneration) {
  TempDir dir;
  {
    StereoCalibration c = makeCalibration(dir.path);
    c.load(kNominal.first, kNominal.second);
    ASSERT_TRUE(c.set(true, pairWithFocal(600).first).success);
    ASSERT_TRUE(c.set(false, pairWithFocal(600).second).success);
  }
  // The left file rewritten in place through its link, as camera_info_manager writes it.
  std::string error;
  ASSERT_TRUE(writeCalibrationFileAtomic(dir.path + "/mono.yaml", "stereo_left", pairWithFocal(612.0).first, &error))
      << error;
  { std::ofstream(dir.path + "/stereo_left.yaml", std::ios::trunc) << fileBytes(dir.path + "/mono.yaml"); }
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  EXPECT_NE(c.problem().find("fx'"), std::string::npos) << c.problem();
  // The only generation is the one written over: nothing valid is left but the nominal pair.
  EXPECT_EQ(inForceFocal(c, true), 500.0);
  EXPECT_EQ(inForceFocal(c, false), 500.0);
}

// A calibration verified GOOD is marked on disk, kept through later commits, and is what runs
// when the files are rejected at start-up (here a principal point far off the image, written
// through the link), not the newer unverified generations.
TEST(StereoCalibrationLoad, ARejectedFileFallsBackToTheNewestVerifiedGeneration) {
  TempDir dir;
  {
    StereoCalibration c = makeCalibration(dir.path);
    c.load(kNominal.first, kNominal.second);
    bool marked = true;
    EXPECT_EQ(c.markVerified(0, &marked), "");
    EXPECT_FALSE(marked) << "the nominal pair in memory is no generation";
    for (const double fx : {600.0, 610.0, 620.0, 630.0}) {
      ASSERT_TRUE(c.set(true, pairWithFocal(fx).first).success);
      ASSERT_TRUE(c.set(false, pairWithFocal(fx).second).success);
      if (fx != 600.0) continue;
      EXPECT_EQ(c.markVerified(c.inForce().epoch + 1, &marked), "");
      EXPECT_FALSE(marked) << "an epoch not in force";
      EXPECT_EQ(c.markVerified(c.inForce().epoch, &marked), "");
      EXPECT_TRUE(marked);
      EXPECT_EQ(c.markVerified(c.inForce().epoch, &marked), "");
      EXPECT_FALSE(marked) << "marked once";
    }
    const auto verified = c.newestVerified();
    ASSERT_TRUE(verified) << "the verified generation must survive three later commits";
    EXPECT_EQ(verified->left.P[0], 600.0);
  }
  CameraInfo far = pairWithFocal(630).first;
  far.P[6] += 100000;
  std::string error;
  ASSERT_TRUE(writeCalibrationFileAtomic(dir.path + "/far.yaml", "stereo_left", far, &error)) << error;
  { std::ofstream(dir.path + "/stereo_left.yaml", std::ios::trunc) << fileBytes(dir.path + "/far.yaml"); }
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  EXPECT_NE(c.problem().find("P[6]"), std::string::npos) << c.problem();
  EXPECT_NE(c.problem().find("verified GOOD"), std::string::npos) << c.problem();
  EXPECT_EQ(inForceFocal(c, true), 600.0) << "the newer valid generations (610, 620) were never verified";
  EXPECT_EQ(inForceFocal(c, false), 600.0);
  std::printf("  problem: %s\n", c.problem().c_str());
}

TEST(StereoCalibrationLoad, CorruptFilesWithoutAStoreRunOnTheNominalPair) {
  TempDir dir;
  { std::ofstream(dir.path + "/stereo_left.yaml") << "\x01\x02 not yaml {{{"; }
  writeRegular(dir.path + "/stereo_right.yaml", pairWithFocal(600).second);
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  EXPECT_NE(c.problem().find("left_camera_info_url"), std::string::npos) << c.problem();
  EXPECT_NE(c.problem().find("nominal"), std::string::npos) << c.problem();
  EXPECT_EQ(inForceFocal(c, false), 500.0) << "never half of a pair";
}

TEST(StereoCalibrationLoad, OneFileMissingIsHalfACalibration) {
  TempDir dir;
  writeRegular(dir.path + "/stereo_right.yaml", pairWithFocal(600).second);
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  EXPECT_NE(c.problem().find("missing"), std::string::npos) << c.problem();
  EXPECT_EQ(inForceFocal(c, false), 500.0);
}

TEST(StereoCalibrationLoad, ValidRegularFilesAreUsed) {
  TempDir dir;
  writeRegular(dir.path + "/stereo_left.yaml", pairWithFocal(600).first);
  writeRegular(dir.path + "/stereo_right.yaml", pairWithFocal(600).second);
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  EXPECT_EQ(c.problem(), "");
  EXPECT_EQ(inForceFocal(c, true), 600.0);
}

TEST(StereoCalibrationSet, RefusalsPersistNothing) {
  TempDir dir;
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  ASSERT_TRUE(c.set(true, kNominal.first).success);  // stores the nominal pair
  const std::string left_bytes = fileBytes(dir.path + "/stereo_left.yaml");
  const std::string right_bytes = fileBytes(dir.path + "/stereo_right.yaml");
  ASSERT_FALSE(left_bytes.empty());
  const uint32_t epoch = c.inForce().epoch;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const struct {
    const char* name;
    std::function<void(CameraInfo&)> mutate;
    const char* needle;
  } cases[] = {
      {"NaN skew", [&](CameraInfo& i) { i.K[1] = nan; }, "K[1]"},
      {"NaN in R", [&](CameraInfo& i) { i.R[3] = nan; }, "R[3]"},
      {"NaN in P", [&](CameraInfo& i) { i.P[6] = nan; }, "P[6]"},
      {"all-zero P", [](CameraInfo& i) { i.P.fill(0); }, "P is all zero"},
      {"wrong size", [](CameraInfo& i) { i.width = 640; }, "differs from the image's 752x480"},
      {"binning 1000", [](CameraInfo& i) { i.binning_x = i.binning_y = 1000; }, "binning"},
      {"not plumb_bob",
       [](CameraInfo& i) {
         i.distortion_model = "rational_polynomial";
         i.D.resize(8, 0.0);
       },
       "plumb_bob"},
  };
  for (const auto& k : cases) {
    for (const bool left : {true, false}) {
      CameraInfo info = left ? kNominal.first : kNominal.second;
      k.mutate(info);
      const auto result = c.set(left, info);
      EXPECT_FALSE(result.success) << k.name;
      EXPECT_NE(result.message.find(k.needle), std::string::npos) << k.name << ": " << result.message;
      EXPECT_NE(result.message.find(left ? "left/set_camera_info" : "right/set_camera_info"), std::string::npos)
          << result.message;
    }
  }
  EXPECT_EQ(fileBytes(dir.path + "/stereo_left.yaml"), left_bytes);
  EXPECT_EQ(fileBytes(dir.path + "/stereo_right.yaml"), right_bytes);
  EXPECT_EQ(c.inForce().epoch, epoch);
  EXPECT_EQ(inForceFocal(c, true), 500.0);
}

TEST(StereoCalibrationSet, MismatchedPIsStagedUntilTheOtherCameraMatches) {
  TempDir dir;
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  const auto next = pairWithFocal(640.0);
  // One camera recalibrated alone: its P does not match the other camera's in force.
  auto result = c.set(true, next.first);
  EXPECT_TRUE(result.success);
  EXPECT_EQ(result.message.rfind("staged:", 0), 0u) << result.message;
  EXPECT_NE(result.message.find("fx'"), std::string::npos) << result.message;
  EXPECT_EQ(inForceFocal(c, true), 500.0) << "nothing in force changes while staged";
  EXPECT_EQ(c.inForce().epoch, 0u);
  EXPECT_NE(c.stagedText().find("left"), std::string::npos);
  struct stat st;
  EXPECT_NE(::stat((dir.path + "/stereo_left.yaml").c_str(), &st), 0) << "nothing written while staged";
  // The matching right camera: both committed together.
  result = c.set(false, next.second);
  EXPECT_TRUE(result.success) << result.message;
  EXPECT_EQ(c.inForce().epoch, 2u);
  EXPECT_EQ(inForceFocal(c, true), 640.0);
  EXPECT_EQ(inForceFocal(c, false), 640.0);
  EXPECT_EQ(shownFocals(dir.path + "/stereo_left.yaml", dir.path + "/stereo_right.yaml"), std::make_pair(640.0, 640.0));
  EXPECT_EQ(c.stagedText(), "");
  // A change that keeps P (k1 only) is committed at once.
  CameraInfo k1 = next.first;
  k1.D[0] = -0.05;
  result = c.set(true, k1);
  EXPECT_TRUE(result.success);
  EXPECT_EQ(result.message.rfind("stored", 0), 0u) << result.message;
  EXPECT_EQ(c.inForce().epoch, 3u);
  EXPECT_EQ(c.inForce().left.D[0], -0.05);
}

TEST(StereoCalibrationSet, StagedCalibrationIsDiscardedAfterTheTimeout) {
  TempDir dir;
  StereoCalibration c = makeCalibration(dir.path, 0.2);
  c.load(kNominal.first, kNominal.second);
  ASSERT_TRUE(c.set(false, pairWithFocal(640.0).second).success);
  ASSERT_NE(c.stagedText(), "");
  EXPECT_EQ(c.expireStaged(), "") << "not yet";
  std::string discarded;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (discarded.empty() && std::chrono::steady_clock::now() < deadline) discarded = c.expireStaged();
  EXPECT_NE(discarded.find("staged right calibration discarded"), std::string::npos) << discarded;
  EXPECT_EQ(c.problem(), discarded);
  EXPECT_EQ(c.stagedText(), "");
  // The left camera's matching P now finds nothing staged: it is staged in turn.
  EXPECT_EQ(c.set(true, pairWithFocal(640.0).first).message.rfind("staged:", 0), 0u);
  EXPECT_EQ(inForceFocal(c, false), 500.0);
}

TEST(StereoCalibrationSet, RefusedSetDiscardsTheStagedOne) {
  TempDir dir;
  StereoCalibration c = makeCalibration(dir.path);
  c.load(kNominal.first, kNominal.second);
  ASSERT_TRUE(c.set(true, pairWithFocal(640.0).first).success);
  CameraInfo bad = pairWithFocal(640.0).second;
  bad.R[0] = std::numeric_limits<double>::quiet_NaN();
  const auto result = c.set(false, bad);
  EXPECT_FALSE(result.success);
  EXPECT_NE(result.discarded.find("staged left calibration discarded"), std::string::npos) << result.discarded;
  EXPECT_EQ(c.stagedText(), "");
  EXPECT_EQ(inForceFocal(c, true), 500.0);
}

TEST(StereoCalibrationSet, UnwritableFolderRefusesAndKeepsTheCalibration) {
  TempDir dir;
  { std::ofstream(dir.path + "/plain_file") << "not a directory"; }
  StereoCalibration c({"stereo_left", "file://" + dir.path + "/stereo_left.yaml", "left_camera_info_url"},
                      {"stereo_right", "file://" + dir.path + "/plain_file/stereo_right.yaml", "right_camera_info_url"},
                      kWidth, kHeight, 10.0);
  c.load(kNominal.first, kNominal.second);
  CameraInfo k1 = kNominal.first;
  k1.D[0] = -0.05;
  const auto result = c.set(true, k1);
  EXPECT_FALSE(result.success);
  EXPECT_NE(result.message.find("plain_file"), std::string::npos) << result.message;
  EXPECT_EQ(c.inForce().epoch, 0u);
  EXPECT_EQ(c.inForce().left.D[0], kNominal.first.D[0]);
  EXPECT_EQ(shownFocals(dir.path + "/stereo_left.yaml", dir.path + "/plain_file/stereo_right.yaml"),
            std::make_pair(-1.0, -1.0))
      << "the left file must not appear alone";
}

// A rig of two 650 px cameras with radial distortion `k1`, the right one turned by 0.5 degrees
// about y and 0.3 about x, 0.12 m apart: its rectification has an R of its own.
core::StereoRig turnedRig(double k1) {
  core::StereoRig rig;
  for (core::PinholeCamera* c : {&rig.left, &rig.right}) {
    c->width = kWidth;
    c->height = kHeight;
    c->fx = c->fy = 650.0;
    c->cx = 376.0;
    c->cy = 240.0;
    c->dist = {{k1, k1 == 0.0 ? 0.0 : 0.07, 0.0, 0.0, 0.0}};
  }
  rig.right_from_left.linear() = (Eigen::AngleAxisd(0.5 * M_PI / 180, Eigen::Vector3d::UnitY()) *
                                  Eigen::AngleAxisd(0.3 * M_PI / 180, Eigen::Vector3d::UnitX()))
                                     .toRotationMatrix();
  rig.right_from_left.translation() = Eigen::Vector3d(-0.12, 0.001, -0.0005);
  return rig;
}

// camera_calibration's monocular calibrator on one camera of the head sends that camera's K and
// D with R the identity and Tx 0. Staged like any call (the first half of a stereo calibration of
// an aligned rig looks the same), it is put in force, once no other call completes it within the
// pair timeout, with the stereo extrinsics it had (both cameras rectified again): never answered
// success and dropped.
TEST(StereoCalibrationSet, AMonocularCalibrationKeepsTheStereoExtrinsics) {
  TempDir dir;
  const core::StereoRig rig = turnedRig(-0.25);
  const auto in_force = toStereoCameraInfo(rig);
  constexpr double kPairTimeoutS = 0.05;
  StereoCalibration c = makeCalibration(dir.path, kPairTimeoutS);
  c.load(in_force.first, in_force.second);

  CameraInfo mono = in_force.first;  // the left camera calibrated alone
  mono.K = {658.0, 0.0, 379.5, 0.0, 657.0, 236.0, 0.0, 0.0, 1.0};
  mono.D = {-0.26, 0.08, 0.0005, -0.0003, 0.0};
  mono.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  mono.P = {640.0, 0.0, 380.0, 0.0, 0.0, 640.0, 237.0, 0.0, 0.0, 0.0, 1.0, 0.0};
  const StereoCalibration::SetResult staged = c.set(true, mono);
  ASSERT_TRUE(staged.success) << staged.message;
  EXPECT_EQ(staged.message.rfind("staged:", 0), 0u) << staged.message;
  EXPECT_NE(staged.message.find("this camera alone"), std::string::npos) << staged.message;
  EXPECT_TRUE(c.applyStagedMonocular().empty()) << "before the pair timeout";
  std::this_thread::sleep_for(std::chrono::duration<double>(2 * kPairTimeoutS));  // the timeout itself
  EXPECT_EQ(c.expireStaged(), "") << "the capture thread's expiry leaves it to applyStagedMonocular";
  const auto results = c.applyStagedMonocular();
  ASSERT_EQ(results.size(), 1u);
  ASSERT_TRUE(results[0].success) << results[0].message;
  EXPECT_NE(results[0].message.find("left camera alone"), std::string::npos) << results[0].message;

  const StereoCalibration::InForce now = c.inForce();
  EXPECT_EQ(now.left.K, mono.K);
  EXPECT_EQ(now.left.D, mono.D);
  EXPECT_EQ(now.right.K, in_force.second.K) << "the right camera's intrinsics stay";
  EXPECT_EQ(now.right.D, in_force.second.D);
  EXPECT_EQ(checkRectifiedPair(now.left, "l", now.right, "r"), "");
  // The extrinsics of the new pair, by the rectification's definition: p_right = R2^T (R1 p_left
  // + t), t = (Tx / fx', 0, 0).
  using Matrix3 = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;
  const Matrix3 R1(now.left.R.data()), R2(now.right.R.data());
  const Eigen::Matrix3d rotation = R2.transpose() * R1;
  const Eigen::Vector3d translation = R2.transpose() * Eigen::Vector3d(now.right.P[3] / now.right.P[0], 0.0, 0.0);
  EXPECT_LT(Eigen::AngleAxisd(rotation * rig.right_from_left.linear().transpose()).angle(), 1e-9);
  EXPECT_LT((translation - rig.right_from_left.translation()).norm(), 1e-9);
}

// The first half of a stereo calibration of an aligned rig looks monocular: its other half,
// arriving in time, makes the pair.
TEST(StereoCalibrationSet, AnAlignedStereoPairIsAPairNotTwoMonocularCalibrations) {
  TempDir dir;
  const auto in_force = toStereoCameraInfo(turnedRig(0.0));
  StereoCalibration c = makeCalibration(dir.path);
  c.load(in_force.first, in_force.second);
  const auto aligned = pairWithFocal(600.0);  // no rotation: R the identity, left Tx 0
  ASSERT_TRUE(c.set(true, aligned.first).success);
  const StereoCalibration::SetResult result = c.set(false, aligned.second);
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_NE(result.message.find("stored with the staged left"), std::string::npos) << result.message;
  EXPECT_EQ(inForceFocal(c, true), 600.0);
  EXPECT_EQ(inForceFocal(c, false), 600.0);
}
