// How finely the core's parallel loops over rows are cut.
#pragma once

#include <algorithm>
#include <opencv2/core/utility.hpp>

namespace embedded_calibration_stereo::core {

// The number of pieces to cut a cv::parallel_for_ over `units` rows into, each at least
// `min_units` rows: four per thread. In a nodelet manager other stages (the Rectifier of the
// next frame) run on the same cores at the same time, and a piece cannot be shared out once a
// thread has started it: with one piece per thread, the threads that finish early wait for the
// one that was preempted. (bench/pipeline, with two frames in flight, shows the gain;
// bench_disparity, which runs alone, does not.)
inline int parallelPieces(int units, int min_units) {
  return std::max(1, std::min(cv::getNumThreads() * 4, units / min_units));
}

}  // namespace embedded_calibration_stereo::core
