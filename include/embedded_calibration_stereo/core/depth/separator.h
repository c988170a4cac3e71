#pragma once
// Separation of the calibration device's image from calibration-mode frames, so that depth can
// be computed while the light is on. With the light on a camera sees
//   I_E = t * I_scene + alpha * I_C + noise,
// where I_C is the device image taught with the light on and the scene dark (or covered) and
// alpha is the device's brightness relative to the teach frames (1 in steady state; between 0
// and 1 while the light switches; off 1 when the lamp ages or the camera gain differs).
// The separated image is I_S = I_E - alpha * I_C, on the scale of a light-off frame (t * I_scene).
//
// Two ways of finding alpha (SeparatorOptions::method):
//  - kPaperGlobalAlpha, the original system's model (the baseline): one alpha per image,
//    alpha = F(mean(I_E - I_C)), F a cubic fitted by least squares in the teach step from
//    (mean(I_E - I_C), true alpha) samples; the true alpha of a sample comes from a static scene
//    shown with the light on and off: the least-squares gain of (I_on - I_off) against I_C
//    (measureAlphaSample). Its weakness: mean(I_E - I_C) also contains the scene's mean
//    brightness, so a scene brighter or darker than the teach scenes biases alpha.
//  - kRegionalAlpha (default, our design): alpha per tile, by least squares of I_E against I_C
//    after high-passing both (a 5x5 box mean removed): the scene is uncorrelated with the
//    checkerboard's fine structure, so the scene only adds noise to the fit, never bias (without
//    the high-pass, smooth scene structure correlates with board outlines and biases alpha).
//    Fits are pooled over the neighbouring tiles (a 3x3 block of 32 px tiles by default), then
//    shrunk towards the image-wide alpha by how much of their spread exceeds their own
//    estimated noise (empirical Bayes), so a uniform light costs little extra
//    noise while a real light gradient is followed; blocks without enough device contrast
//    (outside the boards, where I_C is the flat housing) take the image-wide estimate. The tile
//    grid is interpolated bilinearly to a per-pixel alpha. It needs no alpha curve, follows lamp
//    ramps and uneven lighting, and is not biased by the scene's brightness (test_separator
//    prints both methods' PSNR on the teach scene, a darker scene and a light ramp).
//
// Where I_C comes from: it is TAUGHT, not predicted: frames with the light on and the scene dark
// (a lens cap over the half-mirror's scene side, or a dark room), averaged (teachDeviceImage) to
// reduce the sensor noise (with N frames the template adds noise sigma/sqrt(N)).
// Keeping I_C valid: the device image moves in the image when the calibration drifts (zoom,
// focus, a knock move the virtual boards). The taught template is only valid for the
// calibration it was taught under: re-teach after every accepted calibration change
// (DeviceTemplate::calibration_epoch records the epoch; the caller compares it with the frame's
// calibration_epoch and passes frames through unseparated, or re-teaches, when they differ).
// Warping I_C by the board homographies of tracked corners is not implemented.
//
// bgr8: the regional fit uses the green channel (the device is lit white, so all channels share
// alpha) and the subtraction applies to all three; mono8 and bgr8 are the only inputs.
// Speed: bench_separator prints each method's time per stereo frame against the 3 ms budget.
//
// Saturation: where I_E is 255 the true sum is unknown; the output there is a lower bound.
//
// Threading: DeviceTemplate and ImageSeparator are immutable after construction; separate() is
// const, keeps no state and may run on any number of threads at once (the nodelet runs the left
// and right images in parallel, see separateStereo).
#include <opencv2/core.hpp>
#include <cstdint>
#include <string>
#include <vector>

namespace embedded_calibration_stereo::core {

enum class SeparationMethod { kPaperGlobalAlpha, kRegionalAlpha };

// "paper_global_alpha" or "regional_alpha"; throws std::invalid_argument naming the choices.
SeparationMethod parseSeparationMethod(const std::string& name);
std::string toString(SeparationMethod method);

struct SeparatorOptions {
  SeparationMethod method = SeparationMethod::kRegionalAlpha;
  int tile_size = 32;          // regional: tile edge, pixels (8..256)
  int pooling_radius = 1;      // regional: tiles pooled on each side (0 = tile alone, 1 = 3x3)
  // regional: a tile block whose device variance sum is below this fraction of the largest
  // block's uses the image-wide alpha (its own fit would be dominated by the scene).
  double min_device_contrast = 0.05;
  // regional: pixels per independent sample of the scene residual (texture and lens blur make
  // neighbours alike); scales the estimated noise of each block's alpha used for the shrinkage.
  double noise_correlation_pixels = 4.0;
  // regional: both I_E and I_C lose their local box mean over this window (odd, 0 = off)
  // before the fit, so the scene's smooth structure cannot correlate with board outlines.
  int highpass_window = 5;
  double max_alpha = 2.0;      // both methods: alpha is clamped to [0, max_alpha]

