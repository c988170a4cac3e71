// rostest: every nodelet refuses a wrongly typed or out-of-range parameter at load time, with a
// FATAL "<Nodelet> cannot start: <parameter>: <problem>" (nodelet_bad_config.test). The same
// parameters with good values load (control), so a refusal is the bad value's doing.
#include <gtest/gtest.h>
#include <nodelet/loader.h>

#include <memory>

#include "driver_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using test_support::Collector;
using Params = std::map<std::string, XmlRpc::XmlRpcValue>;

namespace {

std::unique_ptr<nodelet::Loader> loader;                   // created in main, after ros::init
std::unique_ptr<Collector<rosgraph_msgs::Log>> rosout;     // idem
const test_support::TempDir temp_dir("ecs_nodelet_bad_config");
int loads = 0;

// Parameters each nodelet needs besides the one under test (writable calibration files, no
// prior to teach, ...), all valid.
Params baseParams(const std::string& nodelet) {
  if (nodelet == "CameraDriver")
    return {{"backend", "sim"},
            {"fps", 10.0},
            {"left_camera_info_url", "file://" + temp_dir.path + "/left.yaml"},
            {"right_camera_info_url", "file://" + temp_dir.path + "/right.yaml"}};
  if (nodelet == "PatternTracker")
    return {{"prior_file", temp_dir.path + "/no_prior.yaml"}, {"teach_on_start", false}};
  if (nodelet == "OnlineCalibrator") return {{"commit", "none"}, {"auto_calibrate", false}};
  if (nodelet == "LightController") return {{"light_backend", "none"}, {"prior_file", temp_dir.path + "/no_prior.yaml"}};
  return {};
}

// Sets the private parameters and loads `nodelet` under a fresh name; true when it started.
bool load(const std::string& nodelet, const Params& params, std::string* name) {
  *name = "/bad_config/" + nodelet + "_" + std::to_string(++loads);
  ros::param::del(*name);
  for (const auto& p : params) ros::param::set(*name + "/" + p.first, p.second);
  return loader->load(*name, "embedded_calibration_stereo/" + nodelet, ros::M_string(), std::vector<std::string>());
}

// A FATAL /rosout message containing every needle.
bool waitForFatal(const std::vector<std::string>& needles, double timeout_s, std::string* found) {
  return rosout->waitFor(
      [&](const std::vector<rosgraph_msgs::Log::ConstPtr>& messages) {
        for (const auto& m : messages) {
          if (m->level != rosgraph_msgs::Log::FATAL) continue;
          bool all = true;
          for (const auto& n : needles) all = all && m->msg.find(n) != std::string::npos;
          if (all) {
            *found = m->msg;
            return true;
          }
        }
        return false;
      },
      timeout_s);
}

struct BadConfig {
  std::string nodelet;
  std::string label;  // the test's name
  std::string parameter;
  XmlRpc::XmlRpcValue value;
  std::string problem;  // expected in the message
};

std::ostream& operator<<(std::ostream& out, const BadConfig& c) { return out << c.label; }

const std::vector<std::string> kNodelets = {"CameraDriver", "PatternTracker", "OnlineCalibrator", "Separator",
                                            "Rectifier",    "Disparity",      "LightController",  "CalibrationHealth"};

}  // namespace

