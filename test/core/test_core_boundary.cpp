// The core library's boundary: every file under src/core and include/.../core includes only the
// standard library, POSIX, OpenCV, Eigen, Ceres and the core itself. A ROS header, a message
// header or one of our ROS glue headers in the core fails this test (the build also gives the core
// no ROS include path; see CMakeLists.txt).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

const fs::path kSource = ECS_SOURCE_DIR;

std::vector<fs::path> coreFiles() {
  std::vector<fs::path> files;
  for (const fs::path root :
       {kSource / "src/core", kSource / "include/embedded_calibration_stereo/core"})
    for (const auto& entry : fs::recursive_directory_iterator(root))
      if (entry.is_regular_file()) files.push_back(entry.path());
  return files;
}

bool startsWith(const std::string& s, const std::string& prefix) {
  return s.compare(0, prefix.size(), prefix) == 0;
}

// Empty when the include may stand in a core file; otherwise why not.
std::string includeProblem(const fs::path& file, char delimiter, const std::string& name) {
  if (delimiter == '"') {
    // Quoted: a core header by its full name, or a private header beside the including file.
    if (startsWith(name, "embedded_calibration_stereo/core/") &&
        fs::exists(kSource / "include" / name))
      return "";
    if (name.find("..") == std::string::npos && fs::exists(file.parent_path() / name)) return "";
    return "not a core header";
  }
  for (const char* allowed : {"opencv2/", "Eigen/", "unsupported/Eigen/", "ceres/", "sys/"})
    if (startsWith(name, allowed)) return "";
  // Standard C++ and C headers have no folder (<vector>, <cmath>, <unistd.h>, <immintrin.h>).
  if (name.find('/') == std::string::npos) return "";
  return "outside the standard library, POSIX, OpenCV, Eigen and Ceres";
}

}  // namespace

TEST(CoreBoundaryTest, CoreFilesIncludeNoRosOrMessageHeader) {
  const std::regex include_line(R"(^\s*#\s*include\s*([<"])([^>"]+)[>"])");
  int files = 0, includes = 0;
  for (const fs::path& file : coreFiles()) {
    ++files;
    std::ifstream in(file);
    std::string line;
    for (int number = 1; std::getline(in, line); ++number) {
      std::smatch m;
      if (!std::regex_search(line, m, include_line)) continue;
      ++includes;
      const std::string problem = includeProblem(file, m[1].str()[0], m[2].str());
      EXPECT_TRUE(problem.empty()) << file.lexically_relative(kSource).string() << ":" << number
                                   << " includes " << m[2] << ": " << problem;
    }
  }
  // The walk itself must have found the core, or the test would pass on nothing.
  EXPECT_GT(files, 60);
  EXPECT_GT(includes, 300);
}

// The rule itself, on names a core file must never include and on ones it may.
TEST(CoreBoundaryTest, RuleRefusesRosAndMessageHeaders) {
  const fs::path file = kSource / "src/core/depth/disparity.cpp";
  for (const char* bad :
       {"ros/ros.h", "sensor_msgs/CameraInfo.h", "cv_bridge/cv_bridge.h", "image_geometry/stereo_camera_model.h",
        "tf2_ros/transform_broadcaster.h"})
    EXPECT_FALSE(includeProblem(file, '<', bad).empty()) << bad;
  for (const char* bad : {"embedded_calibration_stereo/CalibrationStatus.h",
                          "embedded_calibration_stereo/ros/conversions.h", "ros/ros.h"})
    EXPECT_FALSE(includeProblem(file, '"', bad).empty()) << bad;
  EXPECT_TRUE(includeProblem(file, '<', "opencv2/core.hpp").empty());
  EXPECT_TRUE(includeProblem(file, '<', "vector").empty());
  EXPECT_TRUE(includeProblem(file, '"', "embedded_calibration_stereo/core/depth/disparity.h").empty());
  EXPECT_TRUE(includeProblem(file, '"', "parallel_pieces.h").empty());
}
