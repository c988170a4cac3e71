#include "embedded_calibration_stereo/core/depth/separator.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>  // cv::accumulate
#include <sstream>
#include <stdexcept>
#include <utility>
#include <vector>

namespace embedded_calibration_stereo::core {

SeparationMethod parseSeparationMethod(const std::string& name) {
  if (name == "paper_global_alpha") return SeparationMethod::kPaperGlobalAlpha;
  if (name == "regional_alpha") return SeparationMethod::kRegionalAlpha;
  throw std::invalid_argument("separation method '" + name +
                              "' unknown; choose paper_global_alpha or regional_alpha");
}

std::string toString(SeparationMethod method) {
  return method == SeparationMethod::kPaperGlobalAlpha ? "paper_global_alpha" : "regional_alpha";
}

std::string SeparatorOptions::validate() const {
  std::vector<std::string> problems;
  if (tile_size < 8 || tile_size > 256) problems.push_back("tile_size must be in [8,256]");
  if (pooling_radius < 0 || pooling_radius > 8) problems.push_back("pooling_radius must be in [0,8]");
  if (!(min_device_contrast >= 0.0 && min_device_contrast < 1.0))
    problems.push_back("min_device_contrast must be in [0,1)");
  if (!(noise_correlation_pixels >= 1.0 && noise_correlation_pixels <= 100.0))
    problems.push_back("noise_correlation_pixels must be in [1,100]");
  if (highpass_window != 0 && (highpass_window < 3 || highpass_window > 31 || highpass_window % 2 == 0))
    problems.push_back("highpass_window must be 0 (off) or odd in [3,31]");
  if (!(max_alpha > 0.0 && max_alpha <= 10.0)) problems.push_back("max_alpha must be in (0,10]");
  std::string joined;
  for (const std::string& p : problems) joined += (joined.empty() ? "" : "; ") + p;
  return joined;
}

double AlphaCurve::evaluate(double mean_difference) const {
  const double s = (mean_difference - x_offset) / x_scale;
  return c[0] + s * (c[1] + s * (c[2] + s * c[3]));
}

namespace {

constexpr double kRegressorScale = 8.0;  // fixed-point steps per grey level of the regressor
constexpr int kFitChannel = 1;           // bgr8: the regional fit uses green

void checkEightBit(const cv::Mat& image, const char* what) {
  if (image.empty()) throw std::invalid_argument(std::string(what) + ": empty image");
  if (image.type() != CV_8UC1 && image.type() != CV_8UC3)
    throw std::invalid_argument(std::string(what) +
                                ": expected CV_8UC1 (mono8) or CV_8UC3 (bgr8), got type " +
                                std::to_string(image.type()));
}

// out = saturate(e - alpha * c) over one row: a plain float loop the compiler vectorises, then
// OpenCV's SIMD rounding and saturating conversion to 8 bits.
void subtractRow(const uchar* e, const float* c, const float* alpha, int n, float* difference,
                 uchar* out) {
  for (int i = 0; i < n; ++i) difference[i] = static_cast<float>(e[i]) - alpha[i] * c[i];
  cv::Mat(1, n, CV_32F, difference).convertTo(cv::Mat(1, n, CV_8U, out), CV_8U);
}

}  // namespace

DeviceTemplate teachDeviceImage(const std::vector<cv::Mat>& device_frames,
                                uint32_t calibration_epoch) {
  if (device_frames.empty()) throw std::invalid_argument("teachDeviceImage: no frames");
  DeviceTemplate templ;
  const cv::Mat& first = device_frames.front();
  checkEightBit(first, "teachDeviceImage");
  templ.device = cv::Mat::zeros(first.size(), CV_MAKETYPE(CV_32F, first.channels()));
  for (const cv::Mat& frame : device_frames) {
    checkEightBit(frame, "teachDeviceImage");
    if (frame.size() != first.size() || frame.type() != first.type())
      throw std::invalid_argument("teachDeviceImage: frames differ in size or type");
    cv::accumulate(frame, templ.device);
  }
  templ.device *= 1.0 / static_cast<double>(device_frames.size());
  templ.frames_averaged = static_cast<int>(device_frames.size());
  templ.calibration_epoch = calibration_epoch;
  return templ;
}

AlphaSample measureAlphaSample(const DeviceTemplate& templ, const cv::Mat& light_on,
                               const cv::Mat& light_off) {
  checkEightBit(light_on, "measureAlphaSample");
  checkEightBit(light_off, "measureAlphaSample");
  if (light_on.size() != templ.device.size() || light_off.size() != templ.device.size() ||
      light_on.channels() != templ.device.channels() || light_off.type() != light_on.type())
    throw std::invalid_argument("measureAlphaSample: frames do not match the template");
  cv::Mat on, off;
  light_on.convertTo(on, CV_32F);
  light_off.convertTo(off, CV_32F);
  AlphaSample sample;
  sample.alpha = (on - off).dot(templ.device) / std::max(1e-9, templ.device.dot(templ.device));
  const int channels = templ.device.channels();
  double on_mean = 0.0, c_mean = 0.0;
  for (int k = 0; k < channels; ++k) {
    on_mean += cv::mean(light_on)[k] / channels;
    c_mean += cv::mean(templ.device)[k] / channels;
  }
  sample.mean_difference = on_mean - c_mean;
  return sample;
}

AlphaCurve fitAlphaCurve(const std::vector<AlphaSample>& samples) {
  if (samples.empty()) throw std::invalid_argument("fitAlphaCurve: no samples");
  AlphaCurve curve;
  double mean = 0.0;
  for (const AlphaSample& s : samples) mean += s.mean_difference / samples.size();
  double var = 0.0;
  for (const AlphaSample& s : samples) var += std::pow(s.mean_difference - mean, 2) / samples.size();
  curve.x_offset = mean;
  curve.x_scale = var > 1e-12 ? std::sqrt(var) : 1.0;
  std::vector<double> xs;
  for (const AlphaSample& s : samples) xs.push_back(std::round(s.mean_difference * 1e6));
  std::sort(xs.begin(), xs.end());
  const int distinct = static_cast<int>(std::unique(xs.begin(), xs.end()) - xs.begin());
  curve.degree = std::min(3, distinct - 1);
  const int n = static_cast<int>(samples.size()), terms = curve.degree + 1;
  cv::Mat A(n, terms, CV_64F), b(n, 1, CV_64F), coeffs;
  for (int i = 0; i < n; ++i) {
    const double s = (samples[i].mean_difference - curve.x_offset) / curve.x_scale;
    double power = 1.0;
    for (int j = 0; j < terms; ++j, power *= s) A.at<double>(i, j) = power;
    b.at<double>(i) = samples[i].alpha;
  }
  cv::solve(A, b, coeffs, cv::DECOMP_SVD);
  for (int j = 0; j < 4; ++j) curve.c[j] = j < terms ? coeffs.at<double>(j) : 0.0;
  double sq = 0.0;
  for (const AlphaSample& s : samples) sq += std::pow(curve.evaluate(s.mean_difference) - s.alpha, 2);
  curve.rms_residual = std::sqrt(sq / n);
  return curve;
}

ImageSeparator::ImageSeparator(const SeparatorOptions& options, DeviceTemplate templ)
    : options_(options), template_(std::move(templ)) {
  const std::string problem = options_.validate();
  if (!problem.empty()) throw std::invalid_argument("SeparatorOptions: " + problem);
  const cv::Mat& c = template_.device;
  if (c.empty() || c.depth() != CV_32F || (c.channels() != 1 && c.channels() != 3))
    throw std::invalid_argument("ImageSeparator: the device template must be a taught CV_32F image");
  if (!c.isContinuous()) template_.device = c.clone();

  const int T = options_.tile_size, W = c.cols, H = c.rows, channels = c.channels();
  tiles_x_ = (W + T - 1) / T;
  tiles_y_ = (H + T - 1) / T;
  tile_sum_c_.assign(tiles_x_ * tiles_y_, 0.0);
  tile_sum_cc_.assign(tiles_x_ * tiles_y_, 0.0);
  tile_count_.assign(tiles_x_ * tiles_y_, 0.0);
  // The regressor of the regional fit: I_C, high-passed like the frames will be, in fixed point
  // (kRegressorScale steps per grey level) so that the per-frame sums run in integers.
  // bgr8: alpha is fitted on the green channel only (the device is lit white, so every channel
  // carries the same gain; one plane makes the fit three times cheaper) and applied to all.
  cv::Mat regressor;
  if (channels == 3) {
    cv::extractChannel(template_.device, regressor, kFitChannel);
  } else {
    regressor = template_.device.clone();
  }
  if (options_.highpass_window > 0) {
    cv::Mat low;
    const int w = options_.highpass_window;
    cv::boxFilter(regressor, low, CV_32F, cv::Size(w, w), cv::Point(-1, -1), true,
                  cv::BORDER_REPLICATE);
    regressor -= low;
  }
  regressor.convertTo(device_regressor_, CV_16S, kRegressorScale);
  for (int y = 0; y < H; ++y) {
    const int16_t* row = device_regressor_.ptr<int16_t>(y);
    for (int x = 0; x < W; ++x) {
      const int tile = (y / T) * tiles_x_ + x / T;
      const double v = row[x] / kRegressorScale;
      tile_sum_c_[tile] += v;
      tile_sum_cc_[tile] += v * v;
      tile_count_[tile] += 1.0;
    }
  }
  const cv::Scalar device_means = cv::mean(template_.device);
  for (int k = 0; k < channels; ++k) device_mean_ += device_means[k] / channels;

  // Tile centres sit at (i + 0.5) T; pixels beyond the first/last centre take the edge tile.
  column_tile_.resize(W);
  column_weight_.resize(W);
  for (int x = 0; x < W; ++x) {
    const double t = std::min(std::max((x + 0.5) / T - 0.5, 0.0), tiles_x_ - 1.0);
    const int i0 = std::min(static_cast<int>(t), std::max(0, tiles_x_ - 2));
    column_tile_[x] = i0;
    column_weight_[x] = tiles_x_ > 1 ? static_cast<float>(t - i0) : 0.0f;
  }
}

void ImageSeparator::checkInput(const cv::Mat& raw) const {
  checkEightBit(raw, "ImageSeparator::separate");
  const cv::Mat& c = template_.device;
  if (raw.size() != c.size() || raw.channels() != c.channels()) {
    std::ostringstream os;
    os << "ImageSeparator::separate: expected " << c.cols << "x" << c.rows << " with "
       << c.channels() << " channel(s) like the taught device image, got " << raw.cols << "x"
       << raw.rows << " with " << raw.channels();
    throw std::invalid_argument(os.str());
  }
}

double ImageSeparator::paperAlpha(const cv::Mat& raw) const {
  const cv::Scalar m = cv::mean(raw);
  double raw_mean = 0.0;
  for (int k = 0; k < raw.channels(); ++k) raw_mean += m[k] / raw.channels();
  return template_.alpha_curve.evaluate(raw_mean - device_mean_);
}

// The frame's sums per tile (row-major) of E, E^2 and E C, E being the fitted plane high-passed
// like the regressor C.
struct ImageSeparator::FrameTileSums {
  std::vector<double> e, ee, ec;
};

// One least-squares fit of E on C over a block of tiles (see fitTiles).
struct ImageSeparator::TileFit {
  double alpha = 1.0, variance = 0.0, contrast = 0.0;
};

ImageSeparator::FrameTileSums ImageSeparator::sumFrameTiles(const cv::Mat& raw) const {
  const int T = options_.tile_size, W = raw.cols, H = raw.rows;
  const int n_tiles = tiles_x_ * tiles_y_;
  FrameTileSums sums{std::vector<double>(n_tiles, 0.0), std::vector<double>(n_tiles, 0.0),
                     std::vector<double>(n_tiles, 0.0)};
  // The frame high-passed like the regressor; an 8-bit local mean keeps this a fast SIMD box
  // filter (its rounding adds 1/12 grey level^2 of noise, uncorrelated with the device).
  cv::Mat plane = raw, low;
  if (raw.channels() == 3) cv::extractChannel(raw, plane, kFitChannel);
  if (options_.highpass_window > 0) {
    const int w = options_.highpass_window;
    cv::blur(plane, low, cv::Size(w, w), cv::Point(-1, -1), cv::BORDER_REPLICATE);
  } else {
    low = cv::Mat::zeros(plane.size(), plane.type());
  }
  for (int y = 0; y < H; ++y) {
    const uchar* e = plane.ptr<uchar>(y);
    const uchar* m = low.ptr<uchar>(y);
    const int16_t* c = device_regressor_.ptr<int16_t>(y);
    const int row0 = (y / T) * tiles_x_;
    for (int tx = 0; tx < tiles_x_; ++tx) {
      const int begin = tx * T, end = std::min(W, (tx + 1) * T);
      // One row segment (<= 256 values): |d| <= 255, |c| <= 255 * kRegressorScale, so the
      // int32 sums cannot overflow; integer sums also let the compiler vectorise.
      int row_e = 0, row_ee = 0, row_ec = 0;
      for (int i = begin; i < end; ++i) {
        const int d = static_cast<int>(e[i]) - static_cast<int>(m[i]);
        row_e += d;
        row_ee += d * d;
        row_ec += d * c[i];
      }
      sums.e[row0 + tx] += row_e;
      sums.ee[row0 + tx] += row_ee;
      sums.ec[row0 + tx] += row_ec / kRegressorScale;
    }
  }
  return sums;
}

// Centred least squares over a block of tiles: alpha = cov(E, C) / var(C); the variance of
// that estimate is (residual variance / sum of centred C^2) * noise_correlation_pixels,
// the residual being the scene (plus sensor noise), which is spatially correlated.
// The tiles are summed row by row, left to right: the whole grid sums them in index order.
ImageSeparator::TileFit ImageSeparator::fitTiles(const FrameTileSums& frame, const cv::Rect& tiles) const {
  double n = 0, se = 0, see = 0, sc = 0, scc = 0, sec = 0;
  for (int j = tiles.y; j < tiles.y + tiles.height; ++j) {
    for (int i = tiles.x; i < tiles.x + tiles.width; ++i) {
      const int t = j * tiles_x_ + i;
      n += tile_count_[t]; se += frame.e[t]; see += frame.ee[t]; sc += tile_sum_c_[t];
      scc += tile_sum_cc_[t]; sec += frame.ec[t];
    }
  }
  TileFit f;
  const double sxx = std::max(scc - sc * sc / n, 1e-9), sxy = sec - se * sc / n;
  const double syy = see - se * se / n;
  f.alpha = sxy / sxx;
  const double residual = std::max(0.0, syy - f.alpha * sxy) / std::max(1.0, n - 2);
  f.variance = residual / sxx * options_.noise_correlation_pixels;
  f.contrast = sxx / n;
  return f;
}

std::vector<ImageSeparator::TileFit> ImageSeparator::pooledTileFits(const FrameTileSums& frame) const {
  std::vector<TileFit> fits(tiles_x_ * tiles_y_);
  const int r = options_.pooling_radius;
  for (int ty = 0; ty < tiles_y_; ++ty) {
    for (int tx = 0; tx < tiles_x_; ++tx) {
      // The tiles within r of (tx, ty), clipped to the grid.
      const int x0 = std::max(0, tx - r), x1 = std::min(tiles_x_ - 1, tx + r);
      const int y0 = std::max(0, ty - r), y1 = std::min(tiles_y_ - 1, ty + r);
      fits[ty * tiles_x_ + tx] = fitTiles(frame, cv::Rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1));
    }
  }
  return fits;
}

