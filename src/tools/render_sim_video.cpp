// Renders the simulated head into two lossless videos, one per camera, as a stock camera driver
// (e.g. image_publisher) would play them, with the calibration light's windows, an optional
// covered-scene interval and an optional zoom baked in, plus the ground truth a test needs.
//
// Output folder:
//   left.avi, right.avi   FFV1 in AVI, 8-bit grey; checked to decode back bit-exactly
//   left.yaml, right.yaml calibration files (camera_calibration_parsers layout) of the rig before
//                         any drift: what the head holds at start
//   truth_left.yaml, truth_right.yaml  the same for the truth at the end (after the zoom)
//   left_scene.png, right_scene.png    transmittance * scene, no device, no noise, at the start
//   frames.csv            one row per frame: frame, time_s, left_hash, right_hash (FNV-1a 64 of
//                         the decoded BGR bytes, hex), light (fraction of the exposure with the
//                         light on), covered (0/1), focal_scale
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <sstream>
#include <string>
#include <sys/stat.h>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/core/depth/rectification.h"
#include "embedded_calibration_stereo/core/io/atomic_file.h"
#include "embedded_calibration_stereo/core/io/camera_info_yaml.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace core = embedded_calibration_stereo::core;

namespace {

const char* kUsage =
    "usage: render_sim_video --config sim_rig.yaml --out DIR [--seconds S] [--fps F]\n"
    "                        [--light T1:T2[,T3:T4...]] [--exposure E] [--rise R]\n"
    "                        [--cover T1:T2] [--zoom T:SCALE]\n"
    "  --seconds  length of the videos (default 10)     --fps  frame rate (default 15)\n"
    "  --light    intervals (s) with the calibration light on; each frame records the fraction\n"
    "             of its exposure with the light on, so a switch during an exposure gives a\n"
    "             partly lit frame\n"
    "  --exposure exposure time as a fraction of the frame period (default 0.6)\n"
    "  --rise     seconds the light takes to reach full level after a switch (default 0)\n"
    "  --cover    interval (s) with the scene covered (black): the scene-covered frames a\n"
    "             Separator is taught from\n"
    "  --zoom     at T seconds both focal lengths step to SCALE x nominal\n";

int usageError(const std::string& message) {
  std::fprintf(stderr, "render_sim_video: %s\n%s", message.c_str(), kUsage);
  return 2;
}

bool parseDouble(const std::string& text, double* value) {
  char* end = nullptr;
  *value = std::strtod(text.c_str(), &end);
  return !text.empty() && *end == '\0' && std::isfinite(*value);
}

// "A:B" -> (A, B).
bool parsePair(const std::string& text, std::pair<double, double>* pair) {
  const size_t colon = text.find(':');
  return colon != std::string::npos && parseDouble(text.substr(0, colon), &pair->first) &&
         parseDouble(text.substr(colon + 1), &pair->second);
}

uint64_t fnv1a(const cv::Mat& image) {
  uint64_t hash = 1469598103934665603ull;
  for (int r = 0; r < image.rows; ++r) {
    const uint8_t* row = image.ptr<uint8_t>(r);
    for (size_t i = 0; i < image.cols * image.elemSize(); ++i) {
      hash ^= row[i];
      hash *= 1099511628211ull;
    }
  }
  return hash;
}

struct Timeline {
  std::vector<std::pair<double, double>> light;  // on intervals, s
  double rise_s = 0.0;
  std::pair<double, double> cover{-1.0, -1.0};
  double zoom_at = -1.0, zoom_scale = 1.0;

