#pragma once
// One light window of a simulated head, rendered as the window tracker takes it: a light-off
// frame, `lit_frames` light-on frames at 30 fps, a light-off frame (frame j, j + 1 ...
// j + lit_frames, j + lit_frames + 1; noise seeds 500 + frame off, 1000 + frame lit). The tests
// and the bench of the window tracker use this one set-up.
//
// Threading: renders with `sim`, which is for one thread at a time.
#include <functional>
#include <vector>

#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "embedded_calibration_stereo/core/tracker/window_tracker.h"

namespace embedded_calibration_stereo::core {

struct RenderedWindow {
  WindowFrames left, right;
  std::vector<SimFrame> lit;  // the light-on frames as rendered (their truth)
};

// before_lit(k), when given, runs before the k-th light-on frame (k from 1) is rendered: e.g. to
// set a drift during the burst.
RenderedWindow renderWindow(SimRig& sim, int j, int lit_frames, const std::function<void(int)>& before_lit = {});

}  // namespace embedded_calibration_stereo::core
