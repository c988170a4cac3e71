// Checks a newly built head from a short bag recorded with the head still (docs/bringup.md):
// left/right stamp pairing, the light's timing, each board's visibility and contrast in both
// cameras, clipped exposure; then a verdict, ready or not and why. The measuring and judging are
// the core's (core/calibration/bringup_check.h); this reads the bag twice (levels first, then
// the lit and unlit means once the light's frames are known) and prints.
//
//   rosrun embedded_calibration_stereo bringup_check --bag /tmp/bringup.bag --device-config /etc/ecs/head.yaml
//
// Exit status: 0 ready, 1 not ready, 2 a usage or input error.
#include <cv_bridge/cv_bridge.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/core/calibration/bringup_check.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace core = embedded_calibration_stereo::core;

namespace {

const char* kUsage =
    "usage: bringup_check --bag FILE.bag --device-config HEAD.yaml [options]\n"
    "  --bag FILE             a bag of the head standing still with at least one light burst\n"
    "                         (record.launch, or the topics below)\n"
    "  --device-config FILE   the head's device description (the format of config/sim_rig.yaml)\n"
    "  --ns NS                namespace of the head's topics (default stereo): NS/left/image_raw,\n"
    "                         NS/right/image_raw and NS/calibration_mode\n"
    "  --left-image TOPIC, --right-image TOPIC   the images, if named otherwise (e.g. your driver's)\n"
    "  --mode TOPIC           the driver's calibration_mode; '' when the bag has none\n"
    "  --max-stamp-offset-ms X   largest |right - left| stamp of a stereo frame (default 1)\n"
    "  --min-contrast X       smallest contrast of a lit board, grey levels (default 20)\n"
    "  --max-clipped X        largest fraction of clipped board pixels in lit frames (default 0.01)\n";

struct Options {
  std::string bag, device_config, ns = "stereo", left_topic, right_topic, mode_topic;
  bool mode_given = false;
  core::BringupThresholds thresholds;
};

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

double parseNumber(const std::string& option, const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || !std::isfinite(v) || v < 0)
    throw UsageError(option + ": '" + text + "' is not a number >= 0");
  return v;
}

Options parseOptions(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw UsageError(arg + ": needs a value");
      return argv[++i];
    };
    if (arg == "--bag") o.bag = value();
    else if (arg == "--device-config") o.device_config = value();
    else if (arg == "--ns") o.ns = value();
    else if (arg == "--left-image") o.left_topic = value();
    else if (arg == "--right-image") o.right_topic = value();
    else if (arg == "--mode") o.mode_topic = value(), o.mode_given = true;
    else if (arg == "--max-stamp-offset-ms") o.thresholds.max_stamp_offset_s = 1e-3 * parseNumber(arg, value());
    else if (arg == "--min-contrast") o.thresholds.min_board_contrast = parseNumber(arg, value());
    else if (arg == "--max-clipped") o.thresholds.max_clipped_fraction = parseNumber(arg, value());
    else if (arg == "--help" || arg == "-h") throw UsageError("");
    else throw UsageError("unknown option '" + arg + "'");
  }
  if (o.bag.empty() || o.device_config.empty()) throw UsageError("--bag and --device-config are required");
  const std::string prefix = "/" + o.ns.substr(o.ns.find_first_not_of('/') == std::string::npos ? o.ns.size()
                                                                                               : o.ns.find_first_not_of('/'));
  if (o.left_topic.empty()) o.left_topic = prefix + "/left/image_raw";
  if (o.right_topic.empty()) o.right_topic = prefix + "/right/image_raw";
  if (!o.mode_given) o.mode_topic = prefix + "/calibration_mode";
  const std::string problem = o.thresholds.validate();
  if (!problem.empty()) throw UsageError(problem);
  return o;
}

// One camera as the check sees it: where its boards should be, and its images' figures.
struct Camera {
  const char* name = "";
  std::string topic;
  cv::Size size;
  std::vector<core::BoardRegion> regions;
  cv::Mat mask, surround;
  std::vector<double> stamps;
  std::vector<core::ImageLevels> levels;
};

