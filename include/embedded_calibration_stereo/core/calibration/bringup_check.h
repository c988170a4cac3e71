#pragma once
// The bring-up check of a newly built head (docs/bringup.md): from a short recording of the
// head standing still, the figures the self-calibration depends on and a verdict, ready or not
// and why. The tool (src/tools/bringup_check.cpp) reads the recording and hands each image here.
//
// What is checked, and why each matters:
// - Left/right stamps: every stereo frame must pair a left and a right image exposed together;
//   the graph pairs them by stamp, and the calibration assumes the two exposures see one world.
// - The exposure: the boards' brightness is divided by the scene's changes outside them, so that
//   an auto-exposure answering the light is not taken for the light.
// - The light's timing: frames taken while the light changes must never be used; the driver
//   marks the frames after a switch unsettled for as many frames as it is told, so the light must
//   be fully on (off) by then, and both cameras must see each switch in the same stereo frame.
// - Each board's visibility and contrast in both cameras: the lit image minus the unlit one
//   inside the board's outline, projected from the device description, in blocks of 2x2 squares.
// - Clipped exposure: pixels at full scale (or zero) in the boards on lit frames move corners.
//
// Threading: plain functions and values.
#include <opencv2/core.hpp>
#include <string>
#include <utility>
#include <vector>

#include "embedded_calibration_stereo/core/geometry/calibration_device.h"
#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

struct BringupThresholds {
  double max_stamp_offset_s = 0.001;  // |right - left| stamp of one stereo frame
  double min_paired_fraction = 0.98;  // of the left images that find their right image
  double min_board_contrast = 20.0;   // lit white minus lit black square, grey levels
  double min_board_seen = 0.9;        // fraction of a board's blocks showing that contrast
  double max_clipped_fraction = 0.01; // of the boards' pixels at 0 or full scale, lit frames
  double full_fraction = 0.9;         // of the light's step: the light is fully on (1 - it: off)
  std::string validate() const;
};

// --- Stamps -------------------------------------------------------------------------------------
struct StampPairing {
  std::vector<std::pair<int, int>> pairs;  // (left index, right index), in time order
  int left_frames = 0, right_frames = 0;
  double frame_period_s = 0.0;      // median of the left stamps' steps
  double median_offset_s = 0.0;     // right stamp - left stamp, over the pairs
  double max_abs_offset_s = 0.0;
};
// Pairs each left stamp with the nearest right stamp within half a frame period (each right
// stamp used once). Stamps in seconds, each list increasing.
StampPairing pairStereoStamps(const std::vector<double>& left, const std::vector<double>& right);

// --- Where the boards appear ------------------------------------------------------------------
struct BoardRegion {
  int board_id = 0;                            // the virtual board's id (observations' board_id)
  std::vector<cv::Point2f> outline;            // the board's squares, pixels
  std::vector<cv::Point2f> surround;           // two squares wider: its white margin and the blur
  std::vector<std::vector<cv::Point2f>> blocks;  // blocks of 2x2 squares inside the corner grid
  double inside_fraction = 0.0;                // of its corners projected inside the image
};
// Every virtual board of `device` as one camera of `rig` should see it (raw pixels).
std::vector<BoardRegion> projectBoardRegions(const CalibrationDevice& device, const StereoRig& rig,
                                             bool right_camera);
// The union of the outlines (or of the surrounds) (CV_8UC1, 255 inside) in an image of `size`.
cv::Mat boardOutlineMask(const std::vector<BoardRegion>& regions, cv::Size size, bool surround = false);

// --- Per image ---------------------------------------------------------------------------------
struct ImageLevels {
  double device_level = 0.0;      // mean grey level inside the boards' outlines
  double clipped_fraction = 0.0;  // of those pixels at 0 or 255
  double scene_level = 0.0;       // mean grey level outside the surrounds: the scene alone
};
// `grey`: CV_8UC1; `mask`, `surround`: boardOutlineMask of the same size (outlines, surrounds).
ImageLevels measureImage(const cv::Mat& grey, const cv::Mat& mask, const cv::Mat& surround);

// The boards' levels with the exposure's changes taken out (an auto-exposure answering the
// light): each level scaled by the median of the scene's levels over its frame's scene level.
// For a still head: a moving scene's own changes would be taken for the exposure's.
std::vector<double> withoutExposureChanges(const std::vector<double>& device_level,
                                           const std::vector<double>& scene_level);

// --- The light ---------------------------------------------------------------------------------
// What the driver said of a frame (calibration_mode); known false without it.
struct FrameMode {
  bool known = false;
  bool light_on = false;
  bool settled = false;
};

struct LightSwitch {
  bool rise = true;
  int command_frame = -1;   // first frame whose mode says the new state (-1: no mode)
  int settled_frame = -1;   // first settled frame in the new state (-1: no mode)
  int change_frame = 0;     // first stereo frame either camera shows changing
  int done_frame = 0;       // first stereo frame both cameras show fully in the new state
  int left_middle = 0, right_middle = 0;  // first frame past half the step, per camera
};

struct LightTiming {
  bool switched = false;                  // a step was seen in both cameras
  double left_step = 0.0, right_step = 0.0;  // grey levels, lit minus unlit
  std::vector<double> left_fraction, right_fraction;  // per stereo frame: 0 unlit .. 1 lit
  std::vector<LightSwitch> switches;
  int settled_wrong = 0;    // settled frames not fully in their mode's state (either camera)
  std::vector<int> settled_wrong_frames;  // which (stereo frames), in order
  int settled_frames = 0;   // settled frames with a mode
  int split_switches = 0;   // switches the two cameras see in different stereo frames
};
// Levels per stereo frame (left, right) and the mode of each (an empty `modes`: none).
LightTiming analyseLight(const std::vector<double>& left_level, const std::vector<double>& right_level,
                         const std::vector<FrameMode>& modes, const BringupThresholds& thresholds);

// --- The boards --------------------------------------------------------------------------------
struct BoardVisibility {
  int board_id = 0;
  double inside_fraction = 0.0;  // of its corners in the image (description)
  double contrast = 0.0;         // median over its blocks in the image, grey levels
  double seen_fraction = 0.0;    // of its blocks in the image with at least min_board_contrast
};
// `lit_minus_unlit`: CV_32FC1, the mean lit image minus the mean unlit one of one camera.
std::vector<BoardVisibility> measureBoards(const cv::Mat& lit_minus_unlit, const std::vector<BoardRegion>& regions,
                                           const BringupThresholds& thresholds);

// --- The verdict -------------------------------------------------------------------------------
struct BringupMeasurements {
  StampPairing stamps;
  LightTiming light;
  bool has_modes = false;
  std::vector<BoardVisibility> boards[2];  // left, right
  double clipped_fraction[2] = {0.0, 0.0};  // mean over the fully lit frames
  int clipped_frames[2] = {0, 0};           // lit frames above max_clipped_fraction
  int lit_frames = 0, unlit_frames = 0;     // fully lit and fully unlit stereo frames
};

struct BringupVerdict {
  bool ready = false;
  std::vector<std::string> reasons;  // each problem in words, with its figure
};
BringupVerdict judgeBringup(const BringupMeasurements& m, const BringupThresholds& thresholds);

}  // namespace embedded_calibration_stereo::core
