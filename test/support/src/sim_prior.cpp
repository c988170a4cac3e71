#include "embedded_calibration_stereo/test_support/sim_prior.h"

#include "embedded_calibration_stereo/core/tracker/board_teacher.h"

namespace embedded_calibration_stereo::core {

PatternPrior teachSimPrior(const SimRig& sim, const SimFrame& light_on, const SimFrame& light_off) {
  const StereoRig& rig = sim.config().rig;
  PatternPrior prior;
  prior.cameras.push_back(
      teachCamera({{light_on.left, light_off.left}},
                  BoardLayout::device(sim.virtualBoards(), rig.left, Eigen::Isometry3d::Identity()), "left")
          .prior);
  prior.cameras.push_back(
      teachCamera({{light_on.right, light_off.right}},
                  BoardLayout::device(sim.virtualBoards(), rig.right, rig.right_from_left), "right")
          .prior);
  return prior;
}

PatternPrior teachSimPrior(const SimRig& sim, double time_s) {
  // Rendered in this order, as the tests' figures were measured: the renderer keeps its scene
  // layer between calls, so the order can change the last bits of a frame.
  const SimFrame on = sim.render(time_s, 1.0, 1);
  const SimFrame off = sim.render(time_s, 0.0, 2);
  return teachSimPrior(sim, on, off);
}

}  // namespace embedded_calibration_stereo::core