  double lightLevel(double t) const {
    const auto ramp = [&](double since) {
      return since <= 0.0 ? 0.0 : rise_s <= 0.0 ? 1.0 : std::min(1.0, since / rise_s);
    };
    double level = 0.0;
    for (const auto& [on, off] : light) level += ramp(t - on) - ramp(t - off);
    return std::min(1.0, std::max(0.0, level));
  }
  // Mean light level over the exposure [t0, t0 + exposure_s] (exactly 0 or 1 when untouched).
  double exposedLevel(double t0, double exposure_s) const {
    const int steps = 1000;
    double sum = 0.0;
    for (int i = 0; i < steps; ++i) sum += lightLevel(t0 + exposure_s * (i + 0.5) / steps);
    const double level = sum / steps;
    return level < 1e-9 ? 0.0 : level > 1.0 - 1e-9 ? 1.0 : level;
  }
};

void writeCalibration(const core::StereoRig& rig, const std::string& left_path, const std::string& right_path) {
  core::RectificationOptions options;
  const auto files = core::stereoCameraInfoFiles(rig, core::computeRectificationGeometry(rig, options), "stereo_left",
                                                "stereo_right");
  core::writeFileAtomically(left_path, core::cameraInfoYaml(files.first));
  core::writeFileAtomically(right_path, core::cameraInfoYaml(files.second));
}

// What the command line asks for.
struct VideoOptions {
  std::string config_path, out;
  double seconds = 10.0, fps = 15.0, exposure = 0.6;
  Timeline timeline;
};

// Returned by parseArguments when the program goes on (otherwise: its exit code).
constexpr int kContinue = -1;

int parseLight(const std::string& value, Timeline* timeline) {
  std::stringstream list(value);
  std::string item;
  std::pair<double, double> pair;
  while (std::getline(list, item, ',')) {
    if (!parsePair(item, &pair) || pair.second <= pair.first)
      return usageError("--light: '" + item + "' is not an interval T1:T2 with T2 > T1");
    timeline->light.push_back(pair);
  }
  return kContinue;
}

int parseTimelineOption(const std::string& arg, const std::string& value, Timeline* timeline) {
  std::pair<double, double> pair;
  if (arg == "--rise") {
    if (!parseDouble(value, &timeline->rise_s) || timeline->rise_s < 0) return usageError("--rise must be >= 0");
  } else if (arg == "--light") {
    return parseLight(value, timeline);
  } else if (arg == "--cover") {
    if (!parsePair(value, &pair) || pair.second <= pair.first) return usageError("--cover: expected T1:T2");
    timeline->cover = pair;
  } else if (arg == "--zoom") {
    if (!parsePair(value, &pair) || pair.second < 0.5 || pair.second > 2.0)
      return usageError("--zoom: expected T:SCALE with SCALE in [0.5, 2]");
    timeline->zoom_at = pair.first;
    timeline->zoom_scale = pair.second;
  } else {
    return usageError("unknown option " + arg);
  }
  return kContinue;
}

int parseOption(const std::string& arg, const std::string& value, VideoOptions* o) {
  if (arg == "--config") {
    o->config_path = value;
  } else if (arg == "--out") {
    o->out = value;
  } else if (arg == "--seconds") {
    if (!parseDouble(value, &o->seconds) || o->seconds <= 0) return usageError("--seconds must be > 0");
  } else if (arg == "--fps") {
    if (!parseDouble(value, &o->fps) || o->fps <= 0 || o->fps > 1000) return usageError("--fps must be in (0, 1000]");
  } else if (arg == "--exposure") {
    if (!parseDouble(value, &o->exposure) || o->exposure <= 0 || o->exposure > 1)
      return usageError("--exposure must be in (0, 1]");
  } else {
    return parseTimelineOption(arg, value, &o->timeline);
  }
  return kContinue;
}

int parseArguments(int argc, char** argv, VideoOptions* o) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "-h" || arg == "--help") {
      std::printf("%s", kUsage);
      return 0;
    }
    if (i + 1 >= argc) return usageError(arg + " needs a value");
    const std::string value = argv[++i];
    const int code = parseOption(arg, value, o);
    if (code != kContinue) return code;
  }
  if (o->config_path.empty() || o->out.empty()) return usageError("--config and --out are required");
  return kContinue;
}

// What was written per frame: the grey images (to check the decoded videos against) and the
// frame table's light level, covered flag and focal scale.
struct Recording {
  std::vector<cv::Mat> rendered[2];
  std::vector<double> levels, scales;
  std::vector<bool> covers;
};

// At time t both focal lengths step to `scale` x nominal, in both heads.
void zoom(double scale, double t, core::SimRig* sim, core::SimRig* covered) {
  core::DriftRequest drift;
  drift.focal_scale = scale;
  for (core::SimRig* rig : {sim, covered}) {
    const std::string refusal = rig->setDrift(drift, t);
    if (!refusal.empty()) throw std::runtime_error("zoom refused: " + refusal);
  }
}

void writeFrame(const core::SimFrame& frame, cv::VideoWriter writers[2], Recording* recording) {
  const cv::Mat images[2] = {frame.left, frame.right};
  for (int c = 0; c < 2; ++c) {
    cv::Mat grey = images[c];
    if (grey.channels() == 3) cv::cvtColor(grey, grey, cv::COLOR_BGR2GRAY);
    writers[c].write(grey);
    recording->rendered[c].push_back(grey);
  }
}

