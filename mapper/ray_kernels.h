// Inner loops shared by the training renderer (volume_renderer.cc) and the render-only ray
// marcher (volume_march.cc): voxel lookup, trilinear gathering and shading. Internal to
// mapper/; inline so that both hot loops compile them in place.
#pragma once

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstring>

#include <Eigen/Core>

#include "mapper/field.h"
#include "mapper/volume_renderer.h"

namespace radslam::ray_kernels {

using Corners = RayWorkspace::Corners;

// floor(x) as an int, for |x| < 2^31: without SSE4.1, std::floor is a longer sequence with a
// branch.
[[gnu::always_inline]] inline int floorToInt(float x) {
  const int i = static_cast<int>(x);
  return i - (x < static_cast<float>(i));
}

// Offsets of the 8 cell corners within one block; corner c has dx = c & 1, dy = (c >> 1) & 1,
// dz = c >> 2.
constexpr int kCornerOffset[8] = {0,
                                  1,
                                  Field::kBlockDim,
                                  Field::kBlockDim + 1,
                                  Field::kBlockDim* Field::kBlockDim,
                                  Field::kBlockDim* Field::kBlockDim + 1,
                                  Field::kBlockDim* Field::kBlockDim + Field::kBlockDim,
                                  Field::kBlockDim* Field::kBlockDim + Field::kBlockDim + 1};

// The last cell located at a level along a ray: consecutive samples often share a cell
// (samples are closer than a voxel), and then its corners are reused.
struct CellCache {
  int cell[3] = {INT32_MIN, 0, 0};
  int32_t vox[8];
  uint8_t mask = 0;
};

// Finds the 8 lattice points around p at one level. mask bit c = corner c allocated.
inline void locate(const Field& field, int level, const float* p, Corners* c,
                   CellCache* cache = nullptr) {
  const float inv = field.invVoxelSize(level);
  const float qx = p[0] * inv, qy = p[1] * inv, qz = p[2] * inv;
  const float fx = std::floor(qx), fy = std::floor(qy), fz = std::floor(qz);
  const int ix = static_cast<int>(fx), iy = static_cast<int>(fy), iz = static_cast<int>(fz);
  c->frac[0] = qx - fx;
  c->frac[1] = qy - fy;
  c->frac[2] = qz - fz;
  if (cache) {
    if (cache->cell[0] == ix && cache->cell[1] == iy && cache->cell[2] == iz) {
      std::copy(cache->vox, cache->vox + 8, c->vox);
      c->mask = cache->mask;
      return;
    }
    cache->cell[0] = ix;
    cache->cell[1] = iy;
    cache->cell[2] = iz;
    locate(field, level, p, c);
    std::copy(c->vox, c->vox + 8, cache->vox);
    cache->mask = c->mask;
    return;
  }
  const int lx = localOf(ix), ly = localOf(iy), lz = localOf(iz);
  constexpr int kLast = Field::kBlockDim - 1;
  if (lx < kLast && ly < kLast && lz < kLast) {
    // Fast path: the whole cell lies in one block.
    const int b = field.findBlock(level, blockOf(ix), blockOf(iy), blockOf(iz));
    if (b < 0) {
      c->mask = 0;
      return;
    }
    const int base = b * Field::kBlockVoxels + Field::voxelInBlock(lx, ly, lz);
    for (int k = 0; k < 8; ++k) c->vox[k] = base + kCornerOffset[k];
    c->mask = 0xFF;
    return;
  }
  uint8_t mask = 0;
  int last_key[3] = {INT32_MIN, 0, 0};
  int last_block = -1;
  for (int k = 0; k < 8; ++k) {
    const int x = ix + (k & 1), y = iy + ((k >> 1) & 1), z = iz + (k >> 2);
    const int bx = blockOf(x), by = blockOf(y), bz = blockOf(z);
    int b;
    if (bx == last_key[0] && by == last_key[1] && bz == last_key[2]) {
      b = last_block;
    } else {
      b = field.findBlock(level, bx, by, bz);
      last_key[0] = bx;
      last_key[1] = by;
      last_key[2] = bz;
      last_block = b;
    }
    if (b < 0) {
      c->vox[k] = 0;
      continue;
    }
    c->vox[k] = b * Field::kBlockVoxels + Field::voxelInBlock(localOf(x), localOf(y), localOf(z));
    mask |= static_cast<uint8_t>(1u << k);
  }
  c->mask = mask;
}

inline void cornerWeights(const float* frac, float* w) {
  const float wx[2] = {1 - frac[0], frac[0]};
  const float wy[2] = {1 - frac[1], frac[1]};
  const float wz[2] = {1 - frac[2], frac[2]};
  for (int k = 0; k < 8; ++k) w[k] = wx[k & 1] * wy[(k >> 1) & 1] * wz[k >> 2];
}

// raw[ch] += trilinear interpolation of the level's channels (local accumulators: raw may
// alias the workspace, which would force a store per term).
template <int C>
inline void gather(const float* data, const Corners& c, float* raw) {
  float w[8];
  cornerWeights(c.frac, w);
  float acc[C];
  for (int ch = 0; ch < C; ++ch) acc[ch] = raw[ch];
  if (c.mask == 0xFF) {
    for (int k = 0; k < 8; ++k) {
      const float* v = data + static_cast<size_t>(c.vox[k]) * C;
      for (int ch = 0; ch < C; ++ch) acc[ch] += w[k] * v[ch];
    }
  } else {
    for (int k = 0; k < 8; ++k) {
      if (!(c.mask & (1u << k))) continue;
      const float* v = data + static_cast<size_t>(c.vox[k]) * C;
      for (int ch = 0; ch < C; ++ch) acc[ch] += w[k] * v[ch];
    }
  }
  for (int ch = 0; ch < C; ++ch) raw[ch] = acc[ch];
}

// Evaluates the field at p: raw channels (bias not added) summed over levels. Returns false in
// empty space: where the finest level's block holding p is unallocated.
template <int C>
inline bool evaluate(const Field& field, const float* p, Corners* corners, float* raw,
                     CellCache* cache) {
  const int fine = field.numLevels() - 1;
  locate(field, fine, p, &corners[fine], &cache[fine]);
  if (!(corners[fine].mask & 1u)) return false;
  for (int ch = 0; ch < C; ++ch) raw[ch] = 0;
  gather<C>(field.levelData(fine), corners[fine], raw);
  for (int l = 0; l < fine; ++l) {
    locate(field, l, p, &corners[l], &cache[l]);
    if (corners[l].mask) gather<C>(field.levelData(l), corners[l], raw);
  }
  return true;
}

// Ray parameter where the ray leaves the axis-aligned box of cubes of edge `edge` (m) with
// integer indices lo .. hi (cube i spans i * edge .. (i + 1) * edge per axis). The indices are
// the caller's, found from the lattice as its lookups were: a cube found again from p here
// could round to the neighbour at a face and jump over a whole block.
inline float boxExit(const Ray& ray, const int* lo, const int* hi, float edge) {
  float t_exit = INFINITY;
  for (int d = 0; d < 3; ++d) {
    const float dir = ray.dir[d];
    if (std::abs(dir) < 1e-12f) continue;
    const float face = static_cast<float>(dir > 0 ? hi[d] + 1 : lo[d]) * edge;
    t_exit = std::min(t_exit, (face - ray.origin[d]) / dir);
  }
  return t_exit;
}
inline float cubeExit(const Ray& ray, const int* cube, float edge) {
  return boxExit(ray, cube, cube, edge);
}

// Colour from the raw coefficients: c_k = sigmoid(sum_j raw[1 + 3 j + k] basis[j]).
template <int NB>
inline void shade(const float* raw, const float* basis, float* color) {
  for (int k = 0; k < 3; ++k) {
    float r = raw[1 + k];
    for (int j = 1; j < NB; ++j) r += raw[1 + 3 * j + k] * basis[j];
    color[k] = sigmoid(r);
  }
}

// fastExp, log1pUnit, softplus and sigmoid of mapper/field.h on 4 lanes: the same operations
// in the same order, so each lane is bitwise equal to the scalar function (no FMA contraction
// or fast-math in this build).
using Lanes = Eigen::Array4f;

[[gnu::always_inline]] inline Lanes fastExp4(Lanes x) {
  x = x.max(-87.f).min(88.f);
  const Lanes r = (x * 1.44269504089f + 12582912.f) - 12582912.f;
  const Lanes f = (x - r * 0.693145751953125f) - r * 1.428606765330187e-06f;
  Lanes p = Lanes::Constant(1.f / 720);
  p = p * f + 1.f / 120;
  p = p * f + 1.f / 24;
  p = p * f + 1.f / 6;
  p = p * f + 0.5f;
  p = p * f + 1.f;
  p = p * f + 1.f;
  const Eigen::Array4i bits = (r.cast<int32_t>() + 127) * (1 << 23);
  Lanes scale;
  std::memcpy(scale.data(), bits.data(), sizeof(float) * 4);
  return p * scale;
}

[[gnu::always_inline]] inline Lanes log1pUnit4(const Lanes& e) {
  const Lanes s = e / (2.f + e);
  const Lanes s2 = s * s;
  Lanes p = Lanes::Constant(1.f / 11);
  p = p * s2 + 1.f / 9;
  p = p * s2 + 1.f / 7;
  p = p * s2 + 1.f / 5;
  p = p * s2 + 1.f / 3;
  p = p * s2 + 1.f;
  return (2.f * s) * p;
}

[[gnu::always_inline]] inline Lanes softplus4(const Lanes& x) {
  return x.max(0.f) + log1pUnit4(fastExp4(-x.abs()));
}
[[gnu::always_inline]] inline Lanes sigmoid4(const Lanes& x) { return 1.f / (1.f + fastExp4(-x)); }

// Front-to-back compositing of the render-only march: transmittance, colour and the weight
// moments that give depth and variance.
struct MarchAccumulator {
  float transmit = 1.f;
  double s0 = 0, s1 = 0, s2 = 0;  // sum w, sum w t, sum w t^2
  float color[3] = {0, 0, 0};
  int samples = 0;

