// The track_pattern tool on real photographs, as a new user would try it: real chessboard photos
// (OpenCV's calibration samples, 9x6 inner corners, installed by Debian's opencv-doc package)
// blended onto real scene photos (scikit-image's sample photographs, Debian's python3-skimage):
//   I = (1 - r) * scene + r * board,   r = 0.6, 0.4, 0.25.
// For each board photo: `track_pattern teach --board 9x6` on the clean photo, then
// `track_pattern track` (no background) on every composite. Reference: the corners OpenCV finds on
// the clean photo (findChessboardCornersSB, then cornerSubPix), ordered by the tool's documented
// rule for a plain board (corner 0 the outer corner nearest the image's top-left, corner 1 along
// the more horizontal grid direction). The composites are written to a temporary folder at test
// time; no photograph is copied into the repository.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/test_support/run_command.h"
#include "embedded_calibration_stereo/test_support/real_photos.h"

namespace core = embedded_calibration_stereo::core;

namespace {

using core::runCommand;

const std::string kBoardDir = embedded_calibration_stereo::test_support::kBoardPhotoDir;
const std::string kSceneDir = embedded_calibration_stereo::test_support::kScenePhotoDir;
const cv::Size kGrid(9, 6);
constexpr double kWrongIdPx = 1.0;  // a slipped square is ~25 px off in these photos

struct Score {
  int reference = 0, reported = 0, matched = 0, wrong = 0;
  double sum_sq = 0.0;
  void add(const Score& o) {
    reference += o.reference, reported += o.reported, matched += o.matched, wrong += o.wrong;
    sum_sq += o.sum_sq;
  }
  double found() const { return reference ? static_cast<double>(matched) / reference : 0.0; }
  double rms() const { return matched ? std::sqrt(sum_sq / matched) : 0.0; }
};

std::string tempDir() {
  char tmpl[] = "/tmp/ecs_track_photos_XXXXXX";
  const char* dir = ::mkdtemp(tmpl);
  return dir ? std::string(dir) + "/" : std::string();
}

// OpenCV's corners on the clean photo in the tool's documented order for a plain board.
bool referenceCorners(const cv::Mat& gray, std::vector<cv::Point2f>* out) {
  std::vector<cv::Point2f> c;
  if (!embedded_calibration_stereo::test_support::openCvChessboardCorners(gray, kGrid, &c)) return false;
  // The four orderings of a 9x6 grid (reverse columns, reverse rows).
  double best = 1e30;
  for (int sym = 0; sym < 4; ++sym) {
    std::vector<cv::Point2f> o(c.size());
    for (int id = 0; id < kGrid.area(); ++id) {
      int col = id % kGrid.width, row = id / kGrid.width;
      if (sym & 1) col = kGrid.width - 1 - col;
      if (sym & 2) row = kGrid.height - 1 - row;
      o[id] = c[row * kGrid.width + col];
    }
    const cv::Point2f along_row = o[1] - o[0], along_col = o[kGrid.width] - o[0];
    const double key = o[0].x + o[0].y + (std::abs(along_row.x) >= std::abs(along_col.x) ? 0.0 : 1e6);
    if (key < best) best = key, *out = o;
  }
  return best < 1e30;
}

// The corners of "board_id,corner_id,u,v" lines of board 0 by id (NaN where missing).
std::vector<cv::Point2f> parse(const std::string& csv, int count) {
  std::vector<cv::Point2f> out(count, cv::Point2f(NAN, NAN));
  std::istringstream in(csv);
  std::string line;
  while (std::getline(in, line)) {
    int board = -1, id = -1;
    double u = 0, v = 0;
    if (std::sscanf(line.c_str(), "%d,%d,%lf,%lf", &board, &id, &u, &v) == 4 && board == 0 && id >= 0 && id < count)
      out[id] = cv::Point2f(static_cast<float>(u), static_cast<float>(v));
  }
  return out;
}

// Parses "board_id,corner_id,u,v" lines and scores them against the reference (corners with a NaN
// reference are not counted).
Score score(const std::string& csv, const std::vector<cv::Point2f>& reference) {
  Score s;
  for (const cv::Point2f& p : reference) s.reference += std::isfinite(p.x);
  std::istringstream in(csv);
  std::string line;
  while (std::getline(in, line)) {
    int board = -1, id = -1;
    double u = 0, v = 0;
    if (std::sscanf(line.c_str(), "%d,%d,%lf,%lf", &board, &id, &u, &v) != 4) continue;
    ++s.reported;
    if (board != 0 || id < 0 || id >= static_cast<int>(reference.size())) {
      ++s.wrong;
      continue;
    }
    if (!std::isfinite(reference[id].x)) continue;
    const double e = std::hypot(u - reference[id].x, v - reference[id].y);
    if (e > kWrongIdPx) {
      ++s.wrong;
      continue;
    }
    ++s.matched;
    s.sum_sq += e * e;
  }
  return s;
}

TEST(TrackPatternPhotos, RealChessboardOnRealScenes) {
  const std::string dir = tempDir();
  ASSERT_FALSE(dir.empty()) << "cannot create a temporary folder";
  const std::string tool = ECS_TRACK_PATTERN;
  const std::vector<std::string> photos = {"left01", "left04", "left07", "left12", "right03", "right08"};
  const std::vector<std::string> scenes = {"brick", "grass", "gravel", "coffee", "astronaut"};
  const double ratios[] = {0.6, 0.4, 0.25};
  // Per r: against the tracker's corners on the clean photo (what the scene costs), and against
  // OpenCV's corners on the clean photo (an independent detector).
  std::map<double, Score> per_ratio, per_ratio_cv;
  Score clean_total;
  std::printf("  %-8s %-10s %5s  %9s %12s %14s %6s\n", "photo", "scene", "r", "found", "RMS vs clean", "RMS vs OpenCV",
              "wrong");
  for (const std::string& photo : photos) {
    const std::string board_path = kBoardDir + photo + ".jpg";
    const cv::Mat board = cv::imread(board_path, cv::IMREAD_GRAYSCALE);
    ASSERT_FALSE(board.empty()) << "cannot read " << board_path << " (Debian package opencv-doc; scripts/setup installs it)";
    std::vector<cv::Point2f> opencv;
    ASSERT_TRUE(referenceCorners(board, &opencv)) << "OpenCV finds no 9x6 board in " << board_path;
    const std::string prior = dir + photo + ".yaml";
    std::string out;
    ASSERT_EQ(runCommand(tool + " teach --board 9x6 --image " + board_path + " --out " + prior + " 2>/dev/null", &out), 0)
        << "track_pattern teach failed on " << board_path;
    ASSERT_EQ(runCommand(tool + " track --prior " + prior + " --image " + board_path + " 2>/dev/null", &out), 0);
    const Score clean = score(out, opencv);
    clean_total.add(clean);
    const std::vector<cv::Point2f> tracked_clean = parse(out, kGrid.area());
    std::printf("  %-8s %-10s %5s  %4d/%-4d %12s %14.3f %6d\n", photo.c_str(), "(clean)", "", clean.matched,
                clean.reference, "", clean.rms(), clean.wrong);
    for (const std::string& name : scenes) {
      const cv::Mat background = embedded_calibration_stereo::test_support::scenePhoto(name, board.size());
      ASSERT_FALSE(background.empty()) << "cannot read " << kSceneDir << name
                                       << ".png (Debian package python3-skimage; scripts/setup installs it)";
      for (double r : ratios) {
        cv::Mat composite;
        cv::addWeighted(background, 1.0 - r, board, r, 0.0, composite);
        const std::string path = dir + photo + "_" + name + "_" + std::to_string(r) + ".png";
        ASSERT_TRUE(cv::imwrite(path, composite));
        const int status = runCommand(tool + " track --prior " + prior + " --image " + path + " 2>/dev/null", &out);
        EXPECT_TRUE(status == 0 || status == 1) << "track_pattern track failed on " << path;
        const Score s = score(out, tracked_clean), s_cv = score(out, opencv);
        per_ratio[r].add(s);
        per_ratio_cv[r].add(s_cv);
        std::printf("  %-8s %-10s %5.2f  %4d/%-4d %12.3f %14.3f %6d\n", photo.c_str(), name.c_str(), r, s_cv.matched,
                    s_cv.reference, s.rms(), s_cv.rms(), s_cv.wrong);
        std::remove(path.c_str());
      }
    }
    std::remove(prior.c_str());
  }
  ::rmdir(dir.c_str());
  std::printf("  clean photos against OpenCV: found %.2f %%, RMS %.3f px, wrong ids %d\n", 100 * clean_total.found(),
              clean_total.rms(), clean_total.wrong);
  for (double r : ratios) {
    const Score& s = per_ratio[r];
    const Score& c = per_ratio_cv[r];
    std::printf("  r = %.2f: found %d/%d (%.2f %%), wrong ids %d, RMS %.3f px against the clean photo's corners, "
                "%.3f px against OpenCV's\n",
                r, c.matched, c.reference, 100 * c.found(), c.wrong, s.rms(), c.rms());
    EXPECT_GE(c.found(), 0.99) << "r = " << r;
    EXPECT_LE(s.rms(), 0.1) << "r = " << r;
    // OpenCV's corners carry its own error and the photos' departures from a smooth board model:
    // a looser bound that still catches a tracker that drifts from an independent detector.
    EXPECT_LE(c.rms(), 0.12) << "r = " << r;
    EXPECT_EQ(c.wrong, 0) << "r = " << r;
    EXPECT_EQ(s.wrong, 0) << "r = " << r;
  }
}

}  // namespace
