#include "embedded_calibration_stereo/core/depth/speckle_filter.h"

#include <algorithm>
#include <cstdlib>
#include <stdexcept>
#include "parallel_pieces.h"

namespace embedded_calibration_stereo::core {

int SpeckleFilter::root(int run) {
  while (runs_[run].parent != run) {
    runs_[run].parent = runs_[runs_[run].parent].parent;  // path halving
    run = runs_[run].parent;
  }
  return run;
}

void SpeckleFilter::link(int a, int b) {
  a = root(a);
  b = root(b);
  if (a == b) return;
  if (runs_[a].size < runs_[b].size) std::swap(a, b);
  runs_[b].parent = a;
  runs_[a].size += runs_[b].size;
}

// 1. Runs of rows [rows.start, rows.end): maximal horizontal stretches of valid pixels, each
// neighbour within max_diff, indexed from 0 in *runs; row_first_run_[y] set to the row's first.
// Each row is first classified in a loop the compiler vectorises (code: 0 invalid, 1 valid and
// starting a run, 2 valid and joined to its left neighbour; a 0 sentinel ends the row), so the
// run scan is one byte compare per pixel.
void SpeckleFilter::findRuns(const cv::Mat& d, cv::Range rows, int new_value, int max_diff, std::vector<Run>* runs,
                             std::vector<uint8_t>* codes) {
  const int cols = d.cols;
  runs->clear();
  codes->resize(cols + 1);
  uint8_t* code = codes->data();
  code[cols] = 0;
  for (int y = rows.start; y < rows.end; ++y) {
    row_first_run_[y] = static_cast<int>(runs->size());
    const short* p = d.ptr<short>(y);
    code[0] = p[0] != new_value;
    for (int x = 1; x < cols; ++x) {
      const int here = p[x], left = p[x - 1];
      const bool valid = here != new_value;
      const bool joined = valid && left != new_value && std::abs(here - left) <= max_diff;
      code[x] = static_cast<uint8_t>(valid + joined);
    }
    int x = 0;
    while (x < cols) {
      if (code[x] == 0) {
        ++x;
        continue;
      }
      const int begin = x++;
      while (code[x] == 2) ++x;
      const int index = static_cast<int>(runs->size());
      runs->push_back({begin, x, index, x - begin});
    }
  }
}

// 2. Vertical links for the row pairs (y - 1, y), y in [y_begin, y_end): runs of the two rows
// that overlap are one region if any column of the overlap connects them (both pixels are
// valid there by construction).
void SpeckleFilter::linkRows(const cv::Mat& d, int y_begin, int y_end, int max_diff) {
  for (int y = y_begin; y < y_end; ++y) {
    const short* above = d.ptr<short>(y - 1);
    const short* here = d.ptr<short>(y);
    int a = row_first_run_[y - 1];
    int b = row_first_run_[y];
    const int a_end = row_first_run_[y], b_end = row_first_run_[y + 1];
    while (a < a_end && b < b_end) {
      const Run& ra = runs_[a];
      const Run& rb = runs_[b];
      const int begin = std::max(ra.x_begin, rb.x_begin), end = std::min(ra.x_end, rb.x_end);
      if (begin < end && root(a) != root(b)) {
        for (int x = begin; x < end; ++x) {
          if (std::abs(here[x] - above[x]) <= max_diff) {
            link(a, b);
            break;
          }
        }
      }
      if (ra.x_end <= rb.x_end) ++a;
      else ++b;
    }
  }
}

void SpeckleFilter::apply(cv::Mat* disparity, int new_value, int max_speckle_size, int max_diff) {
  cv::Mat& d = *disparity;
  if (d.type() != CV_16SC1) throw std::invalid_argument("SpeckleFilter: need a CV_16SC1 disparity map");
  if (d.empty() || max_speckle_size <= 0) return;  // no region has at most 0 pixels
  const int rows = d.rows;

  // Horizontal stripes of rows run in parallel; the union-find forests of different stripes
  // stay disjoint until the seams are linked, serially.
  const int stripes = parallelPieces(rows, 32);
  const auto stripe_rows = [rows, stripes](int s) { return cv::Range(rows * s / stripes, rows * (s + 1) / stripes); };
  stripe_runs_.resize(stripes);
  stripe_codes_.resize(stripes);
  row_first_run_.resize(rows + 1);
  cv::parallel_for_(cv::Range(0, stripes), [&](const cv::Range& range) {
    for (int s = range.start; s < range.end; ++s)
      findRuns(d, stripe_rows(s), new_value, max_diff, &stripe_runs_[s], &stripe_codes_[s]);
  });
  runs_.clear();
  for (int s = 0; s < stripes; ++s) {  // stripe-local indices -> indices into runs_
    const int offset = static_cast<int>(runs_.size());
    const cv::Range r = stripe_rows(s);
    for (int y = r.start; y < r.end; ++y) row_first_run_[y] += offset;
    for (Run run : stripe_runs_[s]) {
      run.parent += offset;
      runs_.push_back(run);
    }
  }
  row_first_run_[rows] = static_cast<int>(runs_.size());

  cv::parallel_for_(cv::Range(0, stripes), [&](const cv::Range& range) {
    for (int s = range.start; s < range.end; ++s) linkRows(d, stripe_rows(s).start + 1, stripe_rows(s).end, max_diff);
  });
  for (int s = 1; s < stripes; ++s) linkRows(d, stripe_rows(s).start, stripe_rows(s).start + 1, max_diff);

  // Paint the small regions. (Roots first, serially: root() shortens paths as it goes.)
  small_.resize(runs_.size());
  for (size_t r = 0; r < runs_.size(); ++r)
    small_[r] = runs_[root(static_cast<int>(r))].size <= max_speckle_size;
  cv::parallel_for_(cv::Range(0, stripes), [&](const cv::Range& range) {
    for (int y = stripe_rows(range.start).start; y < stripe_rows(range.end - 1).end; ++y) {
      short* p = d.ptr<short>(y);
      for (int r = row_first_run_[y]; r < row_first_run_[y + 1]; ++r)
        if (small_[r])
          for (int x = runs_[r].x_begin; x < runs_[r].x_end; ++x) p[x] = static_cast<short>(new_value);
    }
  });
}

}  // namespace embedded_calibration_stereo::core
