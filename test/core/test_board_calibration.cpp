// Stereo calibration from images of a flat chessboard (board_calibration.h, calibrate_images)
// against the simulated rig of config/sim_rig.yaml.
//
// Data set, as a careful user would collect it: an 11x8 inner-corner board of 25 mm squares
// held at 30 poses 0.45-0.8 m away, centres spread over the image (3 x 3 grid), tilted 15-40 deg
// about varying axes and rolled +-20 deg, whole board in both images; rendered with the
// simulator's anti-aliased board renderer, 0.8 px Gaussian PSF and 1.5 grey levels of noise.
// Bounds are the calibrator's: fx, fy <= 0.05 %, cx, cy <= 0.3 px, k1 <= 0.005, baseline <= 0.1 %,
// rotation <= 0.01 deg.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "embedded_calibration_stereo/core/calibration/board_calibration.h"
#include "embedded_calibration_stereo/core/calibration/board_calibration_report.h"
#include "embedded_calibration_stereo/core/io/camera_info_yaml.h"
#include "embedded_calibration_stereo/test_support/flat_board_images.h"
#include "embedded_calibration_stereo/test_support/run_command.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {
namespace {

constexpr int kCols = 11, kRows = 8;
constexpr double kSquare = 0.025;
constexpr int kPairs = 30;

struct DataSet {
  StereoRig truth;
  ChessboardSpec board;
  std::vector<FlatBoardImagePair> images;
  std::vector<StereoBoardDetection> detections;  // every pair, in corner-id order
  double detection_rms_px = 0;                   // detected vs true corners, both cameras
};

const DataSet& dataSet() {
  static const DataSet data = [] {
    DataSet d;
    d.truth = loadSimRigConfig(std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml").rig;
    d.board = {kCols, kRows, kSquare};
    const std::vector<Eigen::Isometry3d> poses =
        flatBoardCalibrationPoses(d.truth, kCols, kRows, kSquare, FlatBoardPoseOptions{}, 7);
    double sum_sq = 0;
    int n = 0;
    for (size_t i = 0; i < poses.size(); ++i) {
      VirtualBoard board = d.board.virtualBoard();
      board.rig_from_board = poses[i];
      FlatBoardImagePair pair = renderFlatBoardPair(d.truth, board, FlatBoardImageOptions{}, i);
      StereoBoardDetection det;
      det.name = "pair" + std::to_string(i);
      if (detectChessboard(pair.left, kCols, kRows, CornerDetector::kCornerSubPix, &det.left) &&
          detectChessboard(pair.right, kCols, kRows, CornerDetector::kCornerSubPix, &det.right)) {
        // Error against the truth, whichever grid order OpenCV chose.
        for (const auto& [found, truth] : {std::make_pair(&det.left, &pair.truth.left[0]),
                                           std::make_pair(&det.right, &pair.truth.right[0])}) {
          double best = std::numeric_limits<double>::infinity();
          for (int flips = 0; flips < 4 && truth->size() == found->size(); ++flips) {
            double sum = 0;
            for (int r = 0; r < kRows; ++r)
              for (int c = 0; c < kCols; ++c) {
                const cv::Point2f f = (*found)[((flips & 1) ? kRows - 1 - r : r) * kCols +
                                               ((flips & 2) ? kCols - 1 - c : c)];
                const int id = r * kCols + c;
                sum += std::pow(cv::norm(f - cv::Point2f(truth->u[id], truth->v[id])), 2);
              }
            best = std::min(best, sum);
          }
          sum_sq += best;
          n += static_cast<int>(found->size());
        }
        d.detections.push_back(det);
      }
      d.images.push_back(std::move(pair));
    }
    d.detection_rms_px = n ? std::sqrt(sum_sq / n) : 0;
    return d;
  }();
  return data;
}

double relativeError(double value, double truth) { return std::abs(value - truth) / truth; }

TEST(BoardCalibration, SimulatedPosesAreSeenWholeAndDetectedAccurately) {
  const DataSet& d = dataSet();
  ASSERT_EQ(static_cast<int>(d.images.size()), kPairs);
  EXPECT_EQ(d.detections.size(), d.images.size()) << "the board must be found in every pair";
  for (const FlatBoardImagePair& p : d.images) {
    EXPECT_EQ(static_cast<int>(p.truth.left[0].size()), kCols * kRows);
    EXPECT_EQ(static_cast<int>(p.truth.right[0].size()), kCols * kRows);
  }
  std::printf("corner detection rms vs truth: %.4f px over %zu pairs\n", d.detection_rms_px,
              d.detections.size());
  EXPECT_LT(d.detection_rms_px, 0.06);
}

TEST(BoardCalibration, RecoversTheTruthWithinTheAccuracyTargets) {
  const DataSet& d = dataSet();
  const BoardCalibrationResult r =
      calibrateStereoBoard(d.board, cv::Size(d.truth.left.width, d.truth.left.height), d.detections,
                           BoardCalibrationOptions{});
  ASSERT_TRUE(r.ok) << r.message;
  EXPECT_TRUE(r.summary.converged);
  EXPECT_TRUE(r.summary.covariance_ok);
  for (const auto& [est, truth, sd, name] :
       {std::make_tuple(&r.rig.left, &d.truth.left, &r.summary.left_stddev, "left"),
        std::make_tuple(&r.rig.right, &d.truth.right, &r.summary.right_stddev, "right")}) {
    std::printf(
        "%s: fx %.4f %% (sd %.4f %%), fy %.4f %%, cx %.3f px (sd %.3f), cy %.3f px, k1 %.5f "
        "(sd %.5f)\n",
        name, 100 * relativeError(est->fx, truth->fx), 100 * sd->fx / truth->fx,
        100 * relativeError(est->fy, truth->fy), est->cx - truth->cx, sd->cx, est->cy - truth->cy,
        est->dist[0] - truth->dist[0], sd->dist[0]);
    EXPECT_LE(relativeError(est->fx, truth->fx), 5e-4) << name;
    EXPECT_LE(relativeError(est->fy, truth->fy), 5e-4) << name;
    EXPECT_LE(std::abs(est->cx - truth->cx), 0.3) << name;
    EXPECT_LE(std::abs(est->cy - truth->cy), 0.3) << name;
    EXPECT_LE(std::abs(est->dist[0] - truth->dist[0]), 0.005) << name;
    // The reported standard deviations are honest: the true errors lie within 3 of them.
    EXPECT_LE(std::abs(est->fx - truth->fx), 3 * sd->fx) << name;
    EXPECT_LE(std::abs(est->fy - truth->fy), 3 * sd->fy) << name;
    EXPECT_LE(std::abs(est->cx - truth->cx), 3 * sd->cx) << name;
    EXPECT_LE(std::abs(est->cy - truth->cy), 3 * sd->cy) << name;
    EXPECT_LE(std::abs(est->dist[0] - truth->dist[0]), 3 * sd->dist[0]) << name;
  }
  const double baseline_error = relativeError(r.rig.baseline(), d.truth.baseline());
  const double rotation_error =
      rotationAngleDeg(r.rig.right_from_left.linear(), d.truth.right_from_left.linear());
  std::printf(
      "baseline %.4f %% (sd %.4f %%), rotation %.5f deg (sd %.5f), rms %.4f px, "
      "epipolar %.4f px, solve %.0f ms\n",
      100 * baseline_error, 100 * r.summary.baseline_stddev_m / d.truth.baseline(), rotation_error,
      r.summary.rotation_stddev_deg, r.rms_px, r.summary.epipolar_rms_px, r.summary.solve_ms);
  EXPECT_LE(baseline_error, 1e-3);
  EXPECT_LE(rotation_error, 0.01);
  EXPECT_LE(std::abs(r.rig.baseline() - d.truth.baseline()), 3 * r.summary.baseline_stddev_m);
  EXPECT_LE(rotation_error, 3 * r.summary.rotation_stddev_deg);
  // Residuals at the level of the detection noise, and per-pair figures for every pair.
  EXPECT_LT(r.rms_px, 0.06);
  ASSERT_EQ(r.pairs.size(), d.detections.size());
  for (const PairResiduals& p : r.pairs) {
    EXPECT_EQ(static_cast<int>(p.left.size()), kCols * kRows);
    EXPECT_LT(p.rms_px, 3 * r.rms_px) << p.name;
  }
  // Rectification in the CameraInfo convention: right Tx = -fx' * baseline.
  const auto [left_file, right_file] = stereoCameraInfoFiles(r.rig, r.rectification, "l", "r");
  EXPECT_NEAR(-right_file.P(0, 3) / right_file.P(0, 0), r.rig.baseline(), 1e-9);
  EXPECT_DOUBLE_EQ(left_file.P(0, 3), 0.0);
}

TEST(BoardCalibration, RmsIsNoHigherThanOpenCvStereoCalibrate) {
  const DataSet& d = dataSet();
  const cv::Size size(d.truth.left.width, d.truth.left.height);
  const BoardCalibrationOptions options;
  const BoardCalibrationResult ours = calibrateStereoBoard(d.board, size, d.detections, options);
  ASSERT_TRUE(ours.ok) << ours.message;

  std::vector<std::vector<cv::Point2f>> left, right;
  for (StereoBoardDetection det : d.detections) {
    orientConsistently(&det, kCols, kRows);
    left.push_back(det.left);
    right.push_back(det.right);
  }
  const std::vector<std::vector<cv::Point3f>> object(left.size(), d.board.objectPoints());
  const int flags = openCvDistortionFlags(options);
  cv::Mat kl, dl, kr, dr, rotation, translation, e, f;
  cv::calibrateCamera(object, left, size, kl, dl, cv::noArray(), cv::noArray(), flags);
  cv::calibrateCamera(object, right, size, kr, dr, cv::noArray(), cv::noArray(), flags);
  // As ROS camera_calibration does it: intrinsics held, then OpenCV's full joint refinement.
  const double fixed_rms = cv::stereoCalibrate(object, left, right, kl, dl, kr, dr, size, rotation,
                                               translation, e, f, flags | cv::CALIB_FIX_INTRINSIC);
  const double joint_rms = cv::stereoCalibrate(
      object, left, right, kl, dl, kr, dr, size, rotation, translation, e, f,
      flags | cv::CALIB_USE_INTRINSIC_GUESS,
      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-10));
  std::printf(
      "rms: ours %.6f px, stereoCalibrate intrinsics held %.6f px, joint %.6f px; "
      "OpenCV joint fx error %.4f %% (ours %.4f %%)\n",
      ours.rms_px, fixed_rms, joint_rms, 100 * relativeError(kl.at<double>(0, 0), d.truth.left.fx),
      100 * relativeError(ours.rig.left.fx, d.truth.left.fx));
  EXPECT_NEAR(ours.opencv_initial_rms_px, fixed_rms, 1e-9);
  // Same objective: no higher, up to the solvers' stopping tolerances.
  EXPECT_LE(ours.rms_px, joint_rms + 1e-6);
  EXPECT_LE(ours.rms_px, fixed_rms);
}

TEST(BoardCalibration, RejectsBadInput) {
  int cols = 0, rows = 0;
  std::string error;
  for (const char* bad : {"9", "9x", "x6", "9x6x", "1x6", "nine by six", "9*6"}) {
    EXPECT_FALSE(parseBoardSize(bad, &cols, &rows, &error)) << bad;
    EXPECT_NE(error.find("COLSxROWS"), std::string::npos);
  }
  ASSERT_TRUE(parseBoardSize("9x6", &cols, &rows, &error));
  EXPECT_EQ(cols, 9);
  EXPECT_EQ(rows, 6);
  EXPECT_NE(ChessboardSpec({7, 7, 0.03}).validate().find("square grids"), std::string::npos);
  EXPECT_FALSE(ChessboardSpec({9, 6, 0.0}).validate().empty());

  std::vector<cv::Point2f> corners;
  EXPECT_FALSE(detectChessboard(cv::Mat(480, 752, CV_8UC1, cv::Scalar(128)), 9, 6,
                                CornerDetector::kSectorBased, &corners));
  EXPECT_FALSE(detectChessboard(cv::Mat(480, 752, CV_8UC1, cv::Scalar(128)), 9, 6,
                                CornerDetector::kCornerSubPix, &corners));
  EXPECT_TRUE(detectChessboard(dataSet().images[0].left, kCols, kRows, CornerDetector::kSectorBased,
                               &corners));
  EXPECT_FALSE(detectChessboard(dataSet().images[0].left, kCols - 1, kRows,
                                CornerDetector::kCornerSubPix, &corners))
      << "a grid of the wrong size is not a match";

  const DataSet& d = dataSet();
  ASSERT_GE(d.detections.size(), 3u);
  const cv::Size size(d.truth.left.width, d.truth.left.height);
  const std::vector<StereoBoardDetection> few(d.detections.begin(), d.detections.begin() + 3);
  const BoardCalibrationResult r = calibrateStereoBoard(d.board, size, few, {});
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.message.find("at least 5"), std::string::npos) << r.message;
  std::vector<StereoBoardDetection> partial = d.detections;
  partial[2].right.pop_back();
  EXPECT_NE(calibrateStereoBoard(d.board, size, partial, {}).message.find(partial[2].name),
            std::string::npos);
}

