#pragma once
// The simulated rig's 3D scene: textured planar rectangles ray cast per pixel. Each plane
// carries a procedural multi-scale noise texture defined ON the plane (generated once from its
// texture_seed), so both cameras see the same surface and stereo matching has real detail.
// Textures are sampled from mip levels chosen by each pixel's footprint on the plane (trilinear):
// a far or grazing surface (the floor) would otherwise alias, and a frame re-rendered after a
// zoom or a knock would not match the earlier frame resampled, as it does through a real lens.
//
// Threading: immutable after construction; render() may be called from any thread.
#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <vector>

#include "camera_rays.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"

namespace ecs {
namespace sim {

class SceneRenderer {
 public:
  explicit SceneRenderer(const SimSceneConfig& config);

  // Scene radiance (grey levels 0..255, CV_32F) seen through each pixel of `rays` by a camera
  // at rig_from_camera; 0 where no plane is hit. When depth_z is non-null it receives the z
  // coordinate of each hit in the rig (left optical) frame, +inf where nothing is hit.
  void render(const CameraRays& rays, const Eigen::Isometry3d& rig_from_camera,
              cv::Mat* radiance, cv::Mat* depth_z) const;

 private:
  struct TexturedPlane {
    ScenePlane plane;
    Eigen::Vector3d normal;
    // Mip levels of the texture (CV_32F grey levels): level 0 has one texel per texel_m, texel
    // (i, j) at (i, j) * texel_m; level k+1 is level k low-passed and halved (cv::pyrDown).
    std::vector<cv::Mat> mips;
  };
  bool enabled_;
  std::vector<TexturedPlane> planes_;
};

// Multi-scale value noise (grey levels, mean 128) of the given size, deterministic for a seed.
cv::Mat makeNoiseTexture(int width, int height, int seed);

}  // namespace sim
}  // namespace ecs
