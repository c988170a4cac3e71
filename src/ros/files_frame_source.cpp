// The files backend: replays a directory of left/right image pairs (in name order) or two
// video files, with an optional CSV giving the light state of each frame.
#include <sys/stat.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>
#include <vector>

#include "embedded_calibration_stereo/core/io/config_error.h"
#include "embedded_calibration_stereo/ros/frame_source.h"

namespace embedded_calibration_stereo {
namespace {

bool isDirectory(const std::string& path) {
  struct stat st;
  return stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
}

bool isFile(const std::string& path) {
  struct stat st;
  return stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode);
}

std::string trim(const std::string& s) {
  const size_t b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  return s.substr(b, s.find_last_not_of(" \t\r\n") - b + 1);
}

// Rows "frame,light_on" (light_on: 0/1/true/false/on/off); an optional non-numeric header row.
std::map<int, bool> readLightCsv(const std::string& path) {
  const std::string param = "files_light_csv";
  if (!isFile(path)) throw core::ConfigError(param, "file not found: '" + path + "'");
  std::ifstream in(path);
  std::map<int, bool> states;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    line = trim(line);
    if (line.empty() || line[0] == '#') continue;
    const size_t comma = line.find(',');
    const std::string where = "'" + path + "' line " + std::to_string(line_no);
    if (comma == std::string::npos) throw core::ConfigError(param, where + ": expected 'frame,light_on'");
    const std::string frame_text = trim(line.substr(0, comma));
    std::string value = trim(line.substr(comma + 1));
    const size_t extra = value.find(',');
    if (extra != std::string::npos) value = trim(value.substr(0, extra));
    char* end = nullptr;
    const long frame = std::strtol(frame_text.c_str(), &end, 10);
    if (end == frame_text.c_str() || *end != '\0') {
      if (states.empty() && line_no == 1) continue;  // header row
      throw core::ConfigError(param, where + ": frame '" + frame_text + "' is not an integer");
    }
    if (frame < 0) throw core::ConfigError(param, where + ": negative frame index");
    bool on;
    if (value == "1" || value == "true" || value == "True" || value == "on") {
      on = true;
    } else if (value == "0" || value == "false" || value == "False" || value == "off") {
      on = false;
    } else {
      throw core::ConfigError(param, where + ": light_on '" + value + "' is not 0/1/true/false");
    }
    states[static_cast<int>(frame)] = on;
  }
  if (states.empty()) throw core::ConfigError(param, "'" + path + "' has no rows");
  return states;
}

class FilesFrameSource : public FrameSource {
 public:
  explicit FilesFrameSource(const FilesSourceParams& params) : params_(params) {
    if (params_.encoding != "mono8" && params_.encoding != "bgr8")
      throw core::ConfigError("encoding", "must be mono8 or bgr8 (got '" + params_.encoding + "')");
    if (!params_.left_video.empty() || !params_.right_video.empty()) {
      openVideos();
    } else {
      listImages();
    }
    if (!params_.light_csv.empty()) light_states_ = readLightCsv(params_.light_csv);
    // Read the first pair now: an unreadable file or a size mismatch fails at start-up.
    StereoFrame first;
    std::string error;
    if (!read(0, &first, &error)) throw core::ConfigError(videos_ ? "files_left_video" : "files_dir", error);
    size_ = first.left.size();
    rewind();
  }

  bool grab(double, StereoFrame* frame, std::string* error) override {
    if (!videos_ && next_index_ >= static_cast<int>(left_files_.size())) {
      if (!params_.loop) {
        if (error) *error = "end of the image pairs (files_loop is false)";
        return false;
      }
      rewind();
    }
    if (!read(next_index_, frame, error)) {
      // A video's end is only known by failing to read it.
      if (!videos_ || !params_.loop || next_index_ == 0) return false;
      rewind();
      if (!read(next_index_, frame, error)) return false;
    }
    if (frame->left.size() != size_ || frame->right.size() != size_) {
      if (error) *error = "frame " + std::to_string(next_index_) + " changes the image size";
      return false;
    }
    if (!light_states_.empty()) {
      auto it = light_states_.upper_bound(next_index_);
      frame->light_on = it == light_states_.begin() ? false : std::prev(it)->second;
    } else {
      frame->light_on.reset();
    }
    ++next_index_;
    return true;
  }