TEST(BoardCalibration, OrientsPairsConsistently) {
  const DataSet& d = dataSet();
  StereoBoardDetection reference = d.detections[0];
  orientConsistently(&reference, kCols, kRows);
  EXPECT_LE(reference.left.front().y, reference.left.back().y);
  // Rows reversed, columns reversed, both (= the list reversed): back to the reference order.
  for (int flips = 1; flips < 4; ++flips) {
    StereoBoardDetection det = reference;
    for (int r = 0; r < kRows; ++r)
      for (int c = 0; c < kCols; ++c)
        det.right[r * kCols + c] = reference.right[((flips & 1) ? kRows - 1 - r : r) * kCols +
                                                   ((flips & 2) ? kCols - 1 - c : c)];
    orientConsistently(&det, kCols, kRows);
    EXPECT_EQ(det.left, reference.left) << flips;
    EXPECT_EQ(det.right, reference.right) << flips;
  }
}

TEST(BoardCalibration, WritesFilesAtomicallyAndNamesTheProblem) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("ecs_board_files_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "a.yaml").string();
  writeFileAtomically(path, "old");
  writeFileAtomically(path, "new content");
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  EXPECT_EQ(text.str(), "new content");
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) files += entry.exists();
  EXPECT_EQ(files, 1) << "no temporary file left behind";
  try {
    writeFileAtomically((dir / "missing" / "b.yaml").string(), "x");
    ADD_FAILURE() << "writing into a missing directory must throw";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("missing"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(dir);
}

// ---- The executable, end to end -------------------------------------------------------------

// gtests and tools are built into the same devel/lib/<package> directory.
std::string toolPath() {
  return (std::filesystem::read_symlink("/proc/self/exe").parent_path() / "calibrate_images")
      .string();
}

int runTool(const std::string& arguments, std::string* output = nullptr) {
  std::string text;
  const int status = runCommand(toolPath() + " " + arguments + " 2>&1", &text);
  if (output) *output = text;
  return status;
}

std::string readText(const std::filesystem::path& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

size_t occurrences(const std::string& text, const std::string& what) {
  size_t count = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++count;
  return count;
}

// The number after the first line starting with "key: " (NaN when absent).
double yamlNumber(const std::string& text, const std::string& key) {
  const std::string needle = "\n" + key + ": ";
  const size_t at = ("\n" + text).find(needle);
  return at == std::string::npos ? std::nan("") : std::atof(text.c_str() + at + needle.size() - 1);
}

// The data list of a camera_calibration_parsers matrix.
std::vector<double> yamlData(const std::string& text, const std::string& matrix) {
  std::vector<double> values;
  const size_t at = text.find(matrix + ":\n");
  if (at == std::string::npos) return values;
  const size_t open = text.find("data: [", at), close = text.find(']', open);
  std::stringstream list(text.substr(open + 7, close - open - 7));
  for (std::string item; std::getline(list, item, ',');) values.push_back(std::atof(item.c_str()));
  return values;
}

class CalibrateImagesTool : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(std::filesystem::exists(toolPath()))
        << toolPath() << " is missing: build the calibrate_images target first";
    dir_ = std::filesystem::temp_directory_path() /
           ("ecs_calibrate_images_" + std::to_string(::getpid()));
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_ / "img");
    const DataSet& d = dataSet();
    char name[64];
    for (size_t i = 0; i < d.images.size(); ++i) {
      std::snprintf(name, sizeof name, "left_%02zu.png", i);
      cv::imwrite((dir_ / "img" / name).string(), d.images[i].left);
      std::snprintf(name, sizeof name, "right_%02zu.png", i);
      cv::imwrite((dir_ / "img" / name).string(), d.images[i].right);
    }
    // One more pair without the board in the right image: skipped with a warning.
    cv::imwrite((dir_ / "img" / "left_99.png").string(), d.images[0].left);
    cv::imwrite((dir_ / "img" / "right_99.png").string(),
                cv::Mat(d.images[0].right.size(), CV_8UC1, cv::Scalar(30)));
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::string images(const std::string& side) const {
    return "'" + (dir_ / "img" / (side + "_*.png")).string() + "'";
  }
  std::string common() const {
    return "--board " + std::to_string(kCols) + "x" + std::to_string(kRows) + " --square " +
           std::to_string(kSquare) + " --left " + images("left") + " --right " + images("right");
  }
  std::filesystem::path dir_;
};

