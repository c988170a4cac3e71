// rostest: the PatternTracker on the sim driver. Observations must come for exactly the settled
// light-on frames once taught, and their corners must agree with the simulator's ground truth
// (ground_truth/observations, noise-free, same stamp). A second tracker, loaded in this process
// on a corrupt prior file, must stay idle with an error naming the file until ~teach is called.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <std_srvs/Trigger.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "embedded_calibration_stereo/core/tracker/board_prior.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::BoardObservation;
using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;

namespace {

struct Fixture {
  ros::NodeHandle nh;
  Collector<CalibrationMode> modes{nh, "calibration_mode", 1000};
  Collector<StereoPatternObservation> observations{nh, "calibration/observations", 1000};
  Collector<StereoPatternObservation> truth{nh, "ground_truth/observations", 1000};
  Collector<rosgraph_msgs::Log> log{nh, "/rosout", 1000};
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics{nh, "/diagnostics", 1000};
};

Fixture* fixture = nullptr;

bool calibrating(const CalibrationMode& m) { return m.light_on && m.settled; }

// Settled light-on stamps after `after`, in order.
std::vector<ros::Time> lightOnStamps(const std::vector<CalibrationMode::ConstPtr>& modes, const ros::Time& after) {
  std::vector<ros::Time> stamps;
  for (const auto& m : modes)
    if (calibrating(*m) && m->header.stamp > after) stamps.push_back(m->header.stamp);
  return stamps;
}

// Waits until a complete light-on window (settled light-on frames, then a light-off frame) was
// seen after `after`.
bool waitForWindow(const ros::Time& after, double timeout_s) {
  return fixture->modes.waitFor(
      [&](const std::vector<CalibrationMode::ConstPtr>& modes) {
        bool on = false;
        for (const auto& m : modes) {
          if (m->header.stamp <= after) continue;
          if (calibrating(*m)) on = true;
          if (on && !m->light_on) return true;
        }
        return false;
      },
      timeout_s);
}

struct CornerAgreement {
  size_t truth = 0, matched = 0, extra = 0;
  double squared = 0.0;
  void add(const std::vector<BoardObservation>& found, const std::vector<BoardObservation>& truth_boards) {
    std::map<std::pair<int, int>, std::pair<float, float>> expected;
    for (const auto& b : truth_boards)
      for (size_t i = 0; i < b.corner_ids.size(); ++i) expected[{b.board_id, b.corner_ids[i]}] = {b.u[i], b.v[i]};
    truth += expected.size();
    for (const auto& b : found) {
      for (size_t i = 0; i < b.corner_ids.size(); ++i) {
        const auto it = expected.find({b.board_id, b.corner_ids[i]});
        if (it == expected.end()) {
          ++extra;
          continue;
        }
        ++matched;
        squared += std::pow(b.u[i] - it->second.first, 2) + std::pow(b.v[i] - it->second.second, 2);
      }
    }
  }
  double rms() const { return matched ? std::sqrt(squared / matched) : 0.0; }
  double fraction() const { return truth ? static_cast<double>(matched) / truth : 0.0; }
};

// The prior is written through a temporary file next to it (writeFileAtomically:
// "<file>.tmp.XXXXXX"), renamed over the target: none may be left in `folder` once it is there.
void expectNoTemporaryFilesIn(const std::filesystem::path& folder) {
  std::vector<std::string> leftovers;
  for (const auto& entry : std::filesystem::directory_iterator(folder))
    if (entry.path().filename().string().find(".tmp.") != std::string::npos)
      leftovers.push_back(entry.path().filename().string());
  EXPECT_TRUE(leftovers.empty()) << "temporary files left next to the prior: "
                                 << ::testing::PrintToString(leftovers);
}

// The observations of frames before `end` against ground truth of the same stamp: none for
// light-off or unsettled frames; their corners' agreement to *agreement, frames compared returned.
size_t compareWithTruth(const ros::Time& end, CornerAgreement* agreement) {
  std::map<ros::Time, CalibrationMode::ConstPtr> mode_of;
  for (const auto& m : fixture->modes.snapshot()) mode_of[m->header.stamp] = m;
  std::map<ros::Time, StereoPatternObservation::ConstPtr> truth_of;
  for (const auto& t : fixture->truth.snapshot()) truth_of[t->header.stamp] = t;
  size_t compared = 0;
  for (const auto& o : fixture->observations.snapshot()) {
    if (o->header.stamp >= end) break;
    const auto mode = mode_of.find(o->header.stamp);
    EXPECT_NE(mode, mode_of.end()) << "observation stamp " << o->header.stamp << " is no frame's";
    if (mode == mode_of.end()) continue;
    EXPECT_TRUE(calibrating(*mode->second)) << "observation of a light-off or unsettled frame";
    const auto truth = truth_of.find(o->header.stamp);
    if (truth == truth_of.end()) continue;
    agreement->add(o->left, truth->second->left);
    agreement->add(o->right, truth->second->right);
    ++compared;
  }
  return compared;
}

// Diagnostics report what the last frame found and the time per frame.
void expectDiagnosticsOfCorners() {
  std::map<std::string, std::string> values;
  const bool reported = fixture->diagnostics.waitFor(
      [&](const std::vector<diagnostic_msgs::DiagnosticArray::ConstPtr>& arrays) {
        for (const auto& a : arrays)
          for (const auto& st : a->status) {
            if (st.name.find("stereo/pattern_tracker:") == std::string::npos) continue;
            values.clear();
            for (const auto& kv : st.values) values[kv.key] = kv.value;
            if (values["prior state"] == "loaded" && values["left corners found"] != "0" &&
                values["right corners found"] != "0")
              return true;
          }
        return false;
      },
      3.0);
  std::set<std::string> names;
  for (const auto& a : fixture->diagnostics.snapshot())
    for (const auto& st : a->status) names.insert(st.name + " [" + st.message + "]");
  std::string seen;
  for (const std::string& n : names) seen += n + "; ";
  EXPECT_TRUE(reported) << "no diagnostics with corners found; statuses seen: " << seen;
  std::printf("tracker_sim: diagnostics: left %s boards / %s corners, right %s boards / %s corners, "
              "%s ms last frame, %s ms mean\n",
              values["left boards found"].c_str(), values["left corners found"].c_str(),
              values["right boards found"].c_str(), values["right corners found"].c_str(),
              values["last frame (ms)"].c_str(), values["mean frame (ms)"].c_str());
}

TEST(TrackerSim, TeachesOnStartThenTracksEverySettledLightOnFrame) {
  std::string prior_file;
  ASSERT_TRUE(ros::param::get("~prior_file", prior_file));
  // The launch file's anonymous directory, created by the tracker: removed at the end.
  struct RemoveDir {
    std::filesystem::path path;
    ~RemoveDir() {
      if (path.string().rfind("/tmp/ecs_tracker_sim_test", 0) == 0) std::filesystem::remove_all(path);
    }
  } cleanup{std::filesystem::path(prior_file).parent_path()};
  // First window: teaching; the next one is tracked.
  ASSERT_TRUE(fixture->observations.waitForCount(1, 20.0)) << "no observation within 20 s";
  const ros::Time first = fixture->observations.snapshot().front()->header.stamp;
  core::PatternPrior prior;
  ASSERT_NO_THROW(prior = core::readPatternPrior(prior_file)) << prior_file;
  ASSERT_EQ(prior.cameras.size(), 2u);
  expectNoTemporaryFilesIn(cleanup.path);

  // Two more complete windows after the first observation.
  ASSERT_TRUE(waitForWindow(first, 6.0));
  const ros::Time second_window_end = fixture->modes.snapshot().back()->header.stamp;
  ASSERT_TRUE(waitForWindow(second_window_end, 6.0));
  const ros::Time end = fixture->modes.snapshot().back()->header.stamp;
  std::vector<ros::Time> expected;
  for (const ros::Time& t : lightOnStamps(fixture->modes.snapshot(), first))
    if (t < end) expected.push_back(t);
  ASSERT_GE(expected.size(), 8u);
  // Every settled light-on frame gets its observation (the last ones may still be in flight).
  const bool all = fixture->observations.waitFor(
      [&](const std::vector<StereoPatternObservation::ConstPtr>& obs) {
        std::set<ros::Time> seen;
        for (const auto& o : obs) seen.insert(o->header.stamp);
        for (const ros::Time& t : expected)
          if (!seen.count(t)) return false;
        return true;
      },
      3.0);
  EXPECT_TRUE(all) << "an observation is missing for a settled light-on frame";

  CornerAgreement agreement;
  const size_t compared = compareWithTruth(end, &agreement);
  std::printf("tracker_sim: %zu frames compared with ground truth: %zu of %zu visible corners found (%.1f %%), "
              "RMS %.4f px, %zu corners not in the ground truth\n",
              compared, agreement.matched, agreement.truth, 100.0 * agreement.fraction(), agreement.rms(),
              agreement.extra);
  ASSERT_GE(compared, expected.size() / 2);

  expectDiagnosticsOfCorners();
  EXPECT_LE(agreement.rms(), 0.1);
  EXPECT_GE(agreement.fraction(), 0.95);
  EXPECT_LE(agreement.extra, agreement.matched / 100);
}

TEST(TrackerSim, CorruptPriorIdlesWithAnErrorUntilTeach) {
  test_support::TempDir dir("ecs_tracker_corrupt");
  const std::string prior_file = dir.path + "/prior.yaml";
  std::ofstream(prior_file) << "%YAML:1.0\nformat: \"not a prior\"\ncameras: [ {\n";
  const std::string name = ros::this_node::getNamespace() + "/corrupt_tracker";
  ros::param::set(name + "/prior_file", prior_file);
  ros::param::set(name + "/teach_on_start", false);
  Collector<StereoPatternObservation> observations(fixture->nh, "corrupt/calibration/observations");
  const ros::Time loaded = fixture->modes.snapshot().back()->header.stamp;
  nodelet::Loader loader(false);
  ros::M_string remappings;
  remappings[ros::names::resolve("calibration/observations")] = ros::names::resolve("corrupt/calibration/observations");
  ASSERT_TRUE(loader.load(name, "embedded_calibration_stereo/PatternTracker", remappings, {}));

  std::string error;
  EXPECT_TRUE(test_support::waitForLog(fixture->log, {prior_file, "idle"}, 8.0, &error));
  std::printf("tracker_sim: corrupt prior error: %s\n", error.c_str());
  ASSERT_TRUE(waitForWindow(loaded, 6.0));
  EXPECT_TRUE(observations.snapshot().empty()) << "observations from a corrupt prior";

  ros::ServiceClient teach = fixture->nh.serviceClient<std_srvs::Trigger>(name + "/teach");
  ASSERT_TRUE(teach.waitForExistence(ros::Duration(5.0)));
  std_srvs::Trigger srv;
  ASSERT_TRUE(teach.call(srv));
  EXPECT_TRUE(srv.response.success) << srv.response.message;
  EXPECT_TRUE(observations.waitForCount(3, 15.0)) << "no observations after teach";
  core::PatternPrior prior;
  EXPECT_NO_THROW(prior = core::readPatternPrior(prior_file));
  EXPECT_EQ(prior.cameras.size(), 2u);
  EXPECT_TRUE(loader.unload(name));
}

}  // namespace

int main(int argc, char** argv) {
  return test_support::runTestsWithFixture(argc, argv, "tracker_sim_test", 2, &fixture);
}
