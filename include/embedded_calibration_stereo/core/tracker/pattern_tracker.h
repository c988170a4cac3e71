#pragma once
// Prior-based chessboard corner tracker for the embedded calibration device (ROS-free).
//
// Every (virtual) board of a camera is tracked from where it was last seen (or, at first, from
// the taught prior, see board_prior.h):
//   1. predict every corner: homography of the board grid + per-corner offsets that absorb the
//      lens distortion (learned when teaching, updated by tracking);
//   2. re-centre: correlate the expected checker/margin brightness pattern (box samples at the
//      square centres, each minus its four neighbours, so that a scene that varies over more than
//      a square cancels) over a +-search_radius_px window, so that a zoom step or a knock that
//      moves the board by more than a refinement window is followed without slipping a square
//      (steady state: only the score at the last position is checked; the full search runs when
//      it dropped below 85% of the last frame's, or when the board was not found that way);
//   3. refine each corner with cv::cornerSubPix in a small window;
//   4. accept a corner only if its saddle has the expected polarity and enough contrast (absolute
//      and relative to the taught contrast: this is what makes a light-off frame or an occluded
//      region give no corners) and it agrees with a homography re-fitted to the accepted corners;
//   5. re-predict the rejected corners from the re-fitted homography and refine again, until the
//      accepted set is stable or max_iterations is reached.
// With a scene background (setBackground: a light-off frame, see scene_background.h) steps 1-5
// run on light-on minus background, which removes the scene's pull on the refinement; the
// background follows zoom steps and knocks by re-registration (the frame is then re-tracked;
// a resampled background is less exact than a fresh light-off frame, see scene_background.h).
// Without a still scene (no background, or one taken before the head or the scene moved, which
// track() detects from what remains of the scene in the difference away from the boards):
// steps 1-5 run on the raw image, where the scene's texture pulls each refined corner by a few
// tenths of a pixel. Each board is then aligned as a whole (board_alignment.h): the taught board,
// moved by one homography, is fitted photometrically to every pixel near an edge of its pattern,
// so the scene, uncorrelated with the pattern, averages out. The alignment starts from last
// frame's (steady state: steps 3-5 are skipped while it converges there), from the refined
// corners (which it must agree with), or, when the scene hides too many saddles, from the
// re-centred prediction (coarse to fine; it must stay within a fraction of a square of it): this
// verifies the board's geometry, so no square can slip. A corner is reported where the contrast
// fitted on its own samples is at least half the board's.
// Corner ids come from the grid, so partial boards (occlusion, a board leaving the image) keep
// correct ids; a board with fewer than the minimum number of accepted corners gives nothing and
// keeps its previous state.
//
// Threading: a CameraTracker is used by one thread at a time; inside it the boards are tracked
// with cv::parallel_for_ (each board task reads the image and writes only its own board state).
// A CameraTracker shares nothing mutable with another, so PatternTracker tracks the two cameras
// in parallel (cv::parallel_for_ over cameras) and a caller may use two threads as well.
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/tracker/board_prior.h"
#include "embedded_calibration_stereo/core/geometry/observation.h"
#include "embedded_calibration_stereo/core/tracker/scene_background.h"

namespace embedded_calibration_stereo::core {
namespace tracker {
struct AlignmentTemplate;
struct AlignmentResult;
}
}  // namespace embedded_calibration_stereo::core