cv::Mat greyImage(const sensor_msgs::ImageConstPtr& msg, const Camera& camera) {
  cv::Mat grey = cv_bridge::toCvShare(msg, "mono8")->image;
  if (grey.size() != camera.size)
    throw std::runtime_error(camera.topic + ": a " + std::to_string(grey.cols) + "x" + std::to_string(grey.rows) +
                             " image, the device description's camera is " + std::to_string(camera.size.width) +
                             "x" + std::to_string(camera.size.height));
  return grey;
}

// First pass: every image's stamp and levels, and the driver's modes by stamp.
void readLevels(const rosbag::Bag& bag, Camera* left, Camera* right, const std::string& mode_topic,
                std::map<double, core::FrameMode>* modes) {
  rosbag::View view(bag, rosbag::TopicQuery({left->topic, right->topic, mode_topic}));
  for (const rosbag::MessageInstance& m : view) {
    if (const auto mode = m.instantiate<embedded_calibration_stereo::CalibrationMode>()) {
      (*modes)[mode->header.stamp.toSec()] = core::FrameMode{true, mode->light_on != 0, mode->settled != 0};
      continue;
    }
    const auto image = m.instantiate<sensor_msgs::Image>();
    if (!image) continue;
    Camera* camera = m.getTopic() == left->topic ? left : right;
    camera->stamps.push_back(image->header.stamp.toSec());
    camera->levels.push_back(core::measureImage(greyImage(image, *camera), camera->mask, camera->surround));
  }
}

// The driver's mode of each stereo frame: the one stamped as its left image (within a tenth of
// a frame).
std::vector<core::FrameMode> modesOfPairs(const std::map<double, core::FrameMode>& modes, const Camera& left,
                                         const core::StampPairing& stamps) {
  std::vector<core::FrameMode> out;
  if (modes.empty()) return out;
  const double tolerance = 0.1 * stamps.frame_period_s;
  for (const auto& pair : stamps.pairs) {
    const double t = left.stamps[pair.first];
    auto it = modes.lower_bound(t - tolerance);
    out.push_back(it != modes.end() && it->first <= t + tolerance ? it->second : core::FrameMode());
  }
  return out;
}

// One camera's board levels per stereo frame, the exposure's changes taken out; `scene_range`:
// the lowest and highest scene level, how much the exposure changed.
std::vector<double> pairLevels(const Camera& camera, const core::StampPairing& stamps, bool left,
                               std::pair<double, double>* scene_range) {
  std::vector<double> device, scene;
  for (const auto& pair : stamps.pairs) {
    const core::ImageLevels& l = camera.levels[left ? pair.first : pair.second];
    device.push_back(l.device_level);
    scene.push_back(l.scene_level);
  }
  if (!scene.empty()) {
    const auto range = std::minmax_element(scene.begin(), scene.end());
    *scene_range = {*range.first, *range.second};
  }
  return core::withoutExposureChanges(device, scene);
}

// Second pass: the mean lit image minus the mean unlit one of each camera.
void litMinusUnlit(const rosbag::Bag& bag, Camera* cameras, const std::vector<int>* lit, const std::vector<int>* unlit,
                   cv::Mat* difference) {
  cv::Mat sums[2][2];
  int seen[2] = {0, 0};
  rosbag::View view(bag, rosbag::TopicQuery({cameras[0].topic, cameras[1].topic}));
  for (const rosbag::MessageInstance& m : view) {
    const auto image = m.instantiate<sensor_msgs::Image>();
    if (!image) continue;
    const int c = m.getTopic() == cameras[0].topic ? 0 : 1;
    const int index = seen[c]++;
    for (int state = 0; state < 2; ++state) {
      const std::vector<int>& wanted = state == 0 ? lit[c] : unlit[c];
      if (!std::binary_search(wanted.begin(), wanted.end(), index)) continue;
      if (sums[c][state].empty()) sums[c][state] = cv::Mat::zeros(cameras[c].size, CV_64FC1);
      cv::accumulate(greyImage(image, cameras[c]), sums[c][state]);
    }
  }
  for (int c = 0; c < 2; ++c) {
    cv::Mat d = sums[c][0] / std::max<size_t>(1, lit[c].size()) - sums[c][1] / std::max<size_t>(1, unlit[c].size());
    d.convertTo(difference[c], CV_32FC1);
  }
}

