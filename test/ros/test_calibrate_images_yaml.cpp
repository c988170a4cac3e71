// The camera files calibrate_images writes (core/camera_info_yaml.h, written without ROS) are
// read back by camera_calibration_parsers - what camera_info_manager uses - field for field.
#include <camera_calibration_parsers/parse.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

#include "embedded_calibration_stereo/core/io/camera_info_yaml.h"
#include "embedded_calibration_stereo/core/io/config_io.h"

namespace core = embedded_calibration_stereo::core;

namespace {

TEST(CalibrateImagesYaml, CameraCalibrationParsersReadsEveryField) {
  const cv::FileStorage config =
      core::openYaml(std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml");
  const core::StereoRig rig = core::loadStereoRig(config["rig"], "rig");
  const core::RectificationGeometry geometry =
      core::computeRectificationGeometry(rig, core::RectificationOptions{});
  const auto files = core::stereoCameraInfoFiles(rig, geometry, "narrow_stereo/left", "right");
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    ("ecs_calibrate_images_yaml_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  for (const core::CameraInfoFile* file : {&files.first, &files.second}) {
    const std::string path = (dir / "camera.yaml").string();
    core::writeFileAtomically(path, core::cameraInfoYaml(*file));
    std::string name;
    sensor_msgs::CameraInfo info;
    ASSERT_TRUE(camera_calibration_parsers::readCalibration(path, name, info));
    EXPECT_EQ(name, file->camera_name);
    EXPECT_EQ(static_cast<int>(info.width), file->image_width);
    EXPECT_EQ(static_cast<int>(info.height), file->image_height);
    EXPECT_EQ(info.distortion_model, "plumb_bob");
    ASSERT_EQ(info.D.size(), file->D.size());
    for (size_t i = 0; i < info.D.size(); ++i) EXPECT_DOUBLE_EQ(info.D[i], file->D[i]);
    for (int i = 0; i < 9; ++i) {
      EXPECT_DOUBLE_EQ(info.K[i], file->K.val[i]) << i;
      EXPECT_DOUBLE_EQ(info.R[i], file->R.val[i]) << i;
    }
    for (int i = 0; i < 12; ++i) EXPECT_DOUBLE_EQ(info.P[i], file->P.val[i]) << i;
  }
  // The right camera's P carries Tx = -fx' * baseline, as stereo_image_proc expects.
  EXPECT_NEAR(-files.second.P(0, 3) / files.second.P(0, 0), rig.baseline(), 1e-12);
  std::filesystem::remove_all(dir);
}

}  // namespace
