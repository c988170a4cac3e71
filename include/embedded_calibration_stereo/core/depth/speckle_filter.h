#pragma once
// Speckle removal for a fixed-point (CV_16SC1) disparity map, with cv::filterSpeckles' exact
// semantics: pixels equal to new_value are invalid; valid 4-neighbours whose values differ by at
// most max_diff belong to one region; every region of at most max_speckle_size pixels is set to
// new_value. (test_speckle_filter checks the output equals cv::filterSpeckles'.)
//
// Why not cv::filterSpeckles itself: it flood-fills pixel by pixel through a label image, a
// large share of the default disparity's time (bench_disparity). This finds the same
// regions with a union-find over the horizontal runs of connected pixels, linking runs of
// neighbouring rows where they overlap, which is several times faster.
//
// Threading: one thread at a time per instance (it keeps its buffers between calls); stripes of
// rows run on cv::parallel_for_, each on its own runs and buffers until a serial join.
#include <opencv2/core.hpp>
#include <vector>

namespace embedded_calibration_stereo::core {

class SpeckleFilter {
 public:
  // disparity: CV_16SC1, filtered in place. Throws std::invalid_argument for another type.
  void apply(cv::Mat* disparity, int new_value, int max_speckle_size, int max_diff);

 private:
  // A run of connected valid pixels of one row, [x_begin, x_end); after the linking pass the
  // runs form a union-find forest (parent: index of a run; size: pixels, valid at roots).
  struct Run {
    int x_begin, x_end;
    int parent;
    int size;
  };
  int root(int run);
  void link(int a, int b);
  void findRuns(const cv::Mat& d, cv::Range rows, int new_value, int max_diff, std::vector<Run>* runs,
                std::vector<uint8_t>* codes);
  void linkRows(const cv::Mat& d, int y_begin, int y_end, int max_diff);

  std::vector<Run> runs_;
  std::vector<int> row_first_run_;  // runs of row y: [row_first_run_[y], row_first_run_[y + 1])
  std::vector<uint8_t> small_;      // per run: its region has at most max_speckle_size pixels
  std::vector<std::vector<Run>> stripe_runs_;      // per stripe of rows, before joining runs_
  std::vector<std::vector<uint8_t>> stripe_codes_;  // per stripe: one row's pixel classes
};

}  // namespace embedded_calibration_stereo::core
