#include "embedded_calibration_stereo/test_support/rendered_window.h"

namespace embedded_calibration_stereo::core {

RenderedWindow renderWindow(SimRig& sim, int j, int lit_frames, const std::function<void(int)>& before_lit) {
  constexpr double kFps = 30.0;
  RenderedWindow w;
  const SimFrame before = sim.render(j / kFps, 0.0, 500 + j);
  w.left.light_off_before.push_back(before.left);
  w.right.light_off_before.push_back(before.right);
  for (int k = 1; k <= lit_frames; ++k) {
    if (before_lit) before_lit(k);
    w.lit.push_back(sim.render((j + k) / kFps, 1.0, 1000 + j + k));
    w.left.light_on.push_back(w.lit.back().left);
    w.right.light_on.push_back(w.lit.back().right);
  }
  const SimFrame after = sim.render((j + lit_frames + 1) / kFps, 0.0, 500 + j + lit_frames + 1);
  w.left.light_off_after.push_back(after.left);
  w.right.light_off_after.push_back(after.right);
  return w;
}

}  // namespace embedded_calibration_stereo::core