TEST_F(CalibrateImagesTool, CalibratesAndWritesEveryFile) {
  std::string output;
  const std::filesystem::path out = dir_ / "out";
  ASSERT_EQ(runTool(common() + " --out " + out.string(), &output), 0) << output;
  EXPECT_NE(output.find("board not found in the right image, skipped"), std::string::npos)
      << output;
  for (const char* file : {"left.yaml", "right.yaml", "report.yaml", "residuals.png"})
    EXPECT_TRUE(std::filesystem::exists(out / file)) << file;
  EXPECT_FALSE(cv::imread((out / "residuals.png").string()).empty());

  // The files are plain YAML without OpenCV's header: read the few values needed by hand
  // (test_calibrate_images_yaml parses the camera files with camera_calibration_parsers).
  const StereoRig& truth = dataSet().truth;
  const std::string report = readText(out / "report.yaml");
  EXPECT_GT(yamlNumber(report, "rms_px"), 0.0);
  EXPECT_LT(yamlNumber(report, "rms_px"), 0.1);
  EXPECT_GT(yamlNumber(report, "epipolar_rms_px"), 0.0);
  EXPECT_EQ(occurrences(report, "\n  - {name: "), dataSet().images.size());
  EXPECT_EQ(occurrences(report, "right_99.png: board not found in the right image"), 1u);
  EXPECT_GT(yamlNumber(report, "    fx"), 0.0) << "left fx standard deviation";
  EXPECT_LE(relativeError(yamlNumber(report, "baseline_m"), truth.baseline()), 1e-3);

  const std::string left = readText(out / "left.yaml");
  const std::string right = readText(out / "right.yaml");
  EXPECT_EQ(yamlNumber(left, "image_width"), truth.left.width);
  EXPECT_EQ(occurrences(left, "camera_name: left\n"), 1u);
  EXPECT_EQ(occurrences(left, "distortion_model: plumb_bob\n"), 1u);
  const std::vector<double> k = yamlData(left, "camera_matrix");
  const std::vector<double> p = yamlData(right, "projection_matrix");
  ASSERT_EQ(k.size(), 9u);
  ASSERT_EQ(p.size(), 12u);
  EXPECT_LE(relativeError(k[0], truth.left.fx), 5e-4);
  EXPECT_LE(relativeError(-p[3] / p[0], truth.baseline()), 1e-3);
}