// Shrinks each block's alpha towards the image-wide one by how much of the spread between
// blocks is real (empirical Bayes: tau^2 = spread - mean estimate variance). With a uniform
// light the blocks follow the global alpha (no added noise); a real gradient survives.
void ImageSeparator::shrinkTowardsGlobal(const std::vector<TileFit>& fits, double global_alpha,
                                         std::vector<float>* alpha_tiles) const {
  double max_contrast = 0.0;
  for (const TileFit& f : fits) max_contrast = std::max(max_contrast, f.contrast);
  // A block with little device contrast against the strongest one would have its fit dominated
  // by the scene: it takes the global alpha and does not count in the spread.
  const auto usable = [&](const TileFit& f) {
    return max_contrast > 0 && f.contrast >= options_.min_device_contrast * max_contrast;
  };
  double spread = 0.0, mean_variance = 0.0;
  int used = 0;
  for (const TileFit& f : fits) {
    if (!usable(f)) continue;
    spread += (f.alpha - global_alpha) * (f.alpha - global_alpha);
    mean_variance += f.variance;
    ++used;
  }
  const double tau2 = used > 1 ? std::max(0.0, (spread - mean_variance) / used) : 0.0;
  alpha_tiles->resize(fits.size());
  for (size_t t = 0; t < fits.size(); ++t) {
    const TileFit& f = fits[t];
    const double a = usable(f) ? global_alpha + tau2 / (tau2 + f.variance + 1e-12) *
                                                    (f.alpha - global_alpha)
                               : global_alpha;
    (*alpha_tiles)[t] = static_cast<float>(std::min(std::max(a, 0.0), options_.max_alpha));
  }
}

