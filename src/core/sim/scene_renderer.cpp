#include "scene_renderer.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo::core {
namespace sim {

namespace {
constexpr double kMaxTextureSide = 4096.0;  // texels: bounds a photograph's memory (64 MB)
}  // namespace

cv::Mat makeNoiseTexture(int width, int height, int seed) {
  // Octaves of uniform noise from texel size up to 16 texels, upsampled smoothly and summed:
  // fine octaves give sub-metre detail for matching, coarse ones avoid a flat, repetitive look.
  cv::RNG rng(0x9E3779B97F4A7C15ULL ^ (static_cast<uint64_t>(seed) * 0x100000001B3ULL + 7));
  cv::Mat sum = cv::Mat::zeros(height, width, CV_32F);
  const double amplitudes[] = {1.0, 0.8, 0.65, 0.5, 0.4};
  for (int octave = 0; octave < 5; ++octave) {
    const int step = 1 << octave;
    cv::Mat coarse(std::max(2, height / step + 2), std::max(2, width / step + 2), CV_32F);
    rng.fill(coarse, cv::RNG::UNIFORM, -1.0, 1.0);
    cv::Mat up;
    if (octave == 0) {
      up = coarse(cv::Rect(0, 0, width, height));
    } else {
      cv::resize(coarse, up, cv::Size(), step, step, cv::INTER_CUBIC);
      up = up(cv::Rect(0, 0, width, height));
    }
    cv::scaleAdd(up, amplitudes[octave], sum, sum);
  }
  cv::Scalar mean, stddev;
  cv::meanStdDev(sum, mean, stddev);
  // Each surface gets its own brightness (mean 95..165) and contrast (std 35..55 grey levels),
  // clipped to [16, 255]: no surface is perfectly black, so zero radiance always means "no hit".
  const double target_mean = 95.0 + rng.uniform(0.0, 70.0);
  const double target_std = 35.0 + rng.uniform(0.0, 20.0);
  const double gain = target_std / std::max(stddev[0], 1e-9);
  cv::Mat texture;
  sum.convertTo(texture, CV_32F, gain, target_mean - gain * mean[0]);
  cv::min(cv::max(texture, 16.0), 255.0, texture);
  return texture;
}

cv::Mat loadPhotoTexture(const std::string& path) {
  const cv::Mat grey = cv::imread(path, cv::IMREAD_GRAYSCALE);
  if (grey.empty()) return cv::Mat();
  cv::Mat texture;
  grey.convertTo(texture, CV_32F, 239.0 / 255.0, 16.0);
  return texture;
}

SceneRenderer::TexturedPlane SceneRenderer::makeTexturedPlane(const ScenePlane& p, const std::string& key) {
  TexturedPlane tp;
  tp.plane = p;
  tp.normal = p.u_axis.cross(p.v_axis).normalized();
  if (p.texture_image.empty()) {
    const int w = static_cast<int>(std::ceil(p.width_m / p.texel_m)) + 2;
    const int h = static_cast<int>(std::ceil(p.height_m / p.texel_m)) + 2;
    tp.texture = MipTexture(makeNoiseTexture(w, h, p.texture_seed));
    tp.inv_texel_u = tp.inv_texel_v = static_cast<float>(1.0 / p.texel_m);
  } else {
    cv::Mat photo = loadPhotoTexture(p.texture_image);
    if (photo.empty()) throw ConfigError(key + ".texture.image", "cannot read the image '" + p.texture_image + "'");
    const bool tiled = p.texture_tile_m.x() > 0 && p.texture_tile_m.y() > 0;
    const double tile_w = tiled ? p.texture_tile_m.x() : p.width_m;
    const double tile_h = tiled ? p.texture_tile_m.y() : p.height_m;
    const double copies_x = tiled ? std::ceil(p.width_m / tile_w) : 1.0;
    const double copies_y = tiled ? std::ceil(p.height_m / tile_h) : 1.0;
    // Bound the texture's memory: shrink the photograph until its copies fit kMaxTextureSide.
    const double shrink = std::max({1.0, copies_x * photo.cols / kMaxTextureSide, copies_y * photo.rows / kMaxTextureSide});
    if (shrink > 1.0) {
      cv::Mat small;
      cv::resize(photo, small, cv::Size(std::max(1, static_cast<int>(photo.cols / shrink)),
                                        std::max(1, static_cast<int>(photo.rows / shrink))), 0, 0, cv::INTER_AREA);
      photo = small;
    }
    tp.inv_texel_u = static_cast<float>(photo.cols / tile_w);
    tp.inv_texel_v = static_cast<float>(photo.rows / tile_h);
    tp.texel_offset = 0.5f;
    if (tiled && (copies_x > 1 || copies_y > 1)) {
      cv::Mat repeated;
      cv::repeat(photo, static_cast<int>(copies_y), static_cast<int>(copies_x), repeated);
      photo = repeated;
    }
    tp.texture = MipTexture(photo);
  }
  return tp;
}

// A plane as the kernels see it from one camera, and the columns of each row that can see it.
struct PlaneInCamera {
  scene_kernel::Plane kernel;
  std::vector<int> span_lo, span_hi;  // per row, the columns [lo, hi) that can see the plane
};

SceneRenderer::SceneRenderer(const SimSceneConfig& config) : enabled_(config.enabled) {
  if (!enabled_) return;
  for (size_t i = 0; i < config.planes.size(); ++i)
    planes_.push_back(makeTexturedPlane(config.planes[i], "scene.planes[" + std::to_string(i) + "]"));
  for (size_t i = 0; i < config.movers.size(); ++i)
    movers_.push_back(makeTexturedPlane(config.movers[i].panel, "scene.movers[" + std::to_string(i) + "]"));
}

namespace {

// Keeps the part of a convex polygon where f(q) = n.q + d >= 0 (Sutherland-Hodgman, one plane).
std::vector<Eigen::Vector3d> clipPolygon(const std::vector<Eigen::Vector3d>& polygon, const Eigen::Vector3d& n, double d) {
  std::vector<Eigen::Vector3d> out;
  for (size_t i = 0; i < polygon.size(); ++i) {
    const Eigen::Vector3d& a = polygon[i];
    const Eigen::Vector3d& b = polygon[(i + 1) % polygon.size()];
    const double fa = n.dot(a) + d, fb = n.dot(b) + d;
    if (fa >= 0) out.push_back(a);
    if ((fa >= 0) != (fb >= 0)) out.push_back(a + (b - a) * (fa / (fa - fb)));
  }
  return out;
}

// Columns [lo, hi) of each row that can see a rectangle: its outline, clipped to the pyramid of
// rays the image holds (where the distortion model is monotone), projected, and filled row by
// row; dilated by a row and two columns, since the cast decides each pixel exactly.
void planeRowSpans(const ScenePlane& p, const CameraRays& rays, const Eigen::Isometry3d& camera_from_world,
                   PlaneInCamera* pc) {
  const PinholeCamera& cam = rays.camera;
  const int H = cam.height, W = cam.width;
  pc->span_lo.assign(H, W);
  pc->span_hi.assign(H, 0);
  std::vector<Eigen::Vector3d> polygon;
  for (const Eigen::Vector2d& ab : {Eigen::Vector2d(0, 0), Eigen::Vector2d(1, 0), Eigen::Vector2d(1, 1), Eigen::Vector2d(0, 1)})
    polygon.push_back(camera_from_world * (p.origin + ab.x() * p.width_m * p.u_axis + ab.y() * p.height_m * p.v_axis));
  const double mx = 0.02 * std::max(std::abs(rays.x_min), std::abs(rays.x_max));
  const double my = 0.02 * std::max(std::abs(rays.y_min), std::abs(rays.y_max));
  polygon = clipPolygon(polygon, Eigen::Vector3d(0, 0, 1), -1e-4);
  polygon = clipPolygon(polygon, Eigen::Vector3d(-1, 0, rays.x_max + mx), 0);
  polygon = clipPolygon(polygon, Eigen::Vector3d(1, 0, -(rays.x_min - mx)), 0);
  polygon = clipPolygon(polygon, Eigen::Vector3d(0, -1, rays.y_max + my), 0);
  polygon = clipPolygon(polygon, Eigen::Vector3d(0, 1, -(rays.y_min - my)), 0);
  if (polygon.size() < 3) return;
  std::vector<int> lo(H, W), hi(H, -1);
  const int kSteps = 64;
  Eigen::Vector2d previous;
  cam.project(polygon.back(), &previous);
  for (size_t i = 0; i < polygon.size(); ++i) {
    const Eigen::Vector3d& a = polygon[i];
    const Eigen::Vector3d& b = polygon[(i + 1) % polygon.size()];
    for (int k = 0; k < kSteps; ++k) {
      Eigen::Vector2d px;
      cam.project(a + (b - a) * (static_cast<double>(k) / kSteps), &px);
      // Where the segment previous -> px crosses each row centre (its ends at the rows around them).
      const double v0 = std::min(previous.y(), px.y()), v1 = std::max(previous.y(), px.y());
      const int r0 = std::max(0, static_cast<int>(std::floor(v0))), r1 = std::min(H - 1, static_cast<int>(std::ceil(v1)));
      for (int r = r0; r <= r1; ++r) {
        const double f = v1 > v0 ? std::clamp((r - previous.y()) / (px.y() - previous.y()), 0.0, 1.0) : 0.0;
        const double u = std::clamp(previous.x() + f * (px.x() - previous.x()), -8.0, W + 8.0);
        lo[r] = std::min(lo[r], static_cast<int>(std::floor(u)) - 2);
        hi[r] = std::max(hi[r], static_cast<int>(std::ceil(u)) + 3);
      }
      previous = px;
    }
  }
  // A row's span is [min, max] of the outline's crossings, widened to the rows around it.
  for (int r = 0; r < H; ++r) {
    for (int n = std::max(0, r - 1); n <= std::min(H - 1, r + 1); ++n) {
      pc->span_lo[r] = std::min(pc->span_lo[r], std::max(0, lo[n]));
      pc->span_hi[r] = std::max(pc->span_hi[r], std::min(W, hi[n]));
    }
  }
}

PlaneInCamera placeInCamera(const ScenePlane& plane, const Eigen::Vector3d& normal, const MipTexture& texture,
                            float inv_texel_u, float inv_texel_v, float texel_offset, const CameraRays& rays,
                            const Eigen::Isometry3d& world_from_camera) {
  const Eigen::Matrix3d R = world_from_camera.linear();
  const Eigen::Vector3d C = world_from_camera.translation();
  PlaneInCamera placed;
  scene_kernel::Plane& pc = placed.kernel;
  const Eigen::Vector3d n = R.transpose() * normal;
  const Eigen::Vector3d u = R.transpose() * plane.u_axis;
  const Eigen::Vector3d v = R.transpose() * plane.v_axis;
  for (int k = 0; k < 3; ++k) {
    pc.n[k] = static_cast<float>(n[k]);
    pc.u[k] = static_cast<float>(u[k]);
    pc.v[k] = static_cast<float>(v[k]);
  }
  pc.numerator = static_cast<float>(normal.dot(plane.origin - C));
  pc.a0 = static_cast<float>((C - plane.origin).dot(plane.u_axis));
  pc.b0 = static_cast<float>((C - plane.origin).dot(plane.v_axis));
  pc.width = static_cast<float>(plane.width_m);
  pc.height = static_cast<float>(plane.height_m);
  pc.texture = texture.view();
  pc.inv_texel_u = inv_texel_u;
  pc.inv_texel_v = inv_texel_v;
  pc.texel_offset = texel_offset;
  pc.footprint_scale = std::max(inv_texel_u, inv_texel_v);
  planeRowSpans(plane, rays, world_from_camera.inverse(), &placed);
  return placed;
}

}  // namespace

std::vector<PlaneInCamera> SceneRenderer::placePlanes(const CameraRays& rays, const Eigen::Isometry3d& world_from_camera,
                                                      const std::vector<Eigen::Isometry3d>& world_from_movers) const {
  std::vector<PlaneInCamera> planes;
  for (const TexturedPlane& tp : planes_)
    planes.push_back(placeInCamera(tp.plane, tp.normal, tp.texture, tp.inv_texel_u, tp.inv_texel_v,
                                   tp.texel_offset, rays, world_from_camera));
  // The movers at this frame's poses (same textures).
  for (size_t i = 0; i < movers_.size(); ++i) {
    const TexturedPlane& tp = movers_[i];
    const Eigen::Isometry3d& pose = world_from_movers.at(i);
    ScenePlane p = tp.plane;
    p.origin = pose * tp.plane.origin;
    p.u_axis = pose.linear() * tp.plane.u_axis;
    p.v_axis = pose.linear() * tp.plane.v_axis;
    planes.push_back(placeInCamera(p, pose.linear() * tp.normal, tp.texture, tp.inv_texel_u, tp.inv_texel_v,
                                   tp.texel_offset, rays, world_from_camera));
  }
  return planes;
}

void SceneRenderer::render(const CameraRays& rays, const Eigen::Isometry3d& world_from_camera,
                           const Eigen::Isometry3d& depth_from_world,
                           const std::vector<Eigen::Isometry3d>& world_from_movers, cv::Mat* radiance,
                           cv::Mat* depth_z) const {
  const int W = rays.camera.width, H = rays.camera.height;
  radiance->create(H, W, CV_32F);
  if (depth_z) depth_z->create(H, W, CV_32F);
  const std::vector<PlaneInCamera> planes = placePlanes(rays, world_from_camera, world_from_movers);
  std::vector<scene_kernel::Plane> kernel_planes;
  for (const PlaneInCamera& p : planes) kernel_planes.push_back(p.kernel);
  // Depth z of a hit C + t R m: e.(C + t R m) + d with (e, d) the z row of depth_from_world.
  const Eigen::Vector3d e = depth_from_world.linear().row(2).transpose();
  const Eigen::Vector3d rz = world_from_camera.linear().transpose() * e;  // z of the ray direction, per unit t
  scene_kernel::DepthLine line;
  line.z_centre = static_cast<float>(e.dot(world_from_camera.translation()) + depth_from_world.translation().z());
  for (int k = 0; k < 3; ++k) line.r[k] = static_cast<float>(rz[k]);
  const scene_kernel::Kernel& kernel = *kernel_;

  cv::parallel_for_(cv::Range(0, H), [&](const cv::Range& range) {
    // Plane-major per row: each plane updates the row's nearest hits over the columns that can
    // see it; the texture is then sampled once per pixel, for the nearest plane only.
    std::vector<float> t(W), a(W), b(W);
    std::vector<int> plane(W);
    const scene_kernel::RowHits hits{t.data(), a.data(), b.data(), plane.data()};
    for (int row = range.start; row < range.end; ++row) {
      // The neighbouring row's rays give the vertical pixel step (the previous one at the bottom).
      const int next_row = row + 1 < H ? row + 1 : row - 1;
      const scene_kernel::RowRays row_rays{rays.x.ptr<float>(row), rays.y.ptr<float>(row),
                                           rays.x.ptr<float>(next_row), rays.y.ptr<float>(next_row),
                                           row + 1 < H ? 1.0f : -1.0f, W};
      std::fill(t.begin(), t.end(), std::numeric_limits<float>::infinity());
      std::fill(plane.begin(), plane.end(), -1);
      for (int p = 0; p < static_cast<int>(planes.size()); ++p) {
        const PlaneInCamera& pc = planes[p];
        if (pc.span_lo[row] < pc.span_hi[row])
          kernel.cast(pc.kernel, p, row_rays, pc.span_lo[row], pc.span_hi[row], hits);
      }
      kernel.shade(kernel_planes.data(), row_rays, hits, line, radiance->ptr<float>(row),
                   depth_z ? depth_z->ptr<float>(row) : nullptr);
    }
  });
}

}  // namespace sim
}  // namespace embedded_calibration_stereo::core