TEST_F(CalibrateImagesTool, FailsClearlyOnBadInput) {
  const std::string out = " --out " + (dir_ / "out").string();
  std::string output;
  EXPECT_EQ(runTool("--board 9by6 --square 0.03 --left " + images("left") + " --right " +
                        images("right") + out,
                    &output),
            2);
  EXPECT_NE(output.find("COLSxROWS"), std::string::npos) << output;
  EXPECT_EQ(runTool("--board 9x6 --square 0.03 --left '" + (dir_ / "none_*.png").string() +
                        "' --right " + images("right") + out,
                    &output),
            2);
  EXPECT_NE(output.find("no file matches --left"), std::string::npos) << output;
  EXPECT_EQ(runTool("--board 9x6 --square 0.03 --left " + images("left") + " --right '" +
                        (dir_ / "img" / "right_0*.png").string() + "'" + out,
                    &output),
            2);
  EXPECT_NE(output.find("must match"), std::string::npos) << output;
  EXPECT_EQ(runTool("--board 9x6 --square -1 --left " + images("left") + " --right " +
                        images("right") + out,
                    &output),
            2);
  // Output "directory" that is a file.
  std::ofstream((dir_ / "a_file").string()) << "x";
  EXPECT_EQ(runTool(common() + " --out " + (dir_ / "a_file").string(), &output), 3);
  EXPECT_NE(output.find("cannot be created or written"), std::string::npos) << output;
  // Too few usable pairs: the single pair 99 has no board on the right.
  EXPECT_EQ(
      runTool("--board 11x8 --square 0.025 --left '" + (dir_ / "img" / "left_9*.png").string() +
                  "' --right '" + (dir_ / "img" / "right_9*.png").string() + "'" + out,
              &output),
      1);
  EXPECT_NE(output.find("usable pair"), std::string::npos) << output;
  // Images of another size than the first pair's.
  std::filesystem::create_directories(dir_ / "size");
  cv::imwrite((dir_ / "size" / "left_0.png").string(), dataSet().images[0].left);
  cv::Mat smaller;
  cv::resize(dataSet().images[0].right, smaller, cv::Size(640, 480));
  cv::imwrite((dir_ / "size" / "right_0.png").string(), smaller);
  EXPECT_EQ(
      runTool("--board 11x8 --square 0.025 --left '" + (dir_ / "size" / "left_*.png").string() +
                  "' --right '" + (dir_ / "size" / "right_*.png").string() + "'" + out,
              &output),
      2);
  EXPECT_NE(output.find("expected 752x480 for every image"), std::string::npos) << output;
  EXPECT_FALSE(std::filesystem::exists(dir_ / "out" / "left.yaml"));
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
