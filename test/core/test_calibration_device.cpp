// Reflection geometry of the device's virtual copies: every virtual corner must be the mirror
// image of its physical corner, with the same id, and virtual poses must stay proper rotations.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>

#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/io/config_io.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace embedded_calibration_stereo::core {
namespace {

CalibrationDevice twoCopyDevice(int planes_per_copy) {
  CalibrationDevice dev;
  for (int i = 0; i < 3; ++i) {
    Chessboard b;
    b.id = i;
    b.cols = 8;
    b.rows = 6;
    b.square = 0.025;
    b.device_from_board.linear() = rotationFromVectorDeg(Eigen::Vector3d(10.0 * i, -20.0 + 20.0 * i, 5));
    b.device_from_board.translation() = Eigen::Vector3d(0.25 * i - 0.25, 0.02 * i, 0.01 * i);
    dev.boards.push_back(b);
  }
  dev.rig_from_device.translation() = Eigen::Vector3d(0, -0.3, 0.05);
  dev.rig_from_device.linear() = rotationFromVectorDeg(Eigen::Vector3d(90, 0, 0));
  for (int c = 0; c < 2; ++c) {
    std::vector<MirrorPlane> chain;
    for (int m = 0; m < planes_per_copy; ++m) {
      MirrorPlane p;
      p.normal = Eigen::Vector3d(0.1 * c - 0.05, 0.7 + 0.1 * m, 0.7 - 0.2 * m).normalized();
      p.distance = 0.4 + 0.05 * m + 0.02 * c;
      chain.push_back(p);
    }
    dev.copies.push_back(chain);
  }
  return dev;
}

TEST(MirrorPlane, ReflectionIsAnInvolution) {
  MirrorPlane p;
  p.normal = Eigen::Vector3d(0.3, -0.4, 0.866).normalized();
  p.distance = 0.7;
  const Eigen::Vector3d x(0.1, 2.0, -0.5);
  EXPECT_LT((p.reflect(p.reflect(x)) - x).norm(), 1e-12);
  // The midpoint of x and its image lies on the plane.
  EXPECT_NEAR(p.normal.dot(0.5 * (x + p.reflect(x))), p.distance, 1e-12);
  const Eigen::Matrix3d linear = p.reflection().topLeftCorner<3, 3>();
  EXPECT_NEAR(linear.determinant(), -1.0, 1e-12);
  const Eigen::Vector4d h = p.reflection() * x.homogeneous();
  EXPECT_LT((h.head<3>() - p.reflect(x)).norm(), 1e-12);
}

class VirtualBoards : public ::testing::TestWithParam<int> {};

TEST_P(VirtualBoards, CornersAreMirrorImagesWithIdsKept) {
  const CalibrationDevice dev = twoCopyDevice(GetParam());
  ASSERT_EQ(dev.validate(), "");
  const std::vector<VirtualBoard> vbs = dev.virtualBoards();
  ASSERT_EQ(vbs.size(), 6u);
  double worst = 0.0;
  for (const VirtualBoard& vb : vbs) {
    EXPECT_EQ(vb.virtual_id, vb.copy_index * 3 + vb.board_index);
    EXPECT_EQ(vb.mirrored, GetParam() % 2 == 1);
    EXPECT_NEAR(vb.rig_from_board.linear().determinant(), 1.0, 1e-9);
    const Chessboard& b = dev.boards[vb.board_index];
    for (int id = 0; id < b.cornerCount(); ++id) {
      Eigen::Vector3d expected = dev.rig_from_device * b.device_from_board * b.cornerInBoard(id);
      for (const MirrorPlane& m : dev.copies[vb.copy_index]) expected = m.reflect(expected);
      worst = std::max(worst, (vb.cornerInRig(id) - expected).norm());
    }
  }
  EXPECT_LT(worst, 1e-12);
}

INSTANTIATE_TEST_SUITE_P(OneAndTwoMirrors, VirtualBoards, ::testing::Values(1, 2));

TEST(CalibrationDevice, ValidateNamesTheField) {
  CalibrationDevice dev = twoCopyDevice(1);
  dev.boards[1].square = 0;
  EXPECT_NE(dev.validate().find("boards[1].square_m"), std::string::npos);
  dev = twoCopyDevice(1);
  dev.copies.clear();
  EXPECT_NE(dev.validate().find("copies"), std::string::npos);
}

TEST(ConfigIo, MissingFileAndBadValuesNameTheParameter) {
  EXPECT_THROW(openYaml("/nonexistent/rig.yaml"), ConfigError);
  cv::FileStorage fs("camera.yaml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY);
  fs << "cam" << "{" << "width" << 752 << "height" << 480 << "fx" << -650.0 << "fy" << 650.0
     << "cx" << 376.0 << "cy" << 240.0 << "}";
  const std::string text = fs.releaseAndGetString();
  cv::FileStorage in(text, cv::FileStorage::READ | cv::FileStorage::MEMORY);
  try {
    loadCamera(in["cam"], "rig.left");
    FAIL() << "a negative fx was accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("rig.left"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("fx"), std::string::npos) << e.what();
  }
  try {
    loadCamera(in["missing"], "rig.right");
    FAIL() << "a missing camera was accepted";
  } catch (const ConfigError& e) {
    EXPECT_EQ(e.parameter(), "rig.right");
  }
}

// The device_config file every nodelet reads: the simulator's loader of the same file is the
// independent reference.
TEST(ConfigIo, ADeviceDescriptionIsTheDeviceAndTheOptionalNominalRig) {
  const std::string file = std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml";
  const DeviceDescription description = loadDeviceDescription(file, "device_config");
  const SimRigConfig sim = loadSimRigConfig(file);
  EXPECT_EQ(description.device.boards.size(), sim.device.boards.size());
  ASSERT_TRUE(description.nominal.has_value());
  EXPECT_EQ(description.nominal->left.fx, sim.rig.left.fx);
  EXPECT_EQ(description.nominal->right_from_left.translation(), sim.rig.right_from_left.translation());
  ASSERT_TRUE(loadNominalRig(file, "device_config").has_value());

  const std::string bare = "/tmp/ecs_test_device_" + std::to_string(::getpid()) + ".yaml";
  std::ofstream(bare) << "%YAML:1.0\nother: 1\n";
  EXPECT_FALSE(loadNominalRig(bare, "device_config").has_value());
  for (const std::string& path : {bare, std::string("/nonexistent/device.yaml")}) {
    try {
      loadDeviceDescription(path, "device_config");
      ADD_FAILURE() << path << ": no device section, accepted";
    } catch (const ConfigError& e) {
      EXPECT_EQ(e.parameter(), "device_config");
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    }
  }
  std::remove(bare.c_str());
}

}  // namespace
}  // namespace embedded_calibration_stereo::core