  // A sample at t whose interval lets through decay = exp(-tau), of colour c (RGB).
  [[gnu::always_inline]] void add(float t, float decay, const float* c) {
    const float w = transmit * (1.f - decay);
    transmit *= decay;
    s0 += w;
    s1 += double(w) * t;
    s2 += double(w) * t * t;
    for (int k = 0; k < 3; ++k) color[k] += w * c[k];
    ++samples;
  }
  // Shades n <= 4 consecutive samples (raw channels per lane, colour coefficients with the SH
  // basis) and composites them in ray order, up to where the transmittance falls to
  // min_transmittance: false from there (the ray is opaque).
  template <int NB>
  [[gnu::always_inline]] bool addBatch(const float (*raw)[4], const Lanes& decay, const float* t,
                                       int n, const float* basis, float min_transmittance) {
    Lanes c[3];
    for (int k = 0; k < 3; ++k) {
      Lanes x(raw[1 + k]);
      for (int j = 1; j < NB; ++j) x += Lanes(raw[1 + 3 * j + k]) * basis[j];
      c[k] = sigmoid4(x);
    }
    for (int i = 0; i < n; ++i) {
      if (!(transmit > min_transmittance)) return false;
      const float rgb[3] = {c[0][i], c[1][i], c[2][i]};
      add(t[i], decay[i], rgb);
    }
    return true;
  }
  // The ray's output over background bg (MarchParams::normalize_depth and min_weight).
  RayOutput finish(const Eigen::Vector3f& bg, const MarchParams& params) const {
    RayOutput out;
    const float W = static_cast<float>(s0);
    for (int k = 0; k < 3; ++k) out.color[k] = color[k] + (1.f - W) * bg[k];
    out.weight = W;
    out.samples = samples;
    if (params.normalize_depth) {
      if (W >= params.min_weight && W > 0) {
        const double dm = s1 / s0;
        out.depth = static_cast<float>(dm);
        out.var = static_cast<float>(std::max(0.0, s2 / s0 - dm * dm));
      }
    } else {
      out.depth = static_cast<float>(s1);
      out.var = static_cast<float>(std::max(0.0, s2 - s1 * s1 * (2.0 - s0)));
    }
    return out;
  }
};

}  // namespace radslam::ray_kernels
