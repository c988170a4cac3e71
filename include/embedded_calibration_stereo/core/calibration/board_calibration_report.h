#pragma once
// What calibrate_images writes besides the camera files: report.yaml (RMS figures, per-image
// RMS, every parameter with its standard deviation, baseline and rotation) and a residual plot.
//
// Threading: pure functions, safe from any thread.
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/calibration/board_calibration.h"

namespace embedded_calibration_stereo::core {

// report.yaml text. `skipped` lists the image pairs left out, with the reason.
std::string boardCalibrationReportYaml(const BoardCalibrationResult& result,
                                       const ChessboardSpec& board,
                                       const std::vector<std::string>& skipped);

// A BGR image with, per camera (left column, right column): the residual vectors (predicted -
// detected) as a scatter around the origin, and the same vectors drawn magnified at their
// corners on the image plane; one colour per image pair.
cv::Mat residualPlot(const BoardCalibrationResult& result);

}  // namespace embedded_calibration_stereo::core