void printLight(const core::LightTiming& t, bool has_modes) {
  std::printf("Light: lit minus unlit %.1f (left) and %.1f (right) grey levels in the boards; %zu switches\n",
              t.left_step, t.right_step, t.switches.size());
  for (const core::LightSwitch& s : t.switches) {
    std::printf("  %s: changing from stereo frame %d, fully %s at frame %d (%d frames of change)", s.rise ? "on " : "off",
                s.change_frame, s.rise ? "on" : "off", s.done_frame, s.done_frame - s.change_frame);
    if (s.command_frame >= 0)
      std::printf("; commanded at frame %d: changes %d, fully %s %d frames after it, settled from %d after it",
                  s.command_frame, s.change_frame - s.command_frame, s.rise ? "on" : "off",
                  s.done_frame - s.command_frame, s.settled_frame - s.command_frame);
    if (s.left_middle != s.right_middle)
      std::printf("; left sees it at frame %d, right at %d", s.left_middle, s.right_middle);
    std::printf("\n");
  }
  if (has_modes) {
    std::printf("  settled frames not fully in their state: %d of %d", t.settled_wrong, t.settled_frames);
    for (size_t i = 0; i < t.settled_wrong_frames.size() && i < 12; ++i)
      std::printf("%s%d", i == 0 ? " (stereo frames " : ", ", t.settled_wrong_frames[i]);
    std::printf("%s\n", t.settled_wrong_frames.empty() ? "" : t.settled_wrong_frames.size() > 12 ? ", ...)" : ")");
  }
  else std::printf("  no calibration_mode in the bag: the light's timing from the images only\n");
}

void printReport(const core::BringupMeasurements& m, const std::pair<double, double>* scene_range) {
  const core::StampPairing& s = m.stamps;
  std::printf("Stamps: %zu stereo frames from %d left and %d right images, a frame every %.1f ms; right - left "
              "%.2f ms (median), at most %.2f ms apart\n",
              s.pairs.size(), s.left_frames, s.right_frames, 1e3 * s.frame_period_s, 1e3 * s.median_offset_s,
              1e3 * s.max_abs_offset_s);
  std::printf("Exposure: the scene outside the boards from %.1f to %.1f grey levels (left), %.1f to %.1f (right); "
              "the boards' levels are divided by its changes\n",
              scene_range[0].first, scene_range[0].second, scene_range[1].first, scene_range[1].second);
  printLight(m.light, m.has_modes);
  std::printf("Frames fully lit in both cameras: %d; fully unlit: %d\n", m.lit_frames, m.unlit_frames);
  std::printf("Boards (contrast: lit white minus lit black square, grey levels; seen: the part of the board "
              "showing it):\n  board   left: contrast  seen  in image   right: contrast  seen  in image\n");
  for (size_t i = 0; i < m.boards[0].size() && i < m.boards[1].size(); ++i) {
    const core::BoardVisibility &l = m.boards[0][i], &r = m.boards[1][i];
    std::printf("  %5d   %15.1f  %3.0f %%  %6.0f %%   %16.1f  %3.0f %%  %6.0f %%\n", l.board_id, l.contrast,
                100.0 * l.seen_fraction, 100.0 * l.inside_fraction, r.contrast, 100.0 * r.seen_fraction,
                100.0 * r.inside_fraction);
  }
  std::printf("Clipped pixels (0 or full scale) in the boards on lit frames: left %.2f %%, right %.2f %%\n",
              100.0 * m.clipped_fraction[0], 100.0 * m.clipped_fraction[1]);
}