double ImageSeparator::regionalAlpha(const cv::Mat& raw, std::vector<float>* alpha_tiles) const {
  const FrameTileSums frame = sumFrameTiles(raw);
  const double global_alpha = fitTiles(frame, cv::Rect(0, 0, tiles_x_, tiles_y_)).alpha;
  shrinkTowardsGlobal(pooledTileFits(frame), global_alpha, alpha_tiles);
  return std::min(std::max(global_alpha, 0.0), options_.max_alpha);
}

void ImageSeparator::subtractRegional(const cv::Mat& raw, const std::vector<float>& alpha_tiles,
                                      cv::Mat* out) const {
  const int T = options_.tile_size, W = raw.cols, H = raw.rows, channels = raw.channels();
  std::vector<float> row_alpha(tiles_x_ + 1);
  cv::Mat alpha_row(1, W * channels, CV_32F), difference(1, W * channels, CV_32F);
  cv::Mat pixel_alpha_row(1, W, CV_32F);
  for (int y = 0; y < H; ++y) {
    // Vertical interpolation between the two nearest tile rows, then horizontal per pixel.
    const double t = std::min(std::max((y + 0.5) / T - 0.5, 0.0), tiles_y_ - 1.0);
    const int j0 = std::min(static_cast<int>(t), std::max(0, tiles_y_ - 2));
    const int j1 = std::min(j0 + 1, tiles_y_ - 1);
    const float wy = static_cast<float>(t - j0);
    for (int i = 0; i < tiles_x_; ++i)
      row_alpha[i] = (1 - wy) * alpha_tiles[j0 * tiles_x_ + i] + wy * alpha_tiles[j1 * tiles_x_ + i];
    row_alpha[tiles_x_] = row_alpha[tiles_x_ - 1];
    // Per span of columns sharing the left tile the alpha is linear in the weight: contiguous
    // loops the compiler vectorises.
    float* a = alpha_row.ptr<float>();
    float* pixel_alpha = channels == 1 ? a : pixel_alpha_row.ptr<float>();
    const float* w = column_weight_.data();
    for (int x = 0; x < W;) {
      const int i0 = column_tile_[x];
      int end = x;
      while (end < W && column_tile_[end] == i0) ++end;
      const float base = row_alpha[i0], slope = row_alpha[i0 + 1] - row_alpha[i0];
      for (int i = x; i < end; ++i) pixel_alpha[i] = base + w[i] * slope;
      x = end;
    }
    if (channels == 3)
      for (int x = 0; x < W; ++x) a[3 * x] = a[3 * x + 1] = a[3 * x + 2] = pixel_alpha[x];
    subtractRow(raw.ptr<uchar>(y), template_.device.ptr<float>(y), a, W * channels,
                difference.ptr<float>(), out->ptr<uchar>(y));
  }
}

