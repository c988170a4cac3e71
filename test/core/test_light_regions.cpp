// Where the LightController confirms its light (core/light/light_regions.h): the prior
// file's board regions are re-read when the file changes and refused when unusable; the whole
// image decides until the taught regions have seen a switch; regions of another image size are
// not used.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <optional>
#include <thread>
#include <vector>

#include "embedded_calibration_stereo/core/light/light_regions.h"
#include "embedded_calibration_stereo/core/tracker/board_prior.h"
#include "embedded_calibration_stereo/temp_dir.h"

namespace core = embedded_calibration_stereo::core;
namespace test_support = embedded_calibration_stereo::test_support;

namespace {

constexpr int kWidth = 320, kHeight = 240;

// A fresh folder per test.
struct TempDir : test_support::TempDir {
  TempDir() : test_support::TempDir("ecs_light_regions") {}
};

// One camera with one 4 x 3 board whose outer corners span (x0, y0) .. (x0 + 60, y0 + 40).
core::CameraPrior cameraPrior(const std::string& name, double x0, double y0) {
  core::CameraPrior c;
  c.name = name;
  c.width = kWidth;
  c.height = kHeight;
  c.taught_frames = 1;
  core::BoardPrior b;
  b.board_id = 1;
  b.cols = 4;
  b.rows = 3;
  b.outer_mean = (cv::Mat_<double>(1, 8) << x0, y0, x0 + 60, y0, x0 + 60, y0 + 40, x0, y0 + 40);
  b.outer_sigma = cv::Mat(1, 0, CV_64F);
  for (int r = 0; r < b.rows; ++r)
    for (int col = 0; col < b.cols; ++col) b.offsets.emplace_back(0.0f, 0.0f);
  b.contrast = 100;
  b.square_px = 20;
  c.boards.push_back(b);
  return c;
}

// The file system's time stamps may be coarse: a rewrite must show a new one.
void rewrite(const std::string& path, const core::PatternPrior& prior) {
  const auto before = std::filesystem::exists(path) ? std::filesystem::last_write_time(path)
                                                    : std::filesystem::file_time_type::min();
  for (int i = 0; i < 200; ++i) {
    core::writePatternPrior(path, prior);
    if (std::filesystem::last_write_time(path) != before) return;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  FAIL() << "no new time stamp on " << path;
}

// A frame of both cameras: `base` grey everywhere, plus `device` inside the rectangle
// (100, 80) .. (160, 120) (the board's region).
cv::Mat frame(double base, double device) {
  cv::Mat image(kHeight, kWidth, CV_8UC1, cv::Scalar(base));
  image(cv::Rect(100, 80, 60, 40)).setTo(cv::Scalar(base + device));
  return image;
}

}  // namespace

TEST(BoardRegionsFile, ReadsAtFirstAndAgainOnlyWhenTheFileChanges) {
  TempDir dir;
  const std::string path = dir.path + "/prior.yaml";
  core::BoardRegionsFile file(path, 1.0);
  EXPECT_TRUE(file.refresh()) << "the first call reads (here: no file)";
  EXPECT_FALSE(file.taught());
  EXPECT_EQ(file.problem(), "");
  EXPECT_FALSE(file.refresh()) << "still no file: nothing new";

  rewrite(path, core::PatternPrior{{cameraPrior("left", 100, 80), cameraPrior("right", 90, 80)}});
  EXPECT_TRUE(file.refresh()) << "a file that appeared was not read";
  ASSERT_TRUE(file.taught());
  EXPECT_EQ(file.problem(), "");
  EXPECT_EQ(file.mask(0).size(), cv::Size(kWidth, kHeight));
  EXPECT_GT(file.mask(0).at<uint8_t>(100, 130), 0) << "the board's middle is in its region";
  EXPECT_EQ(file.mask(0).at<uint8_t>(10, 10), 0) << "a far corner of the image is not";
  EXPECT_FALSE(file.refresh()) << "an unchanged file was read again";

  // One camera only: unusable, said why, no regions.
  rewrite(path, core::PatternPrior{{cameraPrior("left", 100, 80)}});
  EXPECT_TRUE(file.refresh()) << "a changed file was not read";
  EXPECT_FALSE(file.taught());
  EXPECT_NE(file.problem().find("expected 2 cameras"), std::string::npos) << file.problem();

  std::filesystem::remove(path);
  EXPECT_TRUE(file.refresh()) << "a file that went away was not noticed";
  EXPECT_FALSE(file.taught());
  EXPECT_EQ(file.problem(), "");
}

// The device is lit only inside its regions, too small a part of the image for the whole-image
// level to step by min_step: only the regions see the light, and once they have seen it switch
// they decide.
TEST(DeviceLightConfirmer, TheTaughtRegionsDecideOnceTheyHaveSeenASwitch) {
  cv::Mat mask = cv::Mat::zeros(kHeight, kWidth, CV_8UC1);
  mask(cv::Rect(100, 80, 60, 40)).setTo(255);
  core::DeviceLightConfirmer confirmer{core::LightConfirmationOptions()};
  confirmer.setRegions(mask, mask);
  EXPECT_TRUE(confirmer.hasRegions());
  EXPECT_FALSE(confirmer.regionsInUse()) << "new regions know nothing before a switch";
  std::vector<std::optional<core::ConfirmedLight>> decided;
  for (int i = 0; i < 12; ++i) {
    const double device = i < 5 ? 0.0 : 40.0;
    decided.push_back(confirmer.push(frame(50, device), frame(50, device)));
  }
  EXPECT_TRUE(confirmer.regionsInUse());
  // decided[i] is frame i - 1: frames 6 .. 10 are settled and lit.
  for (int i = 7; i < 12; ++i) {
    ASSERT_TRUE(decided[i]) << i;
    EXPECT_TRUE(decided[i]->settled) << "frame " << i - 1;
    EXPECT_TRUE(decided[i]->light_on) << "frame " << i - 1 << ": the whole image decided instead of the regions";
  }
  EXPECT_GT(confirmer.inUse().left().step(), 30.0) << "the regions' step is the one in use";
}

// Regions taught while the light is on start knowing nothing: the whole image, which saw the
// light switch on, keeps deciding (no guess that the first plateau of the regions is "off").
TEST(DeviceLightConfirmer, NewRegionsNeverGuessTheState) {
  cv::Mat mask = cv::Mat::zeros(kHeight, kWidth, CV_8UC1);
  mask(cv::Rect(100, 80, 60, 40)).setTo(255);
  core::DeviceLightConfirmer confirmer{core::LightConfirmationOptions()};
  for (int i = 0; i < 10; ++i) {
    const double lit = i < 4 ? 0.0 : 40.0;  // the whole image steps with the light
    confirmer.push(frame(50 + lit, 0), frame(50 + lit, 0));
  }
  confirmer.setRegions(mask, mask);
  for (int i = 0; i < 6; ++i) {
    const std::optional<core::ConfirmedLight> light = confirmer.push(frame(90, 0), frame(90, 0));
    ASSERT_TRUE(light) << i;
    EXPECT_TRUE(light->light_on) << "frame " << i << " after new regions: the state was guessed";
  }
  EXPECT_FALSE(confirmer.regionsInUse());
}

// Regions taught on another camera mode (another image size) are not used: the levels are
// taken over the whole image, which sees the light.
TEST(DeviceLightConfirmer, RegionsOfAnotherImageSizeAreNotUsed) {
  cv::Mat small = cv::Mat::zeros(kHeight / 2, kWidth / 2, CV_8UC1);
  small(cv::Rect(0, 0, 20, 20)).setTo(255);
  core::DeviceLightConfirmer confirmer{core::LightConfirmationOptions()};
  confirmer.setRegions(small, small);
  EXPECT_FALSE(confirmer.fits(0, cv::Size(kWidth, kHeight)));
  EXPECT_TRUE(confirmer.fits(0, cv::Size(kWidth / 2, kHeight / 2)));
  std::optional<core::ConfirmedLight> last;
  for (int i = 0; i < 12; ++i) {
    const double lit = i < 5 ? 0.0 : 40.0;
    ASSERT_NO_THROW(last = confirmer.push(frame(50 + lit, 0), frame(50 + lit, 0))) << i;
  }
  ASSERT_TRUE(last);
  EXPECT_TRUE(last->light_on && last->settled);
  EXPECT_TRUE(confirmer.regionsInUse()) << "the whole-image levels of the regions' confirmation saw the switch";
  EXPECT_TRUE(core::DeviceLightConfirmer(core::LightConfirmationOptions()).fits(0, cv::Size(1, 1)))
      << "without regions every size fits";
}