// The lit and unlit stereo frames' image indices per camera, and the clipping of the lit ones.
void sortFrames(core::BringupMeasurements* m, const Camera* cameras, const core::BringupThresholds& th,
                std::vector<int>* lit, std::vector<int>* unlit) {
  const core::LightTiming& t = m->light;
  for (size_t k = 0; k < t.left_fraction.size(); ++k) {
    const double lo = std::min(t.left_fraction[k], t.right_fraction[k]);
    const double hi = std::max(t.left_fraction[k], t.right_fraction[k]);
    const int index[2] = {m->stamps.pairs[k].first, m->stamps.pairs[k].second};
    if (lo >= th.full_fraction) {
      ++m->lit_frames;
      for (int c = 0; c < 2; ++c) {
        lit[c].push_back(index[c]);
        const double clipped = cameras[c].levels[index[c]].clipped_fraction;
        m->clipped_fraction[c] += clipped;
        if (clipped > th.max_clipped_fraction) ++m->clipped_frames[c];
      }
    } else if (hi <= 1.0 - th.full_fraction) {
      ++m->unlit_frames;
      for (int c = 0; c < 2; ++c) unlit[c].push_back(index[c]);
    }
  }
  for (int c = 0; c < 2; ++c) {
    if (m->lit_frames > 0) m->clipped_fraction[c] /= m->lit_frames;
    std::sort(lit[c].begin(), lit[c].end());
    std::sort(unlit[c].begin(), unlit[c].end());
  }
}

int run(const Options& o) {
  const core::SimRigConfig head = core::loadSimRigConfig(o.device_config);
  Camera cameras[2];
  for (int c = 0; c < 2; ++c) {
    const core::PinholeCamera& camera = c == 0 ? head.rig.left : head.rig.right;
    cameras[c].name = c == 0 ? "left" : "right";
    cameras[c].topic = c == 0 ? o.left_topic : o.right_topic;
    cameras[c].size = cv::Size(camera.width, camera.height);
    cameras[c].regions = core::projectBoardRegions(head.device, head.rig, c == 1);
    cameras[c].mask = core::boardOutlineMask(cameras[c].regions, cameras[c].size);
    cameras[c].surround = core::boardOutlineMask(cameras[c].regions, cameras[c].size, true);
  }
  rosbag::Bag bag(o.bag, rosbag::bagmode::Read);
  std::map<double, core::FrameMode> modes;
  readLevels(bag, &cameras[0], &cameras[1], o.mode_topic, &modes);
  for (const Camera& c : cameras)
    if (c.stamps.empty()) throw std::runtime_error("no image on " + c.topic + " in " + o.bag);
  std::printf("bringup_check: %s: %zu left images (%s), %zu right images (%s), %zu calibration_mode messages\n",
              o.bag.c_str(), cameras[0].stamps.size(), o.left_topic.c_str(), cameras[1].stamps.size(),
              o.right_topic.c_str(), modes.size());

  core::BringupMeasurements m;
  m.stamps = core::pairStereoStamps(cameras[0].stamps, cameras[1].stamps);
  std::pair<double, double> scene_range[2];
  const std::vector<double> levels[2] = {pairLevels(cameras[0], m.stamps, true, &scene_range[0]),
                                         pairLevels(cameras[1], m.stamps, false, &scene_range[1])};
  const std::vector<core::FrameMode> pair_modes = modesOfPairs(modes, cameras[0], m.stamps);
  m.has_modes = !pair_modes.empty();
  m.light = core::analyseLight(levels[0], levels[1], pair_modes, o.thresholds);
  std::vector<int> lit[2], unlit[2];
  sortFrames(&m, cameras, o.thresholds, lit, unlit);
  if (m.lit_frames > 0 && m.unlit_frames > 0) {
    cv::Mat difference[2];
    litMinusUnlit(bag, cameras, lit, unlit, difference);
    for (int c = 0; c < 2; ++c) m.boards[c] = core::measureBoards(difference[c], cameras[c].regions, o.thresholds);
  }
  printReport(m, scene_range);
  const core::BringupVerdict verdict = core::judgeBringup(m, o.thresholds);
  std::printf("Verdict: %s\n", verdict.ready ? "READY: nothing found that keeps this head from calibrating itself"
                                               : "NOT READY:");
  for (const std::string& reason : verdict.reasons) std::printf("  - %s\n", reason.c_str());
  return verdict.ready ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  Options options;
  try {
    options = parseOptions(argc, argv);
  } catch (const UsageError& e) {
    if (std::string(e.what()).empty()) {
      std::fputs(kUsage, stdout);
      return 0;
    }
    std::fprintf(stderr, "bringup_check: %s\n%s", e.what(), kUsage);
    return 2;
  }
  try {
    return run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bringup_check: %s\n", e.what());
    return 2;
  }
}
