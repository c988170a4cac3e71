// Real photographs installed by Debian packages (see real_photos.h).
#include "embedded_calibration_stereo/test_support/real_photos.h"

#include <algorithm>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace embedded_calibration_stereo::test_support {

const char* const kBoardPhotoDir = "/usr/share/doc/opencv-doc/examples/data/";
const char* const kScenePhotoDir = "/usr/lib/python3/dist-packages/skimage/data/";

cv::Mat scenePhoto(const std::string& name, cv::Size size) {
  const cv::Mat image = cv::imread(std::string(kScenePhotoDir) + name + ".png", cv::IMREAD_GRAYSCALE);
  if (image.empty()) return image;
  const double s = std::max(static_cast<double>(size.width) / image.cols, static_cast<double>(size.height) / image.rows);
  cv::Mat scaled;
  cv::resize(image, scaled, cv::Size(), s, s, s < 1 ? cv::INTER_AREA : cv::INTER_LINEAR);
  const cv::Rect crop((scaled.cols - size.width) / 2, (scaled.rows - size.height) / 2, size.width, size.height);
  return scaled(crop).clone();
}

bool openCvChessboardCorners(const cv::Mat& gray, cv::Size grid, std::vector<cv::Point2f>* corners) {
  if (!cv::findChessboardCornersSB(gray, grid, *corners,
                                   cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE | cv::CALIB_CB_ACCURACY))
    return false;
  cv::cornerSubPix(gray, *corners, cv::Size(5, 5), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 0.001));
  return true;
}

}  // namespace embedded_calibration_stereo::test_support