// Control: each nodelet starts with its base parameters and with good values of every parameter
// the refusals below use.
TEST(NodeletGoodConfig, EveryNodeletStarts) {
  const std::map<std::string, Params> good = {
      {"CameraDriver", {{"fps", 30}, {"settle_frames", 2}, {"right_in_left_frame", true}}},
      {"PatternTracker", {{"queue_size", 3}, {"teach_on_start", false}}},
      {"OnlineCalibrator",
       {{"min_frames", 5}, {"max_rms_px", 2}, {"min_boards_per_camera", 1}, {"commit", "none"}, {"board_placement", "held"}}},
      {"Separator", {{"queue_size", 1}, {"teach_frames", 1}, {"approximate_sync", true}, {"method", "regional_alpha"},
                     {"teach_from_ground_truth", false}, {"device_template", "learn"}, {"learn_frames_per_end", 4}}},
      {"Rectifier", {{"queue_size", 1}, {"approximate_sync", true}, {"rectification_method", "fusiello"}}},
      {"Disparity", {{"queue_size", 1}, {"approximate_sync", false}, {"disparity_range", 32}, {"uniqueness_ratio", 10}}},
      {"LightController", {{"min_step", 8}, {"max_delay_frames", 0}, {"approximate_sync", false},
                           {"plateau_fraction", 0.1}, {"calibration_store", "driver"},
                           {"calibration_trigger", "on_demand"}, {"verification_period_s", 6.0}}},
      {"CalibrationHealth", {{"depth_rate_hz", 15.0}, {"boards_posed", false}, {"misalignment_degraded_px", 0.1},
                             {"misalignment_bad_px", 0.5}}},
  };
  for (const std::string& nodelet : kNodelets) {
    Params params = baseParams(nodelet);
    for (const auto& p : good.at(nodelet)) params[p.first] = p.second;
    std::string name;
    EXPECT_TRUE(load(nodelet, params, &name)) << nodelet << " refused good parameters";
    loader->unload(name);
  }
}

class NodeletBadConfig : public testing::TestWithParam<BadConfig> {};

TEST_P(NodeletBadConfig, RefusesToStartNamingTheParameter) {
  const BadConfig& c = GetParam();
  Params params = baseParams(c.nodelet);
  params[c.parameter] = c.value;
  rosout->clear();
  std::string name;
  const bool started = load(c.nodelet, params, &name);
  EXPECT_FALSE(started) << c.nodelet << " started with " << c.parameter << " = " << c.value.toXml();
  std::string found;
  EXPECT_TRUE(waitForFatal({c.nodelet + " cannot start: " + c.parameter + ": ", c.problem}, 10.0, &found))
      << "no FATAL message '" << c.nodelet << " cannot start: " << c.parameter << ": ...' with '" << c.problem << "'";
  std::printf("  %s = %s -> \"%s\"\n", c.parameter.c_str(), c.value.toXml().c_str(), found.c_str());
  if (started) loader->unload(name);
}

