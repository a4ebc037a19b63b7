// Inner loops shared by the training renderer (volume_renderer.cc) and the render-only ray
// marcher (volume_march.cc): voxel lookup, trilinear gathering and shading. Internal to
// mapper/; inline so that both hot loops compile them in place.
#pragma once

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdint>

#include "mapper/field.h"
#include "mapper/volume_renderer.h"

namespace radslam::ray_kernels {

using Corners = RayWorkspace::Corners;

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

// Ray parameter where the ray leaves the axis-aligned cube of edge `edge` holding p.
inline float cubeExit(const Ray& ray, const float* p, float edge) {
  float t_exit = INFINITY;
  for (int d = 0; d < 3; ++d) {
    const float dir = ray.dir[d];
    if (std::abs(dir) < 1e-12f) continue;
    const float b = std::floor(p[d] / edge);
    const float face = (dir > 0 ? b + 1.f : b) * edge;
    t_exit = std::min(t_exit, (face - ray.origin[d]) / dir);
  }
  return t_exit;
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

}  // namespace radslam::ray_kernels
