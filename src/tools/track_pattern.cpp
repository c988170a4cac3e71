// Command-line front end of the pattern tracker (ROS-free).
//
//   track_pattern teach --board COLSxROWS --image FILE [--image FILE ...] [--dark FILE ...]
//                       --out PRIOR.yaml [--camera NAME] [--append]
//   track_pattern teach --device SIM_RIG.yaml [--camera left|right] --image FILE [...]
//                       [--dark FILE ...] --out PRIOR.yaml [--append]
//   track_pattern track --prior PRIOR.yaml --image FILE [--camera NAME] [--dark FILE]
//
// teach: --board teaches one plain chessboard given by its inner-corner grid (board id 0; corner
// 0 is the outer corner nearest the image's top-left). --device teaches the embedded device of a
// sim_rig.yaml-format file (its device and nominal cameras identify the six virtual boards).
// --dark: light-off frame(s): one for all images, or one per image. --append adds (or replaces)
// this camera in an existing prior file, to build a stereo prior: teach left, then right.
// track: prints one line per corner "board_id,corner_id,u,v" on stdout and a summary on
// stderr; --dark gives a light-off frame as the scene background. Exit code 0 when corners were
// found, 1 when none, 2 on a usage or input error.
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/tracker/board_prior.h"
#include "embedded_calibration_stereo/core/tracker/board_teacher.h"
#include "embedded_calibration_stereo/core/tracker/pattern_tracker.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

using namespace embedded_calibration_stereo::core;