INSTANTIATE_TEST_SUITE_P(
    AllNodelets, NodeletBadConfig,
    testing::Values(
        BadConfig{"CameraDriver", "DriverFpsText", "fps", "fast", "must be a number"},
        BadConfig{"CameraDriver", "DriverFpsRange", "fps", 5000.0, "(0, 1000]"},
        BadConfig{"CameraDriver", "DriverSettleFramesDouble", "settle_frames", 2.0, "must be an integer"},
        BadConfig{"CameraDriver", "DriverRightInLeftFrameText", "right_in_left_frame", "yes", "must be true or false"},
        BadConfig{"PatternTracker", "TrackerQueueSizeText", "queue_size", "five", "must be an integer"},
        BadConfig{"PatternTracker", "TrackerQueueSizeRange", "queue_size", 0, "must be >= 1"},
        BadConfig{"PatternTracker", "TrackerTeachOnStartInt", "teach_on_start", 1, "must be true or false"},
        BadConfig{"PatternTracker", "TrackerDeviceConfigInt", "device_config", 5, "must be a string"},
        BadConfig{"PatternTracker", "TrackerTeachFromChoice", "teach_from", "covered", "burst or light_off"},
        BadConfig{"OnlineCalibrator", "CalibratorMinFramesDouble", "min_frames", 5.0, "must be an integer"},
        BadConfig{"OnlineCalibrator", "CalibratorMaxRmsText", "max_rms_px", "big", "must be a number"},
        BadConfig{"OnlineCalibrator", "CalibratorMinBoardsRange", "min_boards_per_camera", 0, "must be >= 1"},
        BadConfig{"OnlineCalibrator", "CalibratorCommitChoice", "commit", "bag", "'bag'"},
        BadConfig{"OnlineCalibrator", "CalibratorBoardPlacementChoice", "board_placement", "free",
                  "held, refined or tested, got 'free'"},
        BadConfig{"OnlineCalibrator", "CalibratorSceneTestRange", "scene_test_probability", 0.7, "must be in [0, 0.5]"},
        BadConfig{"Separator", "SeparatorQueueSizeText", "queue_size", "five", "must be an integer"},
        BadConfig{"Separator", "SeparatorTeachFramesRange", "teach_frames", 0, "must be >= 1"},
        BadConfig{"Separator", "SeparatorApproximateSyncText", "approximate_sync", "yes", "must be true or false"},
        BadConfig{"Separator", "SeparatorTeachFromTruthInt", "teach_from_ground_truth", 1, "must be true or false"},
        BadConfig{"Separator", "SeparatorMethodChoice", "method", "magic", "magic"},
        BadConfig{"Separator", "SeparatorDeviceTemplateChoice", "device_template", "covered", "covered"},
        BadConfig{"Separator", "SeparatorLearnFramesPerEndRange", "learn_frames_per_end", 0, "must be in [1, 30]"},
        BadConfig{"Rectifier", "RectifierQueueSizeDouble", "queue_size", 2.5, "must be an integer"},
        BadConfig{"Rectifier", "RectifierQueueSizeRange", "queue_size", 0, "must be >= 1"},
        BadConfig{"Rectifier", "RectifierApproximateSyncInt", "approximate_sync", 1, "must be true or false"},
        BadConfig{"Rectifier", "RectifierMethodChoice", "rectification_method", "zigzag", "zigzag"},
        BadConfig{"Disparity", "DisparityQueueSizeText", "queue_size", "five", "must be an integer"},
        BadConfig{"Disparity", "DisparityQueueSizeRange", "queue_size", -1, "must be >= 1"},
        BadConfig{"Disparity", "DisparityApproximateSyncText", "approximate_sync", "true", "must be true or false"},
        BadConfig{"Disparity", "DisparityRangeText", "disparity_range", "sixty", "must be an integer"},
        BadConfig{"Disparity", "DisparitySubpixelInt", "subpixel", 1, "must be true or false"},
        BadConfig{"LightController", "LightControllerBackendChoice", "light_backend", "laser", "laser"},
        BadConfig{"LightController", "LightControllerMinStepText", "min_step", "big", "must be a number"},
        BadConfig{"LightController", "LightControllerMaxDelayRange", "max_delay_frames", -1, "must be >= 0"},
        BadConfig{"LightController", "LightControllerPlateauFractionRange", "plateau_fraction", 0.9, "(0, switch_fraction)"},
        BadConfig{"LightController", "LightControllerApproximateSyncInt", "approximate_sync", 1, "must be true or false"},
        BadConfig{"LightController", "LightControllerStoreChoice", "calibration_store", "cloud", "cloud"},
        BadConfig{"LightController", "LightControllerTriggerChoice", "calibration_trigger", "hourly", "hourly"},
        BadConfig{"LightController", "LightControllerVerificationRange", "verification_period_s", -1.0, "must be >= 0"},
        BadConfig{"CalibrationHealth", "HealthDepthRateRange", "depth_rate_hz", -1.0, "must be in [0, 1000]"},
        BadConfig{"CalibrationHealth", "HealthEveryNRenamed", "depth_every_n_frames", 2, "replaced by depth_rate_hz"},
        BadConfig{"CalibrationHealth", "HealthBoardsPosedInt", "boards_posed", 1, "must be true or false"},
        BadConfig{"CalibrationHealth", "HealthBadBelowDegraded", "misalignment_bad_px", 0.01, "must be >= 0.08"}),
    [](const testing::TestParamInfo<BadConfig>& info) { return info.param.label; });

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "nodelet_bad_config_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  ros::NodeHandle nh;
  rosout = std::make_unique<Collector<rosgraph_msgs::Log>>(nh, "/rosout", 1000);
  loader = std::make_unique<nodelet::Loader>(false);
  const int result = RUN_ALL_TESTS();
  loader.reset();
  rosout.reset();
  return result;
}
