#pragma once
// A fresh folder under /tmp for one gtest, removed with everything in it when the test ends.
// Header-only (gtest's EXPECT): for gtests.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <filesystem>
#include <string>

namespace embedded_calibration_stereo::test_support {

struct TempDir {
  // `prefix`: the folder's name before its random suffix ("ecs_light_regions").
  explicit TempDir(const std::string& prefix) {
    std::string name = "/tmp/" + prefix + "_XXXXXX";
    EXPECT_NE(::mkdtemp(name.data()), nullptr);
    path = name;
  }
  ~TempDir() { std::filesystem::remove_all(path); }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  std::string path;
};

}  // namespace embedded_calibration_stereo::test_support
