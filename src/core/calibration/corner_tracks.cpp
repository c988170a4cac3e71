#include "embedded_calibration_stereo/core/calibration/corner_tracks.h"

#include <algorithm>
#include <map>
#include <tuple>

namespace embedded_calibration_stereo::core {

namespace {

double median(std::vector<double> values) {
  const size_t mid = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + mid, values.end());
  if (values.size() % 2 == 1) return values[mid];
  const double upper = values[mid];
  return 0.5 * (upper + *std::max_element(values.begin(), values.begin() + mid));
}

}  // namespace

CornerTracks buildCornerTracks(const std::vector<BoardView>& views, bool shared_across_frames,
                               double max_distance_from_median_px) {
  CornerTracks out;
  // (camera, frame, board, corner) -> track index; std::map keeps a deterministic order.
  std::map<std::tuple<int, int, int, int>, size_t> index;
  for (const BoardView& v : views) {
    const int frame = shared_across_frames ? -1 : v.frame;
    for (size_t i = 0; i < v.size(); ++i) {
      const auto key = std::make_tuple(static_cast<int>(v.camera), frame, v.board, v.corner_ids[i]);
      auto found = index.find(key);
      if (found == index.end()) {
        CornerTrack t;
        t.camera = v.camera;
        t.frame = frame;
        t.board = v.board;
        t.corner_id = v.corner_ids[i];
        found = index.emplace(key, out.tracks.size()).first;
        out.tracks.push_back(std::move(t));
      }
      out.tracks[found->second].observations.push_back(v.pixels[i]);
    }
  }
  const double max_sq = max_distance_from_median_px * max_distance_from_median_px;
  for (CornerTrack& t : out.tracks) {
    if (t.observations.size() >= 3) {
      std::vector<double> u, v;
      for (const Eigen::Vector2d& o : t.observations) u.push_back(o.x()), v.push_back(o.y());
      const Eigen::Vector2d m(median(u), median(v));
      const size_t before = t.observations.size();
      t.observations.erase(
          std::remove_if(t.observations.begin(), t.observations.end(),
                         [&](const Eigen::Vector2d& o) { return (o - m).squaredNorm() > max_sq; }),
          t.observations.end());
      out.rejected += static_cast<int>(before - t.observations.size());
    }
    if (t.observations.empty()) continue;  // no consensus at all: the track goes below
    t.mean.setZero();
    for (const Eigen::Vector2d& o : t.observations) t.mean += o;
    t.mean /= static_cast<double>(t.observations.size());
    t.scatter_sq = 0.0;
    for (const Eigen::Vector2d& o : t.observations) t.scatter_sq += (o - t.mean).squaredNorm();
  }
  out.tracks.erase(std::remove_if(out.tracks.begin(), out.tracks.end(),
                                  [](const CornerTrack& t) { return t.observations.empty(); }),
                   out.tracks.end());
  return out;
}

}  // namespace embedded_calibration_stereo::core
