// The render-only path: deterministic ray marching through allocated space (no depth prior),
// for renders of arbitrary views (the renderer process, final outputs, exports).
#include <algorithm>
#include <climits>
#include <cmath>
#include <stdexcept>
#include <thread>

#include <opencv2/imgproc.hpp>

#include "mapper/ray_kernels.h"
#include "mapper/volume_renderer.h"

namespace radslam {

namespace {

using Corners = RayWorkspace::Corners;
using namespace ray_kernels;

template <int NB>
RayOutput marchImpl(const Field& field, const Ray& ray, const MarchParams& params,
                    const Eigen::Vector3f& bg) {
  constexpr int C = 1 + 3 * NB;
  RayOutput out;
  if (field.empty()) {
    for (int k = 0; k < 3; ++k) out.color[k] = bg[k];
    return out;
  }
  float t0, t1;
  if (!intersectBox(ray, field.boundsMin(), field.boundsMax(), &t0, &t1)) t1 = -1;
  t0 = std::max(t0, params.near);
  t1 = std::min(t1, params.far);
  const int levels = field.numLevels();
  const float basis[4] = {1.f, ray.view_dir.x(), ray.view_dir.y(), ray.view_dir.z()};
  const float bias = field.densityBias();
  const float scale = field.densityScale();
  const float fine_step = params.step_fine * static_cast<float>(field.voxelSize(levels - 1));
  const float coarse_edge = static_cast<float>(field.voxelSize(0)) * Field::kBlockDim;
  const float fine_edge = static_cast<float>(field.voxelSize(levels - 1)) * Field::kBlockDim;
  const float nudge = 1e-3f * fine_step;  // past a block face
  Corners corners[Field::kMaxLevels];
  CellCache cache[Field::kMaxLevels];
  int coarse_block[3] = {INT32_MIN, 0, 0};  // last coarse block found allocated
  float transmit = 1.f;
  double s0 = 0, s1 = 0, s2 = 0;  // sum w, sum w t, sum w t^2
  float color[3] = {0, 0, 0};
  float t = t0;
  int samples = 0;
  while (t < t1 && transmit > params.min_transmittance) {
    const float p[3] = {ray.origin.x() + t * ray.dir.x(), ray.origin.y() + t * ray.dir.y(),
                        ray.origin.z() + t * ray.dir.z()};
    // Empty space: skip the whole unallocated coarse block, else the fine block.
    const int cb[3] = {static_cast<int>(std::floor(p[0] / coarse_edge)),
                       static_cast<int>(std::floor(p[1] / coarse_edge)),
                       static_cast<int>(std::floor(p[2] / coarse_edge))};
    if (cb[0] != coarse_block[0] || cb[1] != coarse_block[1] || cb[2] != coarse_block[2]) {
      if (field.findBlock(0, cb[0], cb[1], cb[2]) < 0) {
        t = std::max(t + nudge, cubeExit(ray, p, coarse_edge) + nudge);
        continue;
      }
      std::copy(cb, cb + 3, coarse_block);
    }
    float raw[C];
    if (!evaluate<C>(field, p, corners, raw, cache)) {
      t = std::max(t + nudge, cubeExit(ray, p, fine_edge) + nudge);
      continue;
    }
    const float step = fine_step;
    float sp, unused;
    softplusAndSigmoid(bias + raw[0], &sp, &unused);
    const float sigma = sp * scale;
    float c[3];
    shade<NB>(raw, basis, c);
    const float decay = fastExp(-sigma * step);
    const float w = transmit * (1.f - decay);
    transmit *= decay;
    s0 += w;
    s1 += double(w) * t;
    s2 += double(w) * t * t;
    for (int k = 0; k < 3; ++k) color[k] += w * c[k];
    ++samples;
    t += step;
  }
  const float W = static_cast<float>(s0);
  for (int k = 0; k < 3; ++k) out.color[k] = color[k] + (1.f - W) * bg[k];
  out.weight = W;
  out.samples = samples;
  if (params.normalize_depth) {
    if (W >= params.min_weight && W > 0) {
      const double d = s1 / s0;
      out.depth = static_cast<float>(d);
      out.var = static_cast<float>(std::max(0.0, s2 / s0 - d * d));
    }
  } else {
    out.depth = static_cast<float>(s1);
    out.var = static_cast<float>(std::max(0.0, s2 - s1 * s1 * (2.0 - s0)));
  }
  return out;
}

}  // namespace

bool intersectBox(const Ray& ray, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi,
                  float* t_enter, float* t_exit) {
  float a = -INFINITY, b = INFINITY;
  for (int d = 0; d < 3; ++d) {
    const float o = ray.origin[d], dir = ray.dir[d];
    if (std::abs(dir) < 1e-12f) {
      if (o < lo[d] || o > hi[d]) return false;
      continue;
    }
    float t0 = (lo[d] - o) / dir, t1 = (hi[d] - o) / dir;
    if (t0 > t1) std::swap(t0, t1);
    a = std::max(a, t0);
    b = std::min(b, t1);
  }
  *t_enter = a;
  *t_exit = b;
  return b >= a;
}

RayOutput VolumeRenderer::march(const Field& field, const Ray& ray,
                                const MarchParams& params) const {
  return field.colorBasis() == 4 ? marchImpl<4>(field, ray, params, background_)
                                 : marchImpl<1>(field, ray, params, background_);
}

RenderImages VolumeRenderer::render(const Field& field, const SE3& T_world_cam,
                                    const CameraModel& camera, const MarchParams& params,
                                    int threads) const {
  if (camera.width <= 0 || camera.height <= 0 || !(camera.fx > 0) || !(camera.fy > 0))
    throw std::invalid_argument("render: camera needs positive size and focal lengths, got " +
                                std::to_string(camera.width) + "x" + std::to_string(camera.height));
  RenderImages out;
  out.color.create(camera.height, camera.width, CV_32FC3);
  out.depth.create(camera.height, camera.width, CV_32FC1);
  out.sigma.create(camera.height, camera.width, CV_32FC1);
  out.weight.create(camera.height, camera.width, CV_32FC1);
  auto rows = [&](int r0, int r1) {
    for (int v = r0; v < r1; ++v) {
      cv::Vec3f* color = out.color.ptr<cv::Vec3f>(v);
      float* depth = out.depth.ptr<float>(v);
      float* sigma = out.sigma.ptr<float>(v);
      float* weight = out.weight.ptr<float>(v);
      for (int u = 0; u < camera.width; ++u) {
        const Eigen::Vector3d cam_dir((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1);
        const RayOutput r = march(field, makeRay(T_world_cam, cam_dir), params);
        color[u] = cv::Vec3f(r.color[0], r.color[1], r.color[2]);
        depth[u] = r.depth;
        sigma[u] = std::sqrt(std::max(0.f, r.var));
        weight[u] = r.weight;
      }
    }
  };
  threads = std::clamp(threads, 1, camera.height);
  if (threads == 1) {
    rows(0, camera.height);
  } else {
    std::vector<std::thread> pool;
    for (int k = 0; k < threads; ++k)
      pool.emplace_back(rows, camera.height * k / threads, camera.height * (k + 1) / threads);
    for (std::thread& th : pool) th.join();
  }
  return out;
}

cv::Mat toBgr8(const cv::Mat& rgb) {
  cv::Mat bgr;
  cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
  cv::Mat out;
  bgr.convertTo(out, CV_8UC3, 255.0);
  return out;
}

}  // namespace radslam
