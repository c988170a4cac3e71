#include "scene_renderer.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "embedded_calibration_stereo/core/geometry/config_error.h"

namespace ecs {
namespace sim {

namespace {
constexpr size_t kMaxMipLevels = 8;
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
    tp.mips.push_back(makeNoiseTexture(w, h, p.texture_seed));
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
    tp.mips.push_back(photo);
  }
  while (tp.mips.size() < kMaxMipLevels && std::min(tp.mips.back().cols, tp.mips.back().rows) >= 4) {
    cv::Mat next;
    cv::pyrDown(tp.mips.back(), next);
    tp.mips.push_back(next);
  }
  return tp;
}

SceneRenderer::SceneRenderer(const SimSceneConfig& config) : enabled_(config.enabled) {
  if (!enabled_) return;
  for (size_t i = 0; i < config.planes.size(); ++i)
    planes_.push_back(makeTexturedPlane(config.planes[i], "scene.planes[" + std::to_string(i) + "]"));
  for (size_t i = 0; i < config.movers.size(); ++i)
    movers_.push_back(makeTexturedPlane(config.movers[i].panel, "scene.movers[" + std::to_string(i) + "]"));
}

namespace {

inline float sampleBilinear(const cv::Mat& tex, float x, float y) {
  x = std::min(std::max(x, 0.0f), tex.cols - 1.001f);
  y = std::min(std::max(y, 0.0f), tex.rows - 1.001f);
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const float fx = x - x0, fy = y - y0;
  const float* r0 = tex.ptr<float>(y0) + x0;
  const float* r1 = tex.ptr<float>(y0 + 1) + x0;
  return (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
}

// Texture value at level-0 texel coordinates (x, y) for a pixel footprint of `footprint` texels:
// blends the two mip levels around log2(footprint); level 0 alone when a pixel covers less than a
// texel.
inline float sampleTrilinear(const std::vector<cv::Mat>& mips, float x, float y, float footprint) {
  if (!(footprint > 1.0f)) return sampleBilinear(mips[0], x, y);
  const float level = std::min(std::log2(footprint), static_cast<float>(mips.size() - 1));
  const int l0 = static_cast<int>(level);
  const int l1 = std::min(l0 + 1, static_cast<int>(mips.size()) - 1);
  const float w = level - l0;
  const float s0 = 1.0f / static_cast<float>(1 << l0), s1 = 1.0f / static_cast<float>(1 << l1);
  const float v0 = sampleBilinear(mips[l0], x * s0, y * s0);
  return w > 0.0f ? (1 - w) * v0 + w * sampleBilinear(mips[l1], x * s1, y * s1) : v0;
}

// A plane expressed as linear forms of the camera ray m = (x, y, 1), so that a pixel costs a
// handful of multiply-adds per plane: t = numerator / (n.m), a = a0 + t (u.m), b = b0 + t (v.m).
struct PlaneInCamera {
  float n[3], u[3], v[3];
  float numerator, a0, b0, width, height;
  cv::Rect box;  // pixels that can see the plane
};

// Footprint of one pixel on a plane, in metres: the larger of the plane displacements (measured
// along the plane's u and v axes) of the hit point t * m when the ray m = (x, y, 1) moves to the
// next column (dmx) and to the next row (dmy). dP = t (dm - m (n.dm) / (n.m)).
inline float pixelFootprint(const PlaneInCamera& pc, float t, float x, float y, float dmx0, float dmx1,
                            float dmy0, float dmy1) {
  const float nm = pc.n[0] * x + pc.n[1] * y + pc.n[2];
  const auto extent = [&](float d0, float d1) {
    const float k = (pc.n[0] * d0 + pc.n[1] * d1) / nm;
    const float p0 = t * (d0 - x * k), p1 = t * (d1 - y * k), p2 = -t * k;
    const float da = pc.u[0] * p0 + pc.u[1] * p1 + pc.u[2] * p2;
    const float db = pc.v[0] * p0 + pc.v[1] * p1 + pc.v[2] * p2;
    return std::sqrt(da * da + db * db);
  };
  return std::max(extent(dmx0, dmx1), extent(dmy0, dmy1));
}

// Image bounding box of a rectangle, from samples of its outline; the whole image when part of
// it is behind the camera or outside the cone the image sees (distortion does not invert there).
cv::Rect planeBoundingBox(const ScenePlane& p, const CameraRays& rays, const Eigen::Isometry3d& camera_from_rig) {
  const PinholeCamera& cam = rays.camera;
  const cv::Rect image(0, 0, cam.width, cam.height);
  double umin = 1e30, umax = -1e30, vmin = 1e30, vmax = -1e30;
  const int kSteps = 32;
  for (int edge = 0; edge < 4; ++edge)
    for (int k = 0; k <= kSteps; ++k) {
      const double f = static_cast<double>(k) / kSteps;
      const double a = edge == 0 ? f : edge == 1 ? 1.0 : edge == 2 ? 1.0 - f : 0.0;
      const double b = edge == 0 ? 0.0 : edge == 1 ? f : edge == 2 ? 1.0 : 1.0 - f;
      const Eigen::Vector3d q =
          camera_from_rig * (p.origin + a * p.width_m * p.u_axis + b * p.height_m * p.v_axis);
      if (q.z() <= 1e-6 || std::hypot(q.x() / q.z(), q.y() / q.z()) > 1.2 * rays.max_radius) return image;
      Eigen::Vector2d px;
      cam.project(q, &px);
      umin = std::min(umin, px.x()), umax = std::max(umax, px.x());
      vmin = std::min(vmin, px.y()), vmax = std::max(vmax, px.y());
    }
  const int pad = 2;
  const cv::Rect box(static_cast<int>(std::floor(umin)) - pad, static_cast<int>(std::floor(vmin)) - pad,
                     static_cast<int>(std::ceil(umax - umin)) + 2 * pad + 2,
                     static_cast<int>(std::ceil(vmax - vmin)) + 2 * pad + 2);
  return box & image;
}

// Nearest-hit update of one row segment against one plane, 4 pixels at a time with OpenCV's
// universal intrinsics (SSE or NEON), then a scalar tail.
void castRowSegment(const PlaneInCamera& pc, int plane_index, const float* x, const float* y, int begin,
                    int end, float* best_t, float* best_a, float* best_b, int* best_plane) {
  const float kMinT = 1e-6f;
  int col = begin;
#if CV_SIMD128
  const cv::v_float32x4 n0 = cv::v_setall_f32(pc.n[0]), n1 = cv::v_setall_f32(pc.n[1]),
                        n2 = cv::v_setall_f32(pc.n[2]);
  const cv::v_float32x4 u0 = cv::v_setall_f32(pc.u[0]), u1 = cv::v_setall_f32(pc.u[1]),
                        u2 = cv::v_setall_f32(pc.u[2]);
  const cv::v_float32x4 v0 = cv::v_setall_f32(pc.v[0]), v1 = cv::v_setall_f32(pc.v[1]),
                        v2 = cv::v_setall_f32(pc.v[2]);
  const cv::v_float32x4 numerator = cv::v_setall_f32(pc.numerator), a0 = cv::v_setall_f32(pc.a0),
                        b0 = cv::v_setall_f32(pc.b0), width = cv::v_setall_f32(pc.width),
                        height = cv::v_setall_f32(pc.height), min_t = cv::v_setall_f32(kMinT),
                        zero = cv::v_setzero_f32();
  const cv::v_int32x4 index = cv::v_setall_s32(plane_index);
  for (; col + 4 <= end; col += 4) {
    const cv::v_float32x4 vx = cv::v_load(x + col), vy = cv::v_load(y + col);
    const cv::v_float32x4 t = numerator / (n0 * vx + n1 * vy + n2);
    const cv::v_float32x4 a = a0 + t * (u0 * vx + u1 * vy + u2);
    const cv::v_float32x4 b = b0 + t * (v0 * vx + v1 * vy + v2);
    const cv::v_float32x4 prev = cv::v_load(best_t + col);
    // Comparisons with NaN are false, so a ray parallel to the plane (t = inf or NaN) never
    // hits; with t finite, a and b are finite and the min-of-margins test is exact.
    const cv::v_float32x4 inside = cv::v_min(cv::v_min(a, width - a), cv::v_min(b, height - b)) >= zero;
    const cv::v_float32x4 hit = (t > min_t) & (t < prev) & inside;
    cv::v_store(best_t + col, cv::v_select(hit, t, prev));
    cv::v_store(best_a + col, cv::v_select(hit, a, cv::v_load(best_a + col)));
    cv::v_store(best_b + col, cv::v_select(hit, b, cv::v_load(best_b + col)));
    cv::v_store(best_plane + col,
                cv::v_select(cv::v_reinterpret_as_s32(hit), index, cv::v_load(best_plane + col)));
  }
#endif
  for (; col < end; ++col) {
    const float t = pc.numerator / (pc.n[0] * x[col] + pc.n[1] * y[col] + pc.n[2]);
    const float a = pc.a0 + t * (pc.u[0] * x[col] + pc.u[1] * y[col] + pc.u[2]);
    const float b = pc.b0 + t * (pc.v[0] * x[col] + pc.v[1] * y[col] + pc.v[2]);
    if (t > kMinT && t < best_t[col] && a >= 0.0f && a <= pc.width && b >= 0.0f && b <= pc.height) {
      best_t[col] = t;
      best_a[col] = a;
      best_b[col] = b;
      best_plane[col] = plane_index;
    }
  }
}

}  // namespace

void SceneRenderer::render(const CameraRays& rays, const Eigen::Isometry3d& world_from_camera,
                           const Eigen::Isometry3d& depth_from_world,
                           const std::vector<Eigen::Isometry3d>& world_from_movers, cv::Mat* radiance,
                           cv::Mat* depth_z) const {
  const int W = rays.camera.width, H = rays.camera.height;
  radiance->create(H, W, CV_32F);
  if (depth_z) depth_z->create(H, W, CV_32F);
  const Eigen::Matrix3d R = world_from_camera.linear();
  const Eigen::Vector3d C = world_from_camera.translation();
  // The fixed planes, then the movers placed at this frame's poses (same textures).
  std::vector<const TexturedPlane*> sources;
  std::vector<ScenePlane> placed;
  std::vector<Eigen::Vector3d> normals;
  for (const TexturedPlane& tp : planes_) {
    sources.push_back(&tp);
    placed.push_back(tp.plane);
    normals.push_back(tp.normal);
  }
  for (size_t i = 0; i < movers_.size(); ++i) {
    const TexturedPlane& tp = movers_[i];
    const Eigen::Isometry3d& pose = world_from_movers.at(i);
    ScenePlane p = tp.plane;
    p.origin = pose * tp.plane.origin;
    p.u_axis = pose.linear() * tp.plane.u_axis;
    p.v_axis = pose.linear() * tp.plane.v_axis;
    sources.push_back(&tp);
    placed.push_back(p);
    normals.push_back(pose.linear() * tp.normal);
  }
  std::vector<PlaneInCamera> planes;
  const Eigen::Isometry3d camera_from_world = world_from_camera.inverse();
  for (size_t i = 0; i < placed.size(); ++i) {
    const ScenePlane& plane = placed[i];
    PlaneInCamera pc;
    const Eigen::Vector3d n = R.transpose() * normals[i];
    const Eigen::Vector3d u = R.transpose() * plane.u_axis;
    const Eigen::Vector3d v = R.transpose() * plane.v_axis;
    for (int k = 0; k < 3; ++k) {
      pc.n[k] = static_cast<float>(n[k]);
      pc.u[k] = static_cast<float>(u[k]);
      pc.v[k] = static_cast<float>(v[k]);
    }
    pc.numerator = static_cast<float>(normals[i].dot(plane.origin - C));
    pc.a0 = static_cast<float>((C - plane.origin).dot(plane.u_axis));
    pc.b0 = static_cast<float>((C - plane.origin).dot(plane.v_axis));
    pc.width = static_cast<float>(plane.width_m);
    pc.height = static_cast<float>(plane.height_m);
    pc.box = planeBoundingBox(plane, rays, camera_from_world);
    planes.push_back(pc);
  }
  // Depth z of a hit C + t R m: e.(C + t R m) + d with (e, d) the z row of depth_from_world.
  const Eigen::Vector3d e = depth_from_world.linear().row(2).transpose();
  const double zC = e.dot(C) + depth_from_world.translation().z();
  const Eigen::Vector3d rz = R.transpose() * e;  // z of the ray direction, per unit t
  const float inf = std::numeric_limits<float>::infinity();

  cv::parallel_for_(cv::Range(0, H), [&](const cv::Range& range) {
    // Plane-major per row: each plane updates the row's nearest hits in one SIMD pass over its
    // bounding box; the texture is then sampled once per pixel, for the nearest plane only.
    std::vector<float> best_t(W), best_a(W), best_b(W);
    std::vector<int> best_plane(W);
    for (int row = range.start; row < range.end; ++row) {
      const float* x = rays.x.ptr<float>(row);
      const float* y = rays.y.ptr<float>(row);
      // The neighbouring row's rays give the vertical pixel step (the previous one at the bottom).
      const int other_row = row + 1 < H ? row + 1 : row - 1;
      const float row_sign = row + 1 < H ? 1.0f : -1.0f;
      const float* xn = rays.x.ptr<float>(other_row);
      const float* yn = rays.y.ptr<float>(other_row);
      std::fill(best_t.begin(), best_t.end(), inf);
      std::fill(best_plane.begin(), best_plane.end(), -1);
      for (int p = 0; p < static_cast<int>(planes.size()); ++p) {
        const PlaneInCamera& pc = planes[p];
        if (row < pc.box.y || row >= pc.box.y + pc.box.height) continue;
        castRowSegment(pc, p, x, y, pc.box.x, pc.box.x + pc.box.width, best_t.data(), best_a.data(),
                       best_b.data(), best_plane.data());
      }
      float* out = radiance->ptr<float>(row);
      float* depth = depth_z ? depth_z->ptr<float>(row) : nullptr;
      for (int col = 0; col < W; ++col) {
        const int p = best_plane[col];
        if (p < 0) {
          out[col] = 0.0f;
          if (depth) depth[col] = inf;
          continue;
        }
        const int next_col = col + 1 < W ? col + 1 : col - 1;
        const float col_sign = col + 1 < W ? 1.0f : -1.0f;
        const TexturedPlane& tp = *sources[p];
        const float footprint =
            pixelFootprint(planes[p], best_t[col], x[col], y[col], col_sign * (x[next_col] - x[col]),
                           col_sign * (y[next_col] - y[col]), row_sign * (xn[col] - x[col]),
                           row_sign * (yn[col] - y[col])) * std::max(tp.inv_texel_u, tp.inv_texel_v);
        out[col] = sampleTrilinear(tp.mips, best_a[col] * tp.inv_texel_u - tp.texel_offset,
                                   best_b[col] * tp.inv_texel_v - tp.texel_offset, footprint);
        if (depth)
          depth[col] = static_cast<float>(zC + best_t[col] * (rz.x() * x[col] + rz.y() * y[col] + rz.z()));
      }
    }
  });
}

}  // namespace sim
}  // namespace ecs