  // Empty when usable; otherwise one message per problem, joined by "; ".
  std::string validate() const;
};

// The cubic F of the paper's model: alpha = c0 + c1 s + c2 s^2 + c3 s^3 with
// s = (mean(I_E - I_C) - x_offset) / x_scale (normalised for a well-conditioned fit).
struct AlphaCurve {
  double c[4] = {1.0, 0.0, 0.0, 0.0};  // default: alpha = 1 whatever the mean
  double x_offset = 0.0, x_scale = 1.0;
  int degree = 0;                      // degree actually fitted (<= 3; lower with few samples)
  double rms_residual = 0.0;           // of the fit, in alpha units
  double evaluate(double mean_difference) const;
};

// One teach sample of the paper's curve.
struct AlphaSample {
  double mean_difference = 0.0;  // mean(I_E - I_C) over the image, grey levels
  double alpha = 1.0;            // true device gain of that frame
};

// Taught device image of one camera.
struct DeviceTemplate {
  cv::Mat device;          // I_C: CV_32F, one or three channels, grey levels
  AlphaCurve alpha_curve;  // the paper's F (used by kPaperGlobalAlpha only)
  uint32_t calibration_epoch = 0;  // calibration in effect when I_C was taught
  int frames_averaged = 0;
};

// Averages light-on, scene-dark frames (all CV_8UC1 or all CV_8UC3, one size) into I_C.
// Throws std::invalid_argument on an empty list or mixed types/sizes.
DeviceTemplate teachDeviceImage(const std::vector<cv::Mat>& device_frames,
                                uint32_t calibration_epoch = 0);

// A teach sample from a static scene seen with the light on and with it off: the true alpha is
// the least-squares gain of (light_on - light_off) against I_C.
AlphaSample measureAlphaSample(const DeviceTemplate& templ, const cv::Mat& light_on,
                               const cv::Mat& light_off);

// Least-squares cubic through the samples (degree min(3, distinct samples - 1)); throws
// std::invalid_argument without samples.
AlphaCurve fitAlphaCurve(const std::vector<AlphaSample>& samples);

// Separates the device image of one camera.
class ImageSeparator {
 public:
  // Throws std::invalid_argument when the options are invalid or the template is empty.
  ImageSeparator(const SeparatorOptions& options, DeviceTemplate templ);

  // raw: CV_8UC1 (mono8) or CV_8UC3 (bgr8) of the template's size and channel count; otherwise
  // throws std::invalid_argument saying what was expected. scene_out (CV_8U, same type) must not
  // alias raw. alpha_out (optional): the mean alpha used, for diagnostics.
  void separate(const cv::Mat& raw, cv::Mat* scene_out, double* alpha_out = nullptr) const;

  const SeparatorOptions& options() const { return options_; }
  const DeviceTemplate& deviceTemplate() const { return template_; }

 private:
  void checkInput(const cv::Mat& raw) const;
  double paperAlpha(const cv::Mat& raw) const;
  // Fills the per-tile alpha grid (tiles_y x tiles_x, row-major); returns the image-wide alpha.
  double regionalAlpha(const cv::Mat& raw, std::vector<float>* alpha_tiles) const;
  // regionalAlpha's stages: the frame's sums per tile, the fit over a block of tiles (the whole
  // grid, or each tile's pooling neighbourhood), and each tile's alpha shrunk towards the global one.
  struct FrameTileSums;
  struct TileFit;
  FrameTileSums sumFrameTiles(const cv::Mat& raw) const;
  TileFit fitTiles(const FrameTileSums& frame, const cv::Rect& tiles) const;
  std::vector<TileFit> pooledTileFits(const FrameTileSums& frame) const;
  void shrinkTowardsGlobal(const std::vector<TileFit>& fits, double global_alpha,
                           std::vector<float>* alpha_tiles) const;
  void subtractRegional(const cv::Mat& raw, const std::vector<float>& alpha_tiles,
                        cv::Mat* out) const;
  void subtractGlobal(const cv::Mat& raw, double alpha, cv::Mat* out) const;

  SeparatorOptions options_;
  DeviceTemplate template_;
  // Precomputed per tile (regional): sum of I_C and of I_C^2, and the device's total mean.
  cv::Mat device_regressor_;  // I_C, high-passed for the regional fit, CV_16S fixed point
  int tiles_x_ = 0, tiles_y_ = 0;
  std::vector<double> tile_sum_c_, tile_sum_cc_, tile_count_;  // row-major tiles
  double device_mean_ = 0.0;
  // Bilinear interpolation of the tile grid along x: left tile column and weight of the right.
  std::vector<int> column_tile_;
  std::vector<float> column_weight_;
};

// What a separation leaves of the device: the mean square of the separated images' fine
// structure (each minus its 5x5 box mean, grey levels squared) over light-on frames (as
// separate() takes them). Every template sees the same scenes, so of two templates the one with
// the lower score removed more of the device: a template of the device as it was before a zoom,
// a focus change or a knock leaves its edges. Frames a template was learned from favour it (their
// scene is in it, a little). Throws as separate() does; 0 for no frames.
double separationResidual(const ImageSeparator& separator, const std::vector<cv::Mat>& light_on);

// Separates both images of a stereo frame, one per thread (cv::parallel_for_).
void separateStereo(const ImageSeparator& left, const ImageSeparator& right,
                    const cv::Mat& left_raw, const cv::Mat& right_raw, cv::Mat* left_scene,
                    cv::Mat* right_scene);

}  // namespace embedded_calibration_stereo::core