namespace embedded_calibration_stereo::core {

struct TrackerOptions {
  // Half-size of the cv::cornerSubPix window; 0 = automatic: on the background difference 0.6
  // square clamped to [2, 7], on the raw image 0.4 square clamped to [2, 5].
  int window_radius_px = 0;
  // Re-centring search half-width (px): covers a 3% zoom step or a 0.5 deg knock at 752x480.
  double search_radius_px = 16.0;
  // Saddle contrast acceptance: at least this many grey levels ...
  double min_contrast = 6.0;
  // ... and at least this fraction of the contrast measured when teaching.
  double relative_contrast = 0.3;
  // Largest distance (px) of an accepted corner from the re-fitted board model, with a scene
  // background and without one (then the scene's texture moves corners by a few tenths of a px).
  double max_residual_px = 0.5;
  double max_residual_no_background_px = 0.75;
  // Largest distance (px) cornerSubPix may move a corner from its prediction, as a fraction of
  // the window radius.
  double max_refine_shift = 1.0;
  // Predict / refine / re-fit rounds per board and frame.
  int max_iterations = 3;
  // A board counts as found with at least max(min_board_corners, min_board_fraction * corners
  // predicted inside the image) accepted corners.
  int min_board_corners = 6;
  double min_board_fraction = 0.25;
  // Minimum normalised correlation of the re-centring pattern (rejects light-off frames early).
  double min_pattern_score = 0.3;
  // Weight of a new frame in the running per-corner offsets (lens distortion), 0 = frozen.
  double offset_update_rate = 0.2;
  // RMS corner motion (px) since the background was registered above which it is re-registered.
  double background_motion_px = 0.1;
  // Gaussian sigma (px) applied to the light-on minus background difference (0 = none).
  double difference_smoothing_px = 1.5;
  // Without a usable background: refine each found board by photometric alignment of the whole
  // board (see "Without a still scene" above) and report the aligned corners.
  bool whole_board_alignment = true;
  // Standard deviation (px) of the edge blur the alignment's pattern model assumes (lens PSF and
  // pixel area); a mismatch costs precision, not accuracy (the blur is symmetric).
  double alignment_blur_px = 1.2;
  // Robust spread (grey levels) of light-on minus background away from the boards above which the
  // background no longer shows the current scene (the head or the scene moved since the light-off
  // frame): it is then not used for this frame.
  double stale_background_level = 2.5;
  // Track boards and cameras in parallel (cv::parallel_for_).
  bool parallel = true;
  // Empty when usable; otherwise a message naming the bad field.
  std::string validate() const;
};

// Pixel order of 3-channel input. Mono8 (CV_8UC1) input ignores it.
enum class ColorOrder { kBgr, kRgb };

// Converts CV_8UC1 / CV_8UC3 to a grey image (shares the data for CV_8UC1); throws
// std::invalid_argument naming the type for anything else (e.g. "unsupported image type 16UC1").
cv::Mat toGrayImage(const cv::Mat& image, ColorOrder order = ColorOrder::kBgr);

// What happened to one board in the last frame (diagnostics, CLI summary, tests).
struct BoardTrackStats {
  int board_id = 0;
  int predicted = 0;  // corners predicted inside the image
  int found = 0;      // corners reported
  double pattern_score = 0.0;
  cv::Point2f recentre_shift;    // px, from the re-centring search
  bool wide_search = false;      // the full search window was needed (first frame, a jump)
  double rms_residual_px = 0.0;  // of the reported corners to the re-fitted model
  // Distance (px, RMS over the 4 outer corners) of the tracked board from the taught prior's
  // mean + modes: grows with drift beyond what was taught.
  double prior_deviation_px = 0.0;
  bool aligned = false;  // the whole-board alignment set the reported corners
};

class CameraTracker {
 public:
  CameraTracker(CameraPrior prior, TrackerOptions options);

  // Tracks every board in one image (CV_8UC1 or CV_8UC3).
  std::vector<BoardCorners> track(const cv::Mat& image, ColorOrder order = ColorOrder::kBgr);
  // Forget the tracked state: the next frame starts from the prior again (keeps the background).
  void reset();
  // A light-off frame of this camera (same size as the tracked frames), or clear it.
  void setBackground(const cv::Mat& light_off, ColorOrder order = ColorOrder::kBgr);
  void clearBackground() {
    background_.clear();
    background_known_stale_ = false;
  }
  const SceneBackground& background() const { return background_; }
  // Robust spread (grey levels) of the last difference away from the boards, and whether it made
  // the background count as stale (see TrackerOptions::stale_background_level); 0/false without one.
  double lastBackgroundResidual() const { return background_residual_; }
  bool lastBackgroundStale() const { return background_stale_; }

