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

namespace {

const std::string kBoardDir = "/usr/share/doc/opencv-doc/examples/data/";
const std::string kSceneDir = "/usr/lib/python3/dist-packages/skimage/data/";
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

// Runs a command; returns its exit status and its stdout.
int run(const std::string& command, std::string* out) {
  FILE* pipe = ::popen(command.c_str(), "r");
  if (!pipe) return -1;
  char buffer[4096];
  out->clear();
  size_t n;
  while ((n = std::fread(buffer, 1, sizeof(buffer), pipe)) > 0) out->append(buffer, n);
  const int status = ::pclose(pipe);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// OpenCV's corners on the clean photo in the tool's documented order for a plain board.
bool referenceCorners(const cv::Mat& gray, std::vector<cv::Point2f>* out) {
  std::vector<cv::Point2f> c;
  if (!cv::findChessboardCornersSB(gray, kGrid, c, cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE |
                                                       cv::CALIB_CB_ACCURACY))
    return false;
  cv::cornerSubPix(gray, c, cv::Size(5, 5), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 0.001));
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

// The scene photo as grey, scaled to cover `size` and centre-cropped.
cv::Mat scene(const std::string& name, cv::Size size) {
  const cv::Mat image = cv::imread(kSceneDir + name + ".png", cv::IMREAD_GRAYSCALE);
  if (image.empty()) return image;
  const double s = std::max(static_cast<double>(size.width) / image.cols, static_cast<double>(size.height) / image.rows);
  cv::Mat scaled;
  cv::resize(image, scaled, cv::Size(), s, s, s < 1 ? cv::INTER_AREA : cv::INTER_LINEAR);
  const cv::Rect crop((scaled.cols - size.width) / 2, (scaled.rows - size.height) / 2, size.width, size.height);
  return scaled(crop).clone();
}

// Parses "board_id,corner_id,u,v" lines and scores them against the reference.
Score score(const std::string& csv, const std::vector<cv::Point2f>& reference) {
  Score s;
  s.reference = static_cast<int>(reference.size());
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
  std::map<double, Score> per_ratio;
  Score clean_total;
  std::printf("  %-8s %-10s %5s  %9s %7s %6s\n", "photo", "scene", "r", "found", "RMS px", "wrong");
  for (const std::string& photo : photos) {
    const std::string board_path = kBoardDir + photo + ".jpg";
    const cv::Mat board = cv::imread(board_path, cv::IMREAD_GRAYSCALE);
    ASSERT_FALSE(board.empty()) << "cannot read " << board_path << " (Debian package opencv-doc; scripts/setup installs it)";
    std::vector<cv::Point2f> reference;
    ASSERT_TRUE(referenceCorners(board, &reference)) << "OpenCV finds no 9x6 board in " << board_path;
    const std::string prior = dir + photo + ".yaml";
    std::string out;
    ASSERT_EQ(run(tool + " teach --board 9x6 --image " + board_path + " --out " + prior + " 2>/dev/null", &out), 0)
        << "track_pattern teach failed on " << board_path;
    // The clean photo itself: the tracker's own agreement with OpenCV's corners.
    ASSERT_EQ(run(tool + " track --prior " + prior + " --image " + board_path + " 2>/dev/null", &out), 0);
    const Score clean = score(out, reference);
    if (std::getenv("ECS_DEV_DUMP")) {
      std::istringstream in(out);
      std::string line;
      while (std::getline(in, line)) {
        int b, id;
        double u, v;
        if (std::sscanf(line.c_str(), "%d,%d,%lf,%lf", &b, &id, &u, &v) == 4)
          std::printf("DUMP %s %d %.3f %.3f %.3f %.3f\n", photo.c_str(), id, reference[id].x, reference[id].y, u - reference[id].x, v - reference[id].y);
      }
    }
    clean_total.add(clean);
    std::printf("  %-8s %-10s %5.2f  %4d/%-4d %7.3f %6d\n", photo.c_str(), "(clean)", 1.0, clean.matched,
                clean.reference, clean.rms(), clean.wrong);
    for (const std::string& name : scenes) {
      const cv::Mat background = scene(name, board.size());
      ASSERT_FALSE(background.empty()) << "cannot read " << kSceneDir << name
                                       << ".png (Debian package python3-skimage; scripts/setup installs it)";
      for (double r : ratios) {
        cv::Mat composite;
        cv::addWeighted(background, 1.0 - r, board, r, 0.0, composite);
        const std::string path = dir + photo + "_" + name + "_" + std::to_string(r) + ".png";
        ASSERT_TRUE(cv::imwrite(path, composite));
        const int status = run(tool + " track --prior " + prior + " --image " + path + " 2>/dev/null", &out);
        EXPECT_TRUE(status == 0 || status == 1) << "track_pattern track failed on " << path;
        const Score s = score(out, reference);
        per_ratio[r].add(s);
        std::printf("  %-8s %-10s %5.2f  %4d/%-4d %7.3f %6d\n", photo.c_str(), name.c_str(), r, s.matched,
                    s.reference, s.rms(), s.wrong);
        std::remove(path.c_str());
      }
    }
    std::remove(prior.c_str());
  }
  ::rmdir(dir.c_str());
  std::printf("  summary (reference: OpenCV's corners on the clean photo)\n");
  std::printf("  clean photos: found %.2f %%, RMS %.3f px, wrong ids %d\n", 100 * clean_total.found(),
              clean_total.rms(), clean_total.wrong);
  for (double r : ratios) {
    const Score& s = per_ratio[r];
    std::printf("  r = %.2f: found %d/%d (%.2f %%), RMS %.3f px, wrong ids %d\n", r, s.matched, s.reference,
                100 * s.found(), s.rms(), s.wrong);
    EXPECT_GE(s.found(), r >= 0.4 ? 0.99 : 0.95) << "r = " << r;
    EXPECT_LE(s.rms(), 0.1) << "r = " << r;
    EXPECT_EQ(s.wrong, 0) << "r = " << r;
  }
}

}  // namespace