void ImageSeparator::subtractGlobal(const cv::Mat& raw, double alpha, cv::Mat* out) const {
  const int n = raw.cols * raw.channels();
  cv::Mat alpha_row(1, n, CV_32F, cv::Scalar(alpha)), difference(1, n, CV_32F);
  for (int y = 0; y < raw.rows; ++y)
    subtractRow(raw.ptr<uchar>(y), template_.device.ptr<float>(y), alpha_row.ptr<float>(), n,
                difference.ptr<float>(), out->ptr<uchar>(y));
}

void ImageSeparator::separate(const cv::Mat& raw, cv::Mat* scene_out, double* alpha_out) const {
  checkInput(raw);
  if (scene_out == nullptr) throw std::invalid_argument("ImageSeparator::separate: null output");
  if (scene_out->data == raw.data && !raw.empty())
    throw std::invalid_argument("ImageSeparator::separate: output must not alias the input");
  scene_out->create(raw.size(), raw.type());
  if (options_.method == SeparationMethod::kPaperGlobalAlpha) {
    const double alpha = std::min(std::max(paperAlpha(raw), 0.0), options_.max_alpha);
    subtractGlobal(raw, alpha, scene_out);
    if (alpha_out) *alpha_out = alpha;
    return;
  }
  std::vector<float> alpha_tiles;
  regionalAlpha(raw, &alpha_tiles);
  subtractRegional(raw, alpha_tiles, scene_out);
  if (alpha_out) {
    double sum = 0.0;
    for (float a : alpha_tiles) sum += a;
    *alpha_out = sum / alpha_tiles.size();
  }
}