// Renders the videos and the calibration files (at the start and, as truth, at the end).
Recording recordVideos(const VideoOptions& o, const core::SimRigConfig& config, int frames) {
  core::SimRigConfig covered_config = config;
  covered_config.scene.enabled = false;
  core::SimRig sim(config), covered(covered_config);
  const cv::Size size(config.rig.left.width, config.rig.left.height);
  const int fourcc = cv::VideoWriter::fourcc('F', 'F', 'V', '1');
  cv::VideoWriter writers[2] = {cv::VideoWriter(o.out + "/left.avi", cv::CAP_FFMPEG, fourcc, o.fps, size, false),
                                cv::VideoWriter(o.out + "/right.avi", cv::CAP_FFMPEG, fourcc, o.fps, size, false)};
  if (!writers[0].isOpened() || !writers[1].isOpened())
    throw std::runtime_error("OpenCV cannot write FFV1 videos in " + o.out);
  writeCalibration(config.rig, o.out + "/left.yaml", o.out + "/right.yaml");

  const Timeline& timeline = o.timeline;
  Recording recording;
  bool zoomed = false;
  for (int k = 0; k < frames; ++k) {
    const double t = k / o.fps;
    if (timeline.zoom_at >= 0 && !zoomed && t >= timeline.zoom_at) {
      zoom(timeline.zoom_scale, t, &sim, &covered);
      zoomed = true;
    }
    const bool is_covered = t >= timeline.cover.first && t < timeline.cover.second;
    const double level = timeline.exposedLevel(t, o.exposure / o.fps);
    // The image is linear in the light level: a frame lit for a fraction of its exposure is
    // rendered at that level (as the simulator renders its own light ramp).
    const core::SimFrame frame = (is_covered ? covered : sim).render(t, level, 2 * k + 1);
    if (k == 0) {
      cv::imwrite(o.out + "/left_scene.png", frame.left_scene);
      cv::imwrite(o.out + "/right_scene.png", frame.right_scene);
    }
    writeFrame(frame, writers, &recording);
    recording.levels.push_back(level);
    recording.scales.push_back(zoomed ? timeline.zoom_scale : 1.0);
    recording.covers.push_back(is_covered);
  }
  writers[0].release();
  writers[1].release();
  writeCalibration(sim.truthAt(frames / o.fps), o.out + "/truth_left.yaml", o.out + "/truth_right.yaml");
  return recording;
}

// Decodes what a player will see, checks that it is bit-exact, and returns each frame's hash.
std::vector<uint64_t> decodedHashes(const std::string& path, const std::vector<cv::Mat>& rendered, int frames) {
  std::vector<uint64_t> hashes;
  cv::VideoCapture capture(path);
  cv::Mat decoded, grey, planes[3];
  for (int k = 0; k < frames; ++k) {
    if (!capture.read(decoded)) throw std::runtime_error(path + ": frame " + std::to_string(k) + " does not decode");
    if (decoded.type() != CV_8UC3) throw std::runtime_error(path + ": decodes to a non-BGR image");
    cv::split(decoded, planes);
    for (int ch = 0; ch < 3; ++ch)
      if (cv::norm(planes[ch], rendered[k], cv::NORM_INF) != 0)
        throw std::runtime_error(path + ": frame " + std::to_string(k) + " does not decode bit-exactly");
    hashes.push_back(fnv1a(decoded));
  }
  if (capture.read(decoded)) throw std::runtime_error(path + ": more frames than written");
  return hashes;
}

void writeFrameTable(const VideoOptions& o, const Recording& recording, const std::vector<uint64_t> hashes[2],
                     int frames) {
  std::ofstream csv(o.out + "/frames.csv");
  csv << "frame,time_s,left_hash,right_hash,light,covered,focal_scale\n";
  char line[256];
  for (int k = 0; k < frames; ++k) {
    std::snprintf(line, sizeof(line), "%d,%.6f,%016" PRIx64 ",%016" PRIx64 ",%.6f,%d,%.6f\n", k, k / o.fps,
                  hashes[0][k], hashes[1][k], recording.levels[k], recording.covers[k] ? 1 : 0, recording.scales[k]);
    csv << line;
  }
  if (!csv) throw std::runtime_error(o.out + "/frames.csv: cannot write");
}

}  // namespace

int main(int argc, char** argv) {
  VideoOptions o;
  const int code = parseArguments(argc, argv, &o);
  if (code != kContinue) return code;
  ::mkdir(o.out.c_str(), 0755);

  try {
    const core::SimRigConfig config = core::loadSimRigConfig(o.config_path);
    const int frames = static_cast<int>(std::lround(o.seconds * o.fps));
    const Recording recording = recordVideos(o, config, frames);
    const std::vector<uint64_t> hashes[2] = {decodedHashes(o.out + "/left.avi", recording.rendered[0], frames),
                                             decodedHashes(o.out + "/right.avi", recording.rendered[1], frames)};
    writeFrameTable(o, recording, hashes, frames);
    std::printf("render_sim_video: %d frames per camera at %.1f fps in %s (lossless, checked)\n", frames, o.fps,
                o.out.c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "render_sim_video: %s\n", e.what());
    return 1;
  }
  return 0;
}