namespace {

struct Args {
  std::string command, board, device, out, prior, camera;
  std::vector<std::string> images, darks;
  bool append = false;
};

[[noreturn]] void usage(const std::string& problem) {
  if (!problem.empty()) std::fprintf(stderr, "track_pattern: %s\n", problem.c_str());
  std::fprintf(stderr,
               "usage:\n"
               "  track_pattern teach --board COLSxROWS --image FILE [--image FILE ...] [--dark FILE ...]\n"
               "                      --out PRIOR.yaml [--camera NAME] [--append]\n"
               "  track_pattern teach --device SIM_RIG.yaml [--camera left|right] --image FILE [...]\n"
               "                      [--dark FILE ...] --out PRIOR.yaml [--append]\n"
               "  track_pattern track --prior PRIOR.yaml --image FILE [--camera NAME] [--dark FILE]\n");
  std::exit(2);
}

Args parse(int argc, char** argv) {
  if (argc < 2) usage("");
  Args a;
  a.command = argv[1];
  if (a.command != "teach" && a.command != "track") usage("unknown command '" + a.command + "'");
  for (int i = 2; i < argc; ++i) {
    const std::string key = argv[i];
    if (key == "--append") {
      a.append = true;
      continue;
    }
    if (i + 1 >= argc) usage(key + " needs a value");
    const std::string value = argv[++i];
    if (key == "--board")
      a.board = value;
    else if (key == "--device")
      a.device = value;
    else if (key == "--image")
      a.images.push_back(value);
    else if (key == "--dark")
      a.darks.push_back(value);
    else if (key == "--out")
      a.out = value;
    else if (key == "--prior")
      a.prior = value;
    else if (key == "--camera")
      a.camera = value;
    else
      usage("unknown option " + key);
  }
  if (a.images.empty()) usage("at least one --image is required");
  if (!a.darks.empty() && a.darks.size() != 1 && a.darks.size() != a.images.size())
    usage("give one --dark for all images or one per --image");
  return a;
}

cv::Mat load(const std::string& path) {
  const cv::Mat image = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (image.empty()) throw std::runtime_error("cannot read image " + path);
  return image;
}

int teach(const Args& a) {
  if (a.out.empty()) usage("teach needs --out PRIOR.yaml");
  if (a.board.empty() == a.device.empty())
    usage("teach needs exactly one of --board COLSxROWS and --device FILE");
  BoardLayout layout;
  std::string name = a.camera;
  if (!a.board.empty()) {
    int cols = 0, rows = 0;
    if (std::sscanf(a.board.c_str(), "%dx%d", &cols, &rows) != 2 || cols < 2 || rows < 2)
      usage("--board must be COLSxROWS inner corners, e.g. 8x6");
    layout = BoardLayout::plainChessboard(cols, rows);
    if (name.empty()) name = "camera";
  } else {
    const SimRigConfig config = loadSimRigConfig(a.device);
    if (name.empty()) name = "left";
    if (name != "left" && name != "right") usage("--camera must be left or right with --device");
    const std::vector<VirtualBoard> boards = config.device.virtualBoards();
    layout = name == "left" ? BoardLayout::device(boards, config.rig.left, Eigen::Isometry3d::Identity())
                            : BoardLayout::device(boards, config.rig.right, config.rig.right_from_left);
  }
  std::vector<TeachFrame> frames;
  for (size_t i = 0; i < a.images.size(); ++i) {
    TeachFrame f;
    f.light_on = load(a.images[i]);
    if (!a.darks.empty()) f.light_off = load(a.darks[a.darks.size() == 1 ? 0 : i]);
    frames.push_back(f);
  }
  const auto t0 = std::chrono::steady_clock::now();
  const TeachResult result = teachCamera(frames, layout, name);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  for (const std::string& note : result.notes) std::fprintf(stderr, "%s\n", note.c_str());

  PatternPrior prior;
  if (a.append && std::ifstream(a.out).good()) prior = readPatternPrior(a.out);
  bool replaced = false;
  for (CameraPrior& c : prior.cameras)
    if (c.name == name) c = result.prior, replaced = true;
  if (!replaced) prior.cameras.push_back(result.prior);
  writePatternPrior(a.out, prior);
  std::fprintf(stderr, "taught %zu board(s) of camera '%s' from %zu frame(s) in %.0f ms -> %s\n",
               result.prior.boards.size(), name.c_str(), frames.size(), ms, a.out.c_str());
  return 0;
}

int track(const Args& a) {
  if (a.prior.empty()) usage("track needs --prior PRIOR.yaml");
  if (a.images.size() != 1) usage("track takes one --image");
  const PatternPrior prior = readPatternPrior(a.prior);
  const CameraPrior* camera = &prior.cameras.front();
  if (!a.camera.empty()) {
    camera = nullptr;
    for (const CameraPrior& c : prior.cameras)
      if (c.name == a.camera) camera = &c;
    if (!camera) usage("camera '" + a.camera + "' is not in " + a.prior);
  }
  TrackerOptions options;
  CameraTracker tracker(*camera, options);
  if (!a.darks.empty()) tracker.setBackground(load(a.darks.front()));
  const cv::Mat image = load(a.images.front());
  const auto t0 = std::chrono::steady_clock::now();
  const std::vector<BoardCorners> boards = tracker.track(image);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  size_t corners = 0;
  for (const BoardCorners& b : boards) {
    for (size_t i = 0; i < b.size(); ++i)
      std::printf("%d,%d,%.4f,%.4f\n", b.board_id, b.corner_ids[i], b.u[i], b.v[i]);
    corners += b.size();
  }
  std::fprintf(stderr,
               "camera '%s': %zu corners on %zu of %d boards in %.1f ms (first frame, from the prior)",
               camera->name.c_str(), corners, boards.size(), tracker.boardCount(), ms);
  for (const BoardTrackStats& s : tracker.lastStats())
    std::fprintf(stderr, "; board %d %d/%d score %.2f", s.board_id, s.found, s.predicted, s.pattern_score);
  std::fprintf(stderr, "\n");
  return corners > 0 ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  const Args args = parse(argc, argv);
  try {
    return args.command == "teach" ? teach(args) : track(args);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "track_pattern: %s\n", e.what());
    return 2;
  }
}