  cv::Size imageSize() const override { return size_; }
  bool recordsLightState() const override { return !light_states_.empty(); }

 private:
  void listImages() {
    if (params_.dir.empty()) throw core::ConfigError("files_dir", "missing (or give files_left_video and files_right_video)");
    if (!isDirectory(params_.dir)) throw core::ConfigError("files_dir", "directory does not exist: '" + params_.dir + "'");
    cv::glob(params_.dir + "/" + params_.left_glob, left_files_, false);
    cv::glob(params_.dir + "/" + params_.right_glob, right_files_, false);
    std::sort(left_files_.begin(), left_files_.end());
    std::sort(right_files_.begin(), right_files_.end());
    if (left_files_.empty())
      throw core::ConfigError("files_left_glob", "no file matches '" + params_.left_glob + "' in '" + params_.dir + "'");
    if (right_files_.size() != left_files_.size())
      throw core::ConfigError("files_right_glob", std::to_string(right_files_.size()) + " files match '" +
                                                     params_.right_glob + "' but " + std::to_string(left_files_.size()) +
                                                     " match files_left_glob");
  }

  void openVideos() {
    videos_ = true;
    const std::pair<const char*, const std::string*> sides[] = {{"files_left_video", &params_.left_video},
                                                                {"files_right_video", &params_.right_video}};
    for (const auto& side : sides) {
      if (side.second->empty()) throw core::ConfigError(side.first, "missing (both videos are needed)");
      if (!isFile(*side.second)) throw core::ConfigError(side.first, "file not found: '" + *side.second + "'");
    }
    left_video_.open(params_.left_video);
    right_video_.open(params_.right_video);
    if (!left_video_.isOpened()) throw core::ConfigError("files_left_video", "cannot decode '" + params_.left_video + "'");
    if (!right_video_.isOpened()) throw core::ConfigError("files_right_video", "cannot decode '" + params_.right_video + "'");
  }

  void rewind() {
    next_index_ = 0;
    if (videos_) {
      left_video_.set(cv::CAP_PROP_POS_FRAMES, 0);
      right_video_.set(cv::CAP_PROP_POS_FRAMES, 0);
    }
  }

  // Reads pair `index` (images) or the next pair (videos). False at the end or on error.
  bool read(int index, StereoFrame* frame, std::string* error) {
    frame->encoding = params_.encoding;
    if (videos_) {
      cv::Mat left, right;
      if (!left_video_.read(left) || !right_video_.read(right)) {
        if (error) *error = "end of the videos";
        return false;
      }
      frame->left = convertToEncoding(left, params_.encoding);
      frame->right = convertToEncoding(right, params_.encoding);
      return true;
    }
    if (index >= static_cast<int>(left_files_.size())) {
      if (error) *error = "end of the image pairs";
      return false;
    }
    const int flags = params_.encoding == "mono8" ? cv::IMREAD_GRAYSCALE : cv::IMREAD_COLOR;
    frame->left = cv::imread(left_files_[index], flags);
    frame->right = cv::imread(right_files_[index], flags);
    if (frame->left.empty() || frame->right.empty()) {
      if (error) *error = "cannot read '" + (frame->left.empty() ? left_files_[index] : right_files_[index]) + "'";
      return false;
    }
    if (frame->left.size() != frame->right.size()) {
      if (error) *error = "'" + left_files_[index] + "' and '" + right_files_[index] + "' differ in size";
      return false;
    }
    return true;
  }

  FilesSourceParams params_;
  bool videos_ = false;
  std::vector<cv::String> left_files_, right_files_;
  cv::VideoCapture left_video_, right_video_;
  std::map<int, bool> light_states_;
  int next_index_ = 0;
  cv::Size size_;
};

}  // namespace

std::unique_ptr<FrameSource> makeFilesFrameSource(const FilesSourceParams& params) {
  return std::make_unique<FilesFrameSource>(params);
}

}  // namespace embedded_calibration_stereo