  // Tracks every board in an image that shows the device alone, no scene (e.g. a device image
  // learned from a window's light pairs, device_image_learner.h): grey levels of I_C, CV_32FC1
  // (negative values allowed) or CV_8UC1. Refines as on a background difference; the
  // background is neither used nor changed.
  std::vector<BoardCorners> trackSceneFree(const cv::Mat& device_image);

  const CameraPrior& prior() const { return prior_; }
  const std::vector<BoardTrackStats>& lastStats() const { return stats_; }
  int boardCount() const { return static_cast<int>(prior_.boards.size()); }

  // Tracks board `index` (of prior().boards) in a grey image; touches only that board's state
  // and stats, so different boards may run concurrently.
  // on_difference: `gray` is light-on minus background (window and residual gate differ).
  // align: on a raw image, align the found board as a whole (TrackerOptions::whole_board_alignment).
  BoardCorners trackBoard(const cv::Mat& gray, int index, bool on_difference, bool align = true);

 private:
  struct BoardState {
    bool valid = false;
    double last_score = 0.0;  // re-centring score of the last good frame
    cv::Matx33d homography;   // grid (col, row) -> pixel, minus offsets
    std::vector<cv::Point2f> offsets;
    // Last whole-board alignment (normalised taught coordinates -> pixel), its contrast, robust
    // residual scale and brightness cell levels; valid while the board is aligned frame after frame.
    bool align_valid = false;
    cv::Matx33d align_a;
    double align_contrast = 0.0, align_huber = 0.0;
    std::vector<double> align_levels;
  };
  std::vector<BoardCorners> trackAll(const cv::Mat& gray, bool on_difference, bool align);
  // wide: skip the quick steady-state check, search the whole re-centring window.
  BoardCorners trackBoardOnce(const cv::Mat& gray, int index, bool on_difference, bool align, bool wide);
  // trackBoardOnce's steps (camera_tracker.cpp), on what one attempt at one board shares.
  struct BoardAttempt;
  void refineCorners(BoardAttempt& a) const;
  bool alignWholeBoard(BoardAttempt& a, int index, bool steady);
  bool alignFrom(BoardAttempt& a, int index, int attempt, bool was_aligned);
  static void referenceCorners(const BoardAttempt& a, const tracker::AlignmentTemplate& tmpl,
                               const cv::Matx33d* last, std::vector<int>* ids, std::vector<cv::Point2f>* positions);
  static bool keepAligned(BoardAttempt& a, const tracker::AlignmentTemplate& tmpl,
                          const tracker::AlignmentResult& fit);
  void acceptBoard(BoardAttempt& a, int index, double score, BoardCorners* out);

  CameraPrior prior_;
  TrackerOptions options_;
  SceneBackground background_;
  // Robust spread of `difference` on the pixels away from every board.
  double backgroundResidual(const cv::Mat& difference) const;
  size_t last_found_ = 0;
  double background_residual_ = 0.0;
  bool background_stale_ = false;
  bool background_known_stale_ = false;  // this background was found stale: skip it until replaced
  cv::Mat away_from_boards_;  // CV_8UC1, non-zero on the sampled pixels away from every board
  // Per board; built at construction, then only read (shared by copies of this tracker).
  std::shared_ptr<const std::vector<tracker::AlignmentTemplate>> templates_;
  std::vector<BoardState> states_;
  std::vector<BoardTrackStats> stats_;
};

class PatternTracker {
 public:
  // prior.cameras: [left, right]. Throws ConfigError on an invalid prior or options.
  PatternTracker(const PatternPrior& prior, const TrackerOptions& options);

  // Light-off frames of both cameras (see CameraTracker::setBackground).
  void setBackground(const cv::Mat& left, const cv::Mat& right, ColorOrder order = ColorOrder::kBgr);
  // Tracks both cameras in parallel.
  StereoObservation trackStereo(const cv::Mat& left, const cv::Mat& right, double stamp,
                                ColorOrder order = ColorOrder::kBgr);
  void reset();
  CameraTracker& camera(int index) { return cameras_.at(index); }
  int cameraCount() const { return static_cast<int>(cameras_.size()); }

 private:
  TrackerOptions options_;
  std::vector<CameraTracker> cameras_;
};

}  // namespace embedded_calibration_stereo::core
