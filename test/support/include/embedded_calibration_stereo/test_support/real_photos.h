#pragma once
// Real photographs installed by Debian packages, for tests that try the tracker as a user would
// (never copied into the repository): OpenCV's chessboard samples (opencv-doc) and scikit-image's
// sample photographs (python3-skimage).
//
// Threading: reentrant.
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace embedded_calibration_stereo::test_support {

// Folder of OpenCV's calibration samples (left01.jpg ...: a 9x6 inner-corner chessboard).
extern const char* const kBoardPhotoDir;
// Folder of scikit-image's sample photographs (brick.png, astronaut.png ...).
extern const char* const kScenePhotoDir;

// The scene photo `name` (without .png) as grey, scaled to cover `size` and centre-cropped to it;
// empty when it cannot be read.
cv::Mat scenePhoto(const std::string& name, cv::Size size);

// OpenCV's corners of a chessboard photo with `grid` inner corners, an independent reference for
// the tracker: findChessboardCornersSB (normalised, exhaustive, accurate), then cornerSubPix in a
// 5x5 window; in OpenCV's order. False when OpenCV finds no board.
bool openCvChessboardCorners(const cv::Mat& gray, cv::Size grid, std::vector<cv::Point2f>* corners);

}  // namespace embedded_calibration_stereo::test_support
