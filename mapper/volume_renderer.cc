#include "mapper/volume_renderer.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include "mapper/ray_kernels.h"

namespace radslam {

namespace {

using Corners = RayWorkspace::Corners;
using Sample = RayWorkspace::Sample;
using namespace ray_kernels;

// Training rays stop once the transmittance falls below this: later samples would change the
// outputs and gradients by less than this fraction.
constexpr float kMinTransmittance = 1e-4f;

template <int NB>
RayOutput forwardImpl(const Field& field, const Ray& ray, const float* t, const float* delta, int n,
                      const Eigen::Vector3f& bg, RayWorkspace* ws) {
  constexpr int C = 1 + 3 * NB;
  const int levels = field.numLevels();
  ws->reserve(n, levels);
  const float basis[4] = {1.f, ray.view_dir.x(), ray.view_dir.y(), ray.view_dir.z()};
  const float bias = field.densityBias();
  const float scale = field.densityScale();
  int m = 0;
  float transmit = 1.f;
  float depth = 0.f, weight = 0.f;
  float color[3] = {0, 0, 0};
  // Samples are located (voxels found, their cache lines prefetched) kLookahead samples ahead
  // of the one being shaded, so memory latency overlaps with work, and samples past the point
  // where the ray turns opaque are never located.
  constexpr int kLookahead = 3;
  const int fine = levels - 1;
  int next = 0, located = 0;
  CellCache cache[Field::kMaxLevels];
  auto locateNext = [&]() {
    while (next < n) {
      const int i = next++;
      const float p[3] = {ray.origin.x() + t[i] * ray.dir.x(), ray.origin.y() + t[i] * ray.dir.y(),
                          ray.origin.z() + t[i] * ray.dir.z()};
      Corners* corners = &ws->corners[static_cast<size_t>(located) * levels];
      locate(field, fine, p, &corners[fine], &cache[fine]);
      if (!(corners[fine].mask & 1u)) continue;  // empty space
      for (int l = 0; l < fine; ++l) locate(field, l, p, &corners[l], &cache[l]);
      for (int l = 0; l < levels; ++l) {
        if (!corners[l].mask) continue;
        const float* data = field.levelData(l);
        for (int k = 0; k < 8; ++k)
          __builtin_prefetch(data + static_cast<size_t>(corners[l].vox[k]) * C);
      }
      ws->samples[located].t = t[i];
      ws->samples[located].delta = delta[i];
      ++located;
      return;
    }
  };
  for (int k = 0; k < kLookahead; ++k) locateNext();
  for (int i = 0; i < located && transmit >= kMinTransmittance; ++i) {
    locateNext();
    Sample& s = ws->samples[m];
    const Corners* corners = &ws->corners[static_cast<size_t>(i) * levels];
    for (int ch = 0; ch < C; ++ch) s.raw[ch] = 0;
    for (int l = 0; l < levels; ++l)
      if (corners[l].mask) gather<C>(field.levelData(l), corners[l], s.raw);
    float sp;
    softplusAndSigmoid(bias + s.raw[0], &sp, &s.dsoftplus);
    s.sigma = sp * scale;
    shade<NB>(s.raw, basis, s.color);
    s.decay = fastExp(-s.sigma * s.delta);
    s.transmit = transmit;
    s.w = transmit * (1.f - s.decay);
    transmit *= s.decay;
    weight += s.w;
    depth += s.w * s.t;
    for (int k = 0; k < 3; ++k) color[k] += s.w * s.color[k];
    ++m;
  }
  ws->n = m;
  RayOutput out;
  out.samples = m;
  float var = 0.f;
  for (int i = 0; i < m; ++i) {
    const Sample& s = ws->samples[i];
    var += s.w * (s.t - depth) * (s.t - depth);
  }
  for (int k = 0; k < 3; ++k) out.color[k] = color[k] + (1.f - weight) * bg[k];
  out.depth = depth;
  out.var = var;
  out.weight = weight;
  return out;
}

// Per-sample channel gradients (raw density and colour coefficients) for upstream gradients g;
// suffix carries sum_{j>i} e_j w_j along the backward loop.
template <int NB>
inline void sampleGrads(const RayWorkspace::Sample& s, const RayOutputGrad& g, float D, float W,
                        const Eigen::Vector3f& bg, const float* basis, float scale, float* suffix,
                        float* graw, float* gcol) {
  // e_i = d loss / d w_i (see the header's formulas; D* and Var depend on all weights).
  const float dt = s.t - D;
  float e = g.depth * s.t + g.var * (dt * dt - 2.f * s.t * D * (1.f - W));
  for (int k = 0; k < 3; ++k) e += g.color[k] * (s.color[k] - bg[k]);
  // d loss / d tau_i = e_i T_{i+1} - sum_{j>i} e_j w_j.
  const float dtau = e * s.transmit * s.decay - *suffix;
  *suffix += e * s.w;
  // Density through softplus (derivative = sigmoid), colour through the sigmoid and the basis.
  graw[0] = dtau * s.delta * scale * s.dsoftplus;
  for (int k = 0; k < 3; ++k) {
    gcol[k] = g.color[k] * s.w * s.color[k] * (1.f - s.color[k]);
    for (int j = 0; j < NB; ++j) graw[1 + 3 * j + k] = gcol[k] * basis[j];
  }
}

template <int NB>
void backwardImpl(const Field& field, const Ray& ray, const RayWorkspace& ws, const RayOutput& out,
                  const RayOutputGrad& g, const RayOutputGrad* g_pose, const Eigen::Vector3f& bg,
                  FieldGradient* grad, RayPoseGrad* pose) {
  constexpr int C = 1 + 3 * NB;
  const int levels = field.numLevels();
  const int n = ws.size();
  const float basis[4] = {1.f, ray.view_dir.x(), ray.view_dir.y(), ray.view_dir.z()};
  const float scale = field.densityScale();
  const float D = out.depth, W = out.weight;
  float suffix = 0.f, suffix_pose = 0.f;
  for (int i = n - 1; i >= 0; --i) {
    const RayWorkspace::Sample& s = ws.sample(i);
    if (i > 0) {
      // The gradient arrays are not in cache (the forward pass read the parameters): fetch
      // the next sample's corners while this one is processed.
      const RayWorkspace::Corners* next = &ws.corners[static_cast<size_t>(i - 1) * levels];
      for (int l = 0; l < levels; ++l) {
        if (!next[l].mask) continue;
        const float* g = grad->data(l);
        for (int k = 0; k < 8; ++k)
          __builtin_prefetch(g + static_cast<size_t>(next[l].vox[k]) * C, 1);
      }
    }
    float graw[C], gcol[3];
    sampleGrads<NB>(s, g, D, W, bg, basis, scale, &suffix, graw, gcol);
    // The pose may follow another loss (g_pose) than the field.
    float graw_pose_own[C], gcol_pose_own[3];
    const float* graw_pose = graw;
    const float* gcol_pose = gcol;
    if (pose && g_pose) {
      sampleGrads<NB>(s, *g_pose, D, W, bg, basis, scale, &suffix_pose, graw_pose_own,
                      gcol_pose_own);
      graw_pose = graw_pose_own;
      gcol_pose = gcol_pose_own;
    }
    if (pose && NB > 1) {
      // Colour depends on the viewing direction through basis j = 1..3.
      for (int d = 0; d < 3; ++d) {
        float gd = 0.f;
        for (int k = 0; k < 3; ++k) gd += gcol_pose[k] * s.raw[1 + 3 * (d + 1) + k];
        pose->g_dir[d] += gd;
      }
    }
    float gx[3] = {0, 0, 0};
    const RayWorkspace::Corners* corners = &ws.corners[static_cast<size_t>(i) * levels];
    for (int l = 0; l < levels; ++l) {
      const RayWorkspace::Corners& c = corners[l];
      if (!c.mask) continue;
      float w[8];
      cornerWeights(c.frac, w);
      float* gdata = grad->data(l);
      const float* data = field.levelData(l);
      // Corners 0 and 7 in one block: the whole cell is (the common case); touch it once.
      const bool one_block =
          c.mask == 0xFF && c.vox[0] / Field::kBlockVoxels == c.vox[7] / Field::kBlockVoxels;
      if (one_block) grad->touch(l, c.vox[0] / Field::kBlockVoxels);
      float sc[8] = {0, 0, 0, 0, 0, 0, 0, 0};  // d loss / d (field value) per corner
      for (int k = 0; k < 8; ++k) {
        if (!(c.mask & (1u << k))) continue;
        if (!one_block) grad->touch(l, c.vox[k] / Field::kBlockVoxels);
        grad->markVoxel(l, c.vox[k]);
        float* gv = gdata + static_cast<size_t>(c.vox[k]) * C;
        for (int ch = 0; ch < C; ++ch) gv[ch] += w[k] * graw[ch];
        if (pose) {
          const float* v = data + static_cast<size_t>(c.vox[k]) * C;
          float acc = 0.f;
          for (int ch = 0; ch < C; ++ch) acc += graw_pose[ch] * v[ch];
          sc[k] = acc;
        }
      }
      if (pose) {
        // Spatial gradient of the trilinear weights, times 1 / voxel size.
        const float fx = c.frac[0], fy = c.frac[1], fz = c.frac[2];
        const float wx[2] = {1 - fx, fx}, wy[2] = {1 - fy, fy}, wz[2] = {1 - fz, fz};
        const float inv = field.invVoxelSize(l);
        for (int k = 0; k < 8; ++k) {
          const int dx = k & 1, dy = (k >> 1) & 1, dz = k >> 2;
          gx[0] += sc[k] * (dx ? 1.f : -1.f) * wy[dy] * wz[dz] * inv;
          gx[1] += sc[k] * wx[dx] * (dy ? 1.f : -1.f) * wz[dz] * inv;
          gx[2] += sc[k] * wx[dx] * wy[dy] * (dz ? 1.f : -1.f) * inv;
        }
      }
    }
    if (pose) {
      for (int d = 0; d < 3; ++d) {
        pose->g_pos[d] += gx[d];
        pose->g_tpos[d] += s.t * gx[d];
      }
    }
  }
}

}  // namespace

Ray makeRay(const SE3& T_world_cam, const Eigen::Vector3d& cam_dir) {
  Ray r;
  const Eigen::Vector3d d = T_world_cam.so3() * cam_dir;
  r.origin = T_world_cam.translation().cast<float>();
  r.dir = d.cast<float>();
  r.view_dir = d.normalized().cast<float>();
  r.cam_dir = cam_dir.cast<float>();
  return r;
}

void RayWorkspace::reserve(int samples, int levels) {
  if (static_cast<int>(this->samples.size()) < samples) this->samples.resize(samples);
  if (corners.size() < static_cast<size_t>(samples) * levels)
    corners.resize(static_cast<size_t>(samples) * levels);
  this->levels = levels;
}

void FieldGradient::resize(const Field& field) {
  const int levels = field.numLevels();
  grad_.resize(levels);
  voxel_bits_.resize(levels);
  touched_flag_.resize(levels);
  touched_.resize(levels);
  for (int l = 0; l < levels; ++l) {
    // The field's reservation, so that growth does not move the arrays either.
    const size_t capacity = field.blockCapacity(l);
    grad_[l].reserve(capacity * Field::kBlockVoxels * field.channels());
    voxel_bits_[l].reserve(capacity * kWords);
    touched_flag_[l].reserve(capacity);
    grad_[l].resize(field.levelSize(l), 0.f);
    voxel_bits_[l].resize(size_t(field.numBlocks(l)) * kWords, 0);
    touched_flag_[l].resize(field.numBlocks(l), 0);
  }
}

void FieldGradient::clear(int channels) {
  const size_t block_floats = size_t(Field::kBlockVoxels) * channels;
  for (size_t l = 0; l < grad_.size(); ++l)
    for (int b : touched_[l]) std::fill_n(grad_[l].begin() + b * block_floats, block_floats, 0.f);
  forgetTouched();
}

void FieldGradient::forgetTouched() {
  for (size_t l = 0; l < touched_.size(); ++l) {
    for (int b : touched_[l]) {
      touched_flag_[l][b] = 0;
      std::fill_n(voxel_bits_[l].begin() + size_t(b) * kWords, kWords, 0);
    }
    touched_[l].clear();
  }
}

Vec6 poseGradient(const SE3& T_world_cam, const Ray& ray, const RayPoseGrad& g) {
  // x_i = T (t_i d_c): dx_i/dv = R, dx_i/dw = -R hat(t_i d_c); view_dir: d/dw = -R hat(d_hat).
  const Mat3 Rt = T_world_cam.rotation().transpose();
  const Vec3 d_cam = ray.cam_dir.cast<double>();
  Vec6 out;
  out.head<3>() = Rt * g.g_pos.cast<double>();
  out.tail<3>() = d_cam.cross(Rt * g.g_tpos.cast<double>()) +
                  d_cam.normalized().cross(Rt * g.g_dir.cast<double>());
  return out;
}

int maxSamples(const SamplingParams& params) {
  return std::max(params.surface_samples + params.spread_samples, params.free_samples);
}

int sampleRay(const SamplingParams& params, float depth, float depth_sigma, float t_enter,
              float t_exit, Rng* rng, float* t, float* delta) {
  int n = 0;
  if (depth > 0) {
    const float sigma = std::clamp(depth_sigma, params.sigma_min, params.sigma_max);
    const float lo = std::max(params.near, depth - params.sigma_range * sigma);
    const float hi = depth + params.sigma_range * sigma;
    if (hi <= lo) return 0;
    if (params.spread_samples > 0 && lo > params.near) {
      const float a = std::max(params.near, t_enter);
      if (lo > a) {
        const float bin = (lo - a) / params.spread_samples;
        for (int i = 0; i < params.spread_samples; ++i) t[n++] = a + (i + rng->uniform()) * bin;
      }
    }
    const float bin = (hi - lo) / params.surface_samples;
    for (int i = 0; i < params.surface_samples; ++i) t[n++] = lo + (i + rng->uniform()) * bin;
    for (int i = 0; i + 1 < n; ++i) delta[i] = t[i + 1] - t[i];
    if (n > 0) delta[n - 1] = bin;
    return n;
  }
  const float a = std::max(params.near, t_enter);
  const float b = std::min(params.far, t_exit);
  if (!(b > a) || params.free_samples <= 0) return 0;
  const float bin = (b - a) / params.free_samples;
  for (int i = 0; i < params.free_samples; ++i) t[n++] = a + (i + rng->uniform()) * bin;
  for (int i = 0; i + 1 < n; ++i) delta[i] = t[i + 1] - t[i];
  delta[n - 1] = bin;
  return n;
}

RayOutput VolumeRenderer::forward(const Field& field, const Ray& ray, const float* t,
                                  const float* delta, int n, RayWorkspace* ws) const {
  return field.colorBasis() == 4 ? forwardImpl<4>(field, ray, t, delta, n, background_, ws)
                                 : forwardImpl<1>(field, ray, t, delta, n, background_, ws);
}

void VolumeRenderer::backward(const Field& field, const Ray& ray, const RayWorkspace& ws,
                              const RayOutput& out, const RayOutputGrad& g, FieldGradient* grad,
                              RayPoseGrad* pose, const RayOutputGrad* g_pose) const {
  if (field.colorBasis() == 4)
    backwardImpl<4>(field, ray, ws, out, g, g_pose, background_, grad, pose);
  else
    backwardImpl<1>(field, ray, ws, out, g, g_pose, background_, grad, pose);
}

}  // namespace radslam
