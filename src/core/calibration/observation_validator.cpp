#include "embedded_calibration_stereo/core/calibration/observation_validator.h"

#include <cmath>
#include <map>
#include <sstream>

namespace embedded_calibration_stereo::core {

namespace {

std::string viewName(int frame, CameraSide camera, int board_id) {
  std::ostringstream s;
  s << "frame " << frame << " " << (camera == CameraSide::kLeft ? "left" : "right") << " board "
    << board_id;
  return s.str();
}

// Validates one board observation; appends the usable view (if any) and the reasons.
void validateBoard(const BoardCorners& in, int frame, CameraSide camera,
                   const std::map<int, int>& board_index_by_id,
                   const std::vector<VirtualBoard>& boards,
                   const ObservationValidationOptions& options, ValidatedObservations* out) {
  const std::string name = viewName(frame, camera, in.board_id);
  const auto found = board_index_by_id.find(in.board_id);
  if (found == board_index_by_id.end()) {
    out->dropped.push_back(name + ": unknown board_id, dropped " + std::to_string(in.size()) +
                           " corners");
    return;
  }
  if (in.u.size() != in.corner_ids.size() || in.v.size() != in.corner_ids.size()) {
    out->dropped.push_back(name + ": corner_ids, u and v differ in length, board dropped");
    return;
  }
  const VirtualBoard& board = boards[found->second];
  std::map<int, int> occurrences;
  for (int id : in.corner_ids) ++occurrences[id];

  int non_finite = 0, out_of_range = 0, duplicated = 0, outside = 0;
  BoardView view;
  view.frame = frame;
  view.camera = camera;
  view.board = found->second;
  const double m = options.max_outside_image_px;
  for (size_t i = 0; i < in.size(); ++i) {
    const int id = in.corner_ids[i];
    const double u = in.u[i], v = in.v[i];
    if (id < 0 || id >= board.cornerCount()) {
      ++out_of_range;
    } else if (occurrences[id] > 1) {
      ++duplicated;  // ambiguous: every copy of the id goes
    } else if (!std::isfinite(u) || !std::isfinite(v)) {
      ++non_finite;
    } else if (u < -m || v < -m || u > options.image_width - 1 + m ||
               v > options.image_height - 1 + m) {
      ++outside;
    } else {
      view.corner_ids.push_back(id);
      view.pixels.emplace_back(u, v);
    }
  }
  const auto report = [&](int count, const char* what) {
    if (count > 0)
      out->dropped.push_back(name + ": " + std::to_string(count) + " corner(s) " + what +
                             ", dropped");
  };
  report(out_of_range, "with ids outside the board");
  report(duplicated, "with duplicate ids");
  report(non_finite, "with non-finite coordinates");
  report(outside, "outside the image");
  if (static_cast<int>(view.size()) < options.min_corners_per_board) {
    if (view.size() > 0)
      out->dropped.push_back(name + ": only " + std::to_string(view.size()) +
                             " valid corners (minimum " +
                             std::to_string(options.min_corners_per_board) + "), board dropped");
    return;
  }
  out->views.push_back(std::move(view));
}

}  // namespace

ValidatedObservations validateObservations(const std::vector<StereoObservation>& frames,
                                           const std::vector<VirtualBoard>& boards,
                                           const ObservationValidationOptions& options) {
  ValidatedObservations out;
  std::map<int, int> board_index_by_id;
  for (size_t i = 0; i < boards.size(); ++i)
    board_index_by_id[boards[i].virtual_id] = static_cast<int>(i);

  for (size_t f = 0; f < frames.size(); ++f) {
    const size_t views_before = out.views.size();
    const int frame = static_cast<int>(f);
    for (CameraSide camera : {CameraSide::kLeft, CameraSide::kRight}) {
      const auto& list = camera == CameraSide::kLeft ? frames[f].left : frames[f].right;
      std::map<int, int> seen;  // a board listed twice in one image is ambiguous
      for (const BoardCorners& b : list) ++seen[b.board_id];
      for (const BoardCorners& b : list) {
        if (seen[b.board_id] > 1) {
          out.dropped.push_back(viewName(frame, camera, b.board_id) +
                                ": board listed more than once in the image, dropped");
          continue;
        }
        validateBoard(b, frame, camera, board_index_by_id, boards, options, &out);
      }
    }
    if (out.views.size() > views_before) ++out.frames_used;
  }
  return out;
}

}  // namespace embedded_calibration_stereo::core
