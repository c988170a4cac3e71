#include "embedded_calibration_stereo/core/io/pfm_io.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace embedded_calibration_stereo::core {
namespace {

bool hostIsLittleEndian() {
  const uint16_t one = 1;
  uint8_t first;
  std::memcpy(&first, &one, 1);
  return first == 1;
}

void swapBytes(float* values, size_t count) {
  for (size_t i = 0; i < count; ++i) {
    uint8_t b[4];
    std::memcpy(b, &values[i], 4);
    std::swap(b[0], b[3]);
    std::swap(b[1], b[2]);
    std::memcpy(&values[i], b, 4);
  }
}

}  // namespace

void writePfm(const std::string& path, const cv::Mat& image) {
  if (image.empty() || (image.type() != CV_32FC1 && image.type() != CV_32FC3))
    throw std::invalid_argument("writePfm: image must be non-empty CV_32FC1 or CV_32FC3");
  std::ofstream out(path, std::ios::binary);
  if (!out) throw std::runtime_error("writePfm: cannot open '" + path + "' for writing");
  const int channels = image.channels();
  out << (channels == 1 ? "Pf" : "PF") << "\n" << image.cols << " " << image.rows << "\n-1.0\n";
  const size_t row_values = static_cast<size_t>(image.cols) * channels;
  std::vector<float> row(row_values);
  for (int y = image.rows - 1; y >= 0; --y) {
    const float* src = image.ptr<float>(y);
    for (size_t i = 0; i < row_values; ++i)
      row[i] = std::isfinite(src[i]) ? src[i] : std::numeric_limits<float>::infinity();
    if (!hostIsLittleEndian()) swapBytes(row.data(), row.size());
    out.write(reinterpret_cast<const char*>(row.data()), row_values * sizeof(float));
  }
  if (!out) throw std::runtime_error("writePfm: write to '" + path + "' failed");
}

cv::Mat readPfm(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("readPfm: cannot open '" + path + "'");
  std::string magic;
  int width = 0, height = 0;
  double scale = 0;
  in >> magic >> width >> height >> scale;
  if (!in || (magic != "Pf" && magic != "PF"))
    throw std::runtime_error("readPfm: '" + path + "' has no PFM header (Pf/PF)");
  if (width <= 0 || height <= 0 || scale == 0)
    throw std::runtime_error("readPfm: '" + path + "' has a bad size or scale");
  in.get();  // the single whitespace byte ending the header
  const int channels = magic == "Pf" ? 1 : 3;
  cv::Mat image(height, width, channels == 1 ? CV_32FC1 : CV_32FC3);
  const bool file_little = scale < 0;
  const size_t row_values = static_cast<size_t>(width) * channels;
  for (int y = height - 1; y >= 0; --y) {
    float* dst = image.ptr<float>(y);
    in.read(reinterpret_cast<char*>(dst), row_values * sizeof(float));
    if (!in) throw std::runtime_error("readPfm: '" + path + "' is truncated");
    if (file_little != hostIsLittleEndian()) swapBytes(dst, row_values);
  }
  return image;
}

}  // namespace embedded_calibration_stereo::core
