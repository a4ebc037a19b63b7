// The render-only path: deterministic ray marching through allocated space (no depth prior),
// for renders of arbitrary views (the renderer process, final outputs, exports).
#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

#include "common/parallel.h"
#include "mapper/ray_kernels.h"
#include "mapper/volume_renderer.h"

namespace radslam {

namespace {

using namespace ray_kernels;

// A level's lattice cell around the current sample, kept while the ray stays in it: pointers to
// the channels of its 8 corners (unallocated corners point at zeros, which add nothing), and the
// last block found, so that moving to the next cell of the same block needs no lookup.
template <int C>
struct LevelCursor {
  const float* data = nullptr;
  float inv = 0;  // 1 / voxel size, 1/m
  int level = 0;
  int cell[3] = {INT32_MIN, 0, 0};
  int block_key[3] = {INT32_MIN, 0, 0};
  int block = -1;
  bool corner0 = false;  // corner 0 allocated
  const float* corner[8];
};

template <int C>
struct Zeros {
  static constexpr float values[C] = {};
};

// Moves the cursor to the cell holding p and returns the position within it (as locate()).
template <int C>
[[gnu::always_inline]] inline void moveTo(const Field& field, const float* p, LevelCursor<C>* cur,
                                          float* frac) {
  const float qx = p[0] * cur->inv, qy = p[1] * cur->inv, qz = p[2] * cur->inv;
  const float fx = std::floor(qx), fy = std::floor(qy), fz = std::floor(qz);
  frac[0] = qx - fx;
  frac[1] = qy - fy;
  frac[2] = qz - fz;
  const int ix = static_cast<int>(fx), iy = static_cast<int>(fy), iz = static_cast<int>(fz);
  if (ix == cur->cell[0] && iy == cur->cell[1] && iz == cur->cell[2]) return;
  cur->cell[0] = ix;
  cur->cell[1] = iy;
  cur->cell[2] = iz;
  const int lx = localOf(ix), ly = localOf(iy), lz = localOf(iz);
  constexpr int kLast = Field::kBlockDim - 1;
  if (lx < kLast && ly < kLast && lz < kLast) {
    // The whole cell lies in one block.
    const int bx = blockOf(ix), by = blockOf(iy), bz = blockOf(iz);
    if (bx != cur->block_key[0] || by != cur->block_key[1] || bz != cur->block_key[2]) {
      cur->block_key[0] = bx;
      cur->block_key[1] = by;
      cur->block_key[2] = bz;
      cur->block = field.findBlock(cur->level, bx, by, bz);
    }
    cur->corner0 = cur->block >= 0;
    if (!cur->corner0) {
      for (int k = 0; k < 8; ++k) cur->corner[k] = Zeros<C>::values;
      return;
    }
    const float* base = cur->data + (static_cast<size_t>(cur->block) * Field::kBlockVoxels +
                                     Field::voxelInBlock(lx, ly, lz)) *
                                        C;
    for (int k = 0; k < 8; ++k) cur->corner[k] = base + kCornerOffset[k] * C;
    return;
  }
  // The cell spans up to 8 blocks.
  for (int k = 0; k < 8; ++k) {
    const int x = ix + (k & 1), y = iy + ((k >> 1) & 1), z = iz + (k >> 2);
    const int bx = blockOf(x), by = blockOf(y), bz = blockOf(z);
    if (bx != cur->block_key[0] || by != cur->block_key[1] || bz != cur->block_key[2]) {
      cur->block_key[0] = bx;
      cur->block_key[1] = by;
      cur->block_key[2] = bz;
      cur->block = field.findBlock(cur->level, bx, by, bz);
    }
    if (k == 0) cur->corner0 = cur->block >= 0;
    cur->corner[k] = cur->block < 0
                         ? Zeros<C>::values
                         : cur->data + (static_cast<size_t>(cur->block) * Field::kBlockVoxels +
                                        Field::voxelInBlock(localOf(x), localOf(y), localOf(z))) *
                                           C;
  }
}

// raw[ch] += trilinear interpolation at the cursor's cell (the same sums, in the same order, as
// gather(); a zero corner adds exactly 0).
template <int C>
[[gnu::always_inline]] inline void gatherCell(const LevelCursor<C>& cur, const float* frac,
                                              float* raw) {
  // cornerWeights(), unrolled.
  const float wx[2] = {1 - frac[0], frac[0]};
  const float wy[2] = {1 - frac[1], frac[1]};
  const float wz[2] = {1 - frac[2], frac[2]};
  float acc[C];
  for (int ch = 0; ch < C; ++ch) acc[ch] = raw[ch];
#pragma GCC unroll 8
  for (int k = 0; k < 8; ++k) {
    const float w = wx[k & 1] * wy[(k >> 1) & 1] * wz[k >> 2];
    const float* v = cur.corner[k];
    for (int ch = 0; ch < C; ++ch) acc[ch] += w * v[ch];
  }
  for (int ch = 0; ch < C; ++ch) raw[ch] = acc[ch];
}

// What the march does in a fine sub-block (Field::kSubDim^3 fine cells).
enum class SubBlock {
  kSample,    // evaluate the field at each sample
  kSkip,      // density bound below MarchParams::skip_thickness: step over it
  kConstant,  // every level reads zeros there: density softplus(bias), colour sigmoid(0)
};

// Judges the fine sub-block (sx, sy, sz) (fine lattice index >> kSubShift) holding p from the
// tables of Field::densityBounds and Field::zeroSubBlocks: its entry plus, per coarser level,
// the entry of the sub-block holding p (which holds the whole fine sub-block, the voxel sizes
// being integer multiples). Unallocated fine blocks are not judged here (the march jumps over
// them itself). *bound: the sub-block's raw density bound, bias included (+inf when unknown);
// complete only with need_bound.
inline SubBlock judgeSubBlock(const Field& field, int fine, int sx, int sy, int sz,
                              const float* const* bounds, const uint8_t* const* zeros,
                              const float* p, float bias, float skip_raw, bool need_bound,
                              float* bound_out) {
  *bound_out = INFINITY;
  // Two sub-blocks per block and axis: the low bit of a sub-block index picks the half, the
  // rest (arithmetic shift, floors negatives) is the block.
  static_assert(Field::kBlockDim == 2 * Field::kSubDim, "two sub-blocks per block and axis");
  auto sub_of = [](int x, int y, int z) { return (x & 1) | ((y & 1) << 1) | ((z & 1) << 2); };
  const int fb = field.findBlock(fine, sx >> 1, sy >> 1, sz >> 1);
  if (fb < 0) return SubBlock::kSample;
  size_t entry = static_cast<size_t>(fb) * Field::kSubBlocks + sub_of(sx, sy, sz);
  float bound = bias + bounds[fine][entry];
  bool zero = zeros[fine][entry];
  for (int l = 0; l < fine && (zero || need_bound || bound < skip_raw); ++l) {
    const float inv = field.invVoxelSize(l);
    const int x = static_cast<int>(std::floor(p[0] * inv)) >> Field::kSubShift;
    const int y = static_cast<int>(std::floor(p[1] * inv)) >> Field::kSubShift;
    const int z = static_cast<int>(std::floor(p[2] * inv)) >> Field::kSubShift;
    const int b = field.findBlock(l, x >> 1, y >> 1, z >> 1);
    // No entry for an unallocated block (its cells also read its neighbours' points).
    if (b < 0) return SubBlock::kSample;
    entry = static_cast<size_t>(b) * Field::kSubBlocks + sub_of(x, y, z);
    bound += bounds[l][entry];
    zero = zero && zeros[l][entry];
  }
  *bound_out = bound;
  if (bound < skip_raw) return SubBlock::kSkip;
  return zero ? SubBlock::kConstant : SubBlock::kSample;
}

// Samples at t = t0, t0 + step, ... through allocated space; at an unallocated coarse or fine
// block the ray jumps just past the block's exit face. The per-sample work is the fine cell
// (cached per level), the trilinear sums and the shading; block lookups happen only when a
// cursor enters a new block. Each fine sub-block entered is judged once (judgeSubBlock): where
// every level reads zeros the samples are composited without lookups (the same values, so the
// render is unchanged), and the approximations of MarchParams (skip, adaptive step) act there.
template <int NB>
RayOutput marchImpl(const Field& field, const Ray& ray, const MarchParams& params,
                    const Eigen::Vector3f& bg) {
  constexpr int C = 1 + 3 * NB;
  if (field.empty()) return MarchAccumulator().finish(bg, params);
  float t0, t1;
  if (!intersectBox(ray, field.boundsMin(), field.boundsMax(), &t0, &t1)) t1 = -1;
  t0 = std::max(t0, params.near);
  t1 = std::min(t1, params.far);
  const int levels = field.numLevels();
  const int fine = levels - 1;
  const float basis[4] = {1.f, ray.view_dir.x(), ray.view_dir.y(), ray.view_dir.z()};
  const float bias = field.densityBias();
  const float scale = field.densityScale();
  const float fine_step = params.step_fine * static_cast<float>(field.voxelSize(fine));
  const float coarse_edge = static_cast<float>(field.voxelSize(0)) * Field::kBlockDim;
  const float fine_edge = static_cast<float>(field.voxelSize(fine)) * Field::kBlockDim;
  const float nudge = 1e-3f * fine_step;  // past a block face
  const float o[3] = {ray.origin.x(), ray.origin.y(), ray.origin.z()};
  const float d[3] = {ray.dir.x(), ray.dir.y(), ray.dir.z()};
  LevelCursor<C> cursor[Field::kMaxLevels];
  for (int l = 0; l < levels; ++l) {
    cursor[l].data = field.levelData(l);
    cursor[l].inv = field.invVoxelSize(l);
    cursor[l].level = l;
  }
  int coarse_block[3] = {INT32_MIN, 0, 0};  // last coarse block found allocated
  // Sub-block tables (judgeSubBlock): per level, the density bounds and zero flags; the raw
  // density (bias included) below which a sub-block is skipped (softplus(raw) < skip_thickness,
  // softplus being increasing); the last fine sub-block judged and the verdict.
  const float* bounds[Field::kMaxLevels] = {};
  const uint8_t* zeros[Field::kMaxLevels] = {};
  for (int l = 0; l < levels; ++l) {
    bounds[l] = field.densityBounds(l);
    zeros[l] = field.zeroSubBlocks(l);
  }
  const float skip_raw =
      params.skip_thickness > 0 ? std::log(std::expm1(params.skip_thickness)) : -INFINITY;
  const float sub_edge = static_cast<float>(field.voxelSize(fine)) * Field::kSubDim;  // m
  int sub_key[3] = {INT32_MIN, 0, 0};
  SubBlock sub_state = SubBlock::kSample;
  // Adaptive step (max_sample_thickness > 0): the current sub-block's step (m) and where the ray
  // leaves it.
  const bool adaptive = params.max_sample_thickness > 0;
  const float max_step = std::max(fine_step, static_cast<float>(field.voxelSize(fine)) *
                                                 std::max(params.step_fine, params.max_step_fine));
  float sub_step = fine_step, sub_exit = INFINITY;
  // The field where every level reads zeros, computed as the lanes below compute it, so that
  // a constant sub-block composites exactly what sampling it would.
  const float const_decay = fastExp4(-(softplus4(bias + Lanes::Zero()) * scale) * fine_step)[0];
  const float const_color = sigmoid4(Lanes::Zero())[0];
  const float const_rgb[3] = {const_color, const_color, const_color};
  MarchAccumulator acc;
  float t = t0;
  // Samples go in batches of up to kLanes consecutive ones in allocated space: their lookups
  // one by one, their shading on lanes, then the compositing in ray order (which stops where
  // the scalar loop would).
  constexpr int kLanes = 4;
  bool opaque = false;
  while (!opaque && t < t1 && acc.transmit > params.min_transmittance) {
    float tb[kLanes];
    float db[kLanes];  // intervals, m
    float raw[C][kLanes] = {};
    int n = 0;
    float ts = t;
    for (float step = fine_step; n < kLanes && ts < t1; ts += step) {
      const float p[3] = {o[0] + ts * d[0], o[1] + ts * d[1], o[2] + ts * d[2]};
      // Empty space: skip the whole unallocated coarse block, else the fine block (only as the
      // batch's first sample: a later one ends the batch and starts the next).
      const int cb[3] = {static_cast<int>(std::floor(p[0] / coarse_edge)),
                         static_cast<int>(std::floor(p[1] / coarse_edge)),
                         static_cast<int>(std::floor(p[2] / coarse_edge))};
      if (cb[0] != coarse_block[0] || cb[1] != coarse_block[1] || cb[2] != coarse_block[2]) {
        if (field.findBlock(0, cb[0], cb[1], cb[2]) < 0) {
          if (n == 0) ts = std::max(ts + nudge, cubeExit(ray, cb, coarse_edge) + nudge);
          break;
        }
        std::copy(cb, cb + 3, coarse_block);
      }
      {
        const float inv = cursor[fine].inv;
        const int sx = static_cast<int>(std::floor(p[0] * inv)) >> Field::kSubShift;
        const int sy = static_cast<int>(std::floor(p[1] * inv)) >> Field::kSubShift;
        const int sz = static_cast<int>(std::floor(p[2] * inv)) >> Field::kSubShift;
        if (sx != sub_key[0] || sy != sub_key[1] || sz != sub_key[2]) {
          sub_key[0] = sx;
          sub_key[1] = sy;
          sub_key[2] = sz;
          float bound;
          sub_state = judgeSubBlock(field, fine, sx, sy, sz, bounds, zeros, p, bias, skip_raw,
                                    adaptive, &bound);
          if (adaptive) {
            // Steps of at most max_sample_thickness where the bound allows (softplus(bound) is
            // the thickness per fine voxel), never past the sub-block's exit.
            const float thickness = softplus(bound) * scale;  // 1/m
            sub_step = std::clamp(params.max_sample_thickness / thickness, fine_step, max_step);
            sub_exit = cubeExit(ray, sub_key, sub_edge);
          }
        }
        if (adaptive) step = std::min(sub_step, std::max(sub_exit - ts, 0.f) + nudge);
        if (sub_state == SubBlock::kSkip) {
          // Over the rest of the sub-block, staying on the sample grid; the loop's increment
          // adds the last step.
          const float steps = std::ceil((cubeExit(ray, sub_key, sub_edge) - ts) / fine_step);
          ts += std::max(0.f, steps - 1.f) * fine_step;
          step = fine_step;
          continue;
        }
        if (sub_state == SubBlock::kConstant) {
          // The batch so far goes first; this sample starts the next one.
          if (n > 0) break;
          // Samples of a constant field: no lookups, the compositing of the loop below.
          const float exit = std::min(cubeExit(ray, sub_key, sub_edge), t1);
          const float decay = step == fine_step
                                  ? const_decay
                                  : fastExp4(-(softplus4(bias + Lanes::Zero()) * scale) * step)[0];
          do {
            if (!(acc.transmit > params.min_transmittance)) {
              opaque = true;
              break;
            }
            acc.add(ts, decay, const_rgb);
            ts += step;
          } while (ts < exit);
          break;
        }
      }
      float frac[3];
      moveTo(field, p, &cursor[fine], frac);
      if (!cursor[fine].corner0) {
        if (n == 0) {
          const int fb[3] = {blockOf(cursor[fine].cell[0]), blockOf(cursor[fine].cell[1]),
                             blockOf(cursor[fine].cell[2])};
          ts = std::max(ts + nudge, cubeExit(ray, fb, fine_edge) + nudge);
        }
        break;
      }
      float r[C] = {};
      gatherCell(cursor[fine], frac, r);
      for (int l = 0; l < fine; ++l) {
        moveTo(field, p, &cursor[l], frac);
        gatherCell(cursor[l], frac, r);
      }
      for (int ch = 0; ch < C; ++ch) raw[ch][n] = r[ch];
      db[n] = step;
      tb[n++] = ts;
    }
    t = ts;
    if (n == 0) continue;
    const Lanes sigma = softplus4(bias + Lanes(raw[0])) * scale;
    const Lanes decay = adaptive ? fastExp4(-sigma * Lanes(db)) : fastExp4(-sigma * fine_step);
    opaque = !acc.addBatch<NB>(raw, decay, tb, n, basis, params.min_transmittance);
  }
  return acc.finish(bg, params);
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
                                    int threads, const RollingShutterView& rolling_shutter) const {
  return renderPinhole(
      T_world_cam, camera, threads,
      [&](const Ray& ray, int, int) { return march(field, ray, params); }, rolling_shutter);
}

RenderImages renderPinhole(const SE3& T_world_cam, const CameraModel& camera, int threads,
                           const std::function<RayOutput(const Ray&, int u, int v)>& march_ray,
                           const RollingShutterView& rolling_shutter) {
  if (camera.width <= 0 || camera.height <= 0 || !(camera.fx > 0) || !(camera.fy > 0))
    throw std::invalid_argument("render: camera needs positive size and focal lengths, got " +
                                std::to_string(camera.width) + "x" + std::to_string(camera.height));
  const cv::Mat& exposure = rolling_shutter.exposure_s;
  if (!exposure.empty() && (exposure.type() != CV_32FC1 || exposure.cols != camera.width ||
                            exposure.rows != camera.height))
    throw std::invalid_argument("render: exposure times must be CV_32FC1 of the camera's size");
  RenderImages out;
  out.color.create(camera.height, camera.width, CV_32FC3);
  out.depth.create(camera.height, camera.width, CV_32FC1);
  out.sigma.create(camera.height, camera.width, CV_32FC1);
  out.weight.create(camera.height, camera.width, CV_32FC1);
  // Square tiles: neighbouring rays read the same voxels while they are still in cache (row
  // by row, a ray's cells are evicted before the next row reaches them). Threads take every
  // threads-th band of tiles; each pixel is independent, so the result does not depend on it.
  constexpr int kTile = 16;  // pixels
  const int bands = (camera.height + kTile - 1) / kTile;
  auto work = [&](int first_band, int band_step) {
    for (int band = first_band; band < bands; band += band_step) {
      const int v0 = band * kTile, v1 = std::min(camera.height, v0 + kTile);
      for (int u0 = 0; u0 < camera.width; u0 += kTile) {
        const int u1 = std::min(camera.width, u0 + kTile);
        for (int v = v0; v < v1; ++v) {
          cv::Vec3f* color = out.color.ptr<cv::Vec3f>(v);
          float* depth = out.depth.ptr<float>(v);
          float* sigma = out.sigma.ptr<float>(v);
          float* weight = out.weight.ptr<float>(v);
          for (int u = u0; u < u1; ++u) {
            Eigen::Vector3d cam_dir((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1);
            if (!exposure.empty())
              cam_dir = SO3::exp(rolling_shutter.omega_cam * exposure.at<float>(v, u)) * cam_dir;
            const RayOutput r = march_ray(makeRay(T_world_cam, cam_dir), u, v);
            color[u] = cv::Vec3f(r.color[0], r.color[1], r.color[2]);
            depth[u] = r.depth;
            sigma[u] = std::sqrt(std::max(0.f, r.var));
            weight[u] = r.weight;
          }
        }
      }
    }
  };
  threads = std::clamp(threads, 1, bands);
  runOnThreads(threads, [&](int k) { work(k, threads); });
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
