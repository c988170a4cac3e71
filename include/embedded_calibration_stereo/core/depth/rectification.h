#pragma once
// Stereo rectification of a calibrated rig: the geometry (R1, R2, P1, P2, Q, as OpenCV's
// stereoRectify returns them) by Bouguet's method (cv::stereoRectify) or by Fusiello's method
// (Fusiello, Trucco, Verri 2000, "A compact algorithm for rectification of stereo pairs",
// the original head's method), and the fixed-point remap tables that apply it.
//
// Conventions: R1/R2 rotate points of the left/right optical frame into the rectified frame of
// that camera; P1 = K' [I | 0], P2 = K' [I | (Tx, 0, 0)] with Tx = -fx' * baseline (the
// CameraInfo/stereo_image_proc convention); Q maps (u, v, disparity, 1) to homogeneous 3D in the
// rectified left frame. Disparity is u_left - u_right >= 0 for points in front of the rig.
//
// Threading: RectificationMaps is immutable once built. build() is slow (a few ms, allocates),
// so a node builds it off the image thread and swaps a std::shared_ptr<const RectificationMaps>
// in; rectify() is const and may run on any number of threads at once.
#include <opencv2/core.hpp>
#include <string>
#include <utility>

#include "embedded_calibration_stereo/core/geometry/stereo_rig.h"

namespace embedded_calibration_stereo::core {

enum class RectificationMethod { kBouguet, kFusiello };

// "bouguet" or "fusiello" (case-sensitive); throws std::invalid_argument naming the choices.
RectificationMethod parseRectificationMethod(const std::string& name);
std::string toString(RectificationMethod method);

struct RectificationGeometry {
  cv::Matx33d R1, R2;
  cv::Matx34d P1, P2;
  cv::Matx44d Q;
  cv::Size size;  // rectified image size (= the raw image size)
  // Baseline of the rectified pair in metres (= -P2(0,3) / P2(0,0)).
  double baseline() const { return -P2(0, 3) / P2(0, 0); }
};

struct RectificationOptions {
  RectificationMethod method = RectificationMethod::kBouguet;
  // Bouguet only: cv::stereoRectify's alpha. 0 = zoom so that every rectified pixel is valid,
  // 1 = keep every raw pixel, -1 = OpenCV's default scaling.
  double alpha = 0.0;
};

// Computes the rectifying rotations and projections. Throws std::invalid_argument when the rig
// is not usable (invalid camera, zero baseline, or a baseline not mainly horizontal).
RectificationGeometry computeRectificationGeometry(const StereoRig& rig,
                                                   const RectificationOptions& options);

// Remaps a stereo pair through its tables (as cv::initUndistortRectifyMap makes them;
// INTER_LINEAR, constant black border) into *left_out and *right_out, which are written in place
// when they already have the right size and type. The two images run side by side, one thread
// each, in one cv::parallel_for_ region: OpenCV parallelises one region at a time per process (a
// region started while another thread's runs executes serially), so one short region per frame,
// rather than one per image, leaves the regions of the other stages of a nodelet manager
// parallel more often; and one image per thread costs less CPU than remap's split of one image
// (docs/figures.md, rectification).
void remapStereoPair(const cv::Mat& left_in, const cv::Mat& right_in, const cv::Mat& left_map1,
                     const cv::Mat& left_map2, const cv::Mat& right_map1, const cv::Mat& right_map2,
                     cv::Mat* left_out, cv::Mat* right_out);

class RectificationMaps {
 public:
  // Builds the geometry and the cv::initUndistortRectifyMap tables in fixed-point form
  // (CV_16SC2 + CV_16UC1, the fastest input of cv::remap).
  static RectificationMaps build(const StereoRig& rig, const RectificationOptions& options);

  // Remaps both raw images (INTER_LINEAR, constant black border). The images must have the
  // rig's size (any type cv::remap supports) and the outputs must not alias the inputs; throws
  // std::invalid_argument otherwise.
  void rectify(const cv::Mat& left_raw, const cv::Mat& right_raw, cv::Mat* left_rect,
               cv::Mat* right_rect) const;
  // The same, returning (left_rect, right_rect) in new buffers.
  std::pair<cv::Mat, cv::Mat> rectify(const cv::Mat& left_raw, const cv::Mat& right_raw) const;

  const RectificationGeometry& geometry() const { return geometry_; }
  RectificationMethod method() const { return method_; }
  // The tables, for callers that remap one side only.
  const cv::Mat& leftMap1() const { return left_map1_; }
  const cv::Mat& leftMap2() const { return left_map2_; }
  const cv::Mat& rightMap1() const { return right_map1_; }
  const cv::Mat& rightMap2() const { return right_map2_; }

 private:
  RectificationMaps() = default;
  RectificationGeometry geometry_;
  RectificationMethod method_ = RectificationMethod::kBouguet;
  cv::Mat left_map1_, left_map2_, right_map1_, right_map2_;
};

// OpenCV forms of a camera (3x3 K, 1x5 plumb_bob distortion), used by both methods and tests.
cv::Matx33d cameraMatrix(const PinholeCamera& camera);
cv::Mat distortionVector(const PinholeCamera& camera);

}  // namespace embedded_calibration_stereo::core
