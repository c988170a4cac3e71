#pragma once
// The simulated rig's 3D scene: textured planar rectangles ray cast per pixel, fixed in the world
// or moving (movers, placed per frame). Each plane carries a texture defined ON the plane: a
// procedural multi-scale noise (generated once from its texture_seed) or a photograph (read
// once as grey), so both cameras see the same surface and stereo matching has real detail.
// Textures are sampled from mip levels chosen by each pixel's footprint on the plane (trilinear):
// a far or grazing surface (the floor) would otherwise alias, and a frame re-rendered after a
// zoom or a knock would not match the earlier frame resampled, as it does through a real lens.
//
// Threading: immutable after construction but for useKernel(), which must not run during a
// render() (SimRig calls both under its render mutex); render() may be called from any thread.
#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <vector>

#include "camera_rays.h"
#include "embedded_calibration_stereo/core/sim/sim_rig.h"
#include "mip_texture.h"
#include "scene_kernel.h"

namespace embedded_calibration_stereo::core {
namespace sim {

struct PlaneInCamera;  // a plane as linear forms of the camera ray (scene_renderer.cpp)

class SceneRenderer {
 public:
  // Throws ConfigError (naming e.g. scene.planes[2].texture.image) when a photograph cannot be read.
  explicit SceneRenderer(const SimSceneConfig& config);

  // Scene radiance (grey levels 0..255, CV_32F) seen through each pixel of `rays` by a camera
  // at world_from_camera, movers placed at world_from_movers (one pose per mover); 0 where no
  // plane is hit. When depth_z is non-null it receives the z coordinate of each hit in the
  // frame depth_from_world maps to (the left optical frame), +inf where nothing is hit.
  void render(const CameraRays& rays, const Eigen::Isometry3d& world_from_camera,
              const Eigen::Isometry3d& depth_from_world, const std::vector<Eigen::Isometry3d>& world_from_movers,
              cv::Mat* radiance, cv::Mat* depth_z) const;

  size_t moverCount() const { return movers_.size(); }
  // The row kernels render() uses (default: the widest this CPU runs); for comparing them.
  void useKernel(const scene_kernel::Kernel& kernel) { kernel_ = &kernel; }
  const scene_kernel::Kernel& kernel() const { return *kernel_; }

 private:
  struct TexturedPlane {
    ScenePlane plane;
    Eigen::Vector3d normal;
    // The texture (grey levels): level-0 texel (i, j) at plane coordinates
    // ((i + texel_offset) / inv_texel_u, (j + texel_offset) / inv_texel_v): noise at texel
    // corners (offset 0), photographs at pixel centres (offset 0.5).
    MipTexture texture;
    float inv_texel_u = 1.0f, inv_texel_v = 1.0f, texel_offset = 0.0f;
  };
  // Every plane and mover as seen from the camera at world_from_camera.
  std::vector<PlaneInCamera> placePlanes(const CameraRays& rays, const Eigen::Isometry3d& world_from_camera,
                                                const std::vector<Eigen::Isometry3d>& world_from_movers) const;
  static TexturedPlane makeTexturedPlane(const ScenePlane& plane, const std::string& key);
  bool enabled_;
  const scene_kernel::Kernel* kernel_ = &scene_kernel::bestKernel();
  std::vector<TexturedPlane> planes_, movers_;
};

// A photograph as a texture: grey levels mapped linearly to [16, 255] (no surface is perfectly
// black: zero radiance means "no hit"), CV_32F; empty when the file cannot be read.
cv::Mat loadPhotoTexture(const std::string& path);

// Multi-scale value noise (grey levels, mean 128) of the given size, deterministic for a seed.
cv::Mat makeNoiseTexture(int width, int height, int seed);

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