double separationResidual(const ImageSeparator& separator, const std::vector<cv::Mat>& light_on) {
  double sum = 0.0;
  size_t pixels = 0;
  for (const cv::Mat& frame : light_on) {
    cv::Mat scene, grey, smooth;
    separator.separate(frame, &scene);
    if (scene.channels() == 3) cv::cvtColor(scene, scene, cv::COLOR_BGR2GRAY);
    scene.convertTo(grey, CV_32F);
    cv::blur(grey, smooth, cv::Size(5, 5), cv::Point(-1, -1), cv::BORDER_REFLECT);
    const cv::Mat fine = grey - smooth;
    sum += fine.dot(fine);
    pixels += fine.total();
  }
  return pixels ? sum / static_cast<double>(pixels) : 0.0;
}

void separateStereo(const ImageSeparator& left, const ImageSeparator& right,
                    const cv::Mat& left_raw, const cv::Mat& right_raw, cv::Mat* left_scene,
                    cv::Mat* right_scene) {
  // One camera per worker; exceptions are carried back to the caller's thread.
  std::exception_ptr errors[2];
  cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& range) {
    for (int side = range.start; side < range.end; ++side) {
      try {
        if (side == 0) left.separate(left_raw, left_scene);
        else right.separate(right_raw, right_scene);
      } catch (...) {
        errors[side] = std::current_exception();
      }
    }
  });
  for (const std::exception_ptr& error : errors)
    if (error) std::rethrow_exception(error);
}

}  // namespace embedded_calibration_stereo::core
