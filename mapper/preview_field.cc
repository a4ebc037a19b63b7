#include "mapper/preview_field.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "mapper/ray_kernels.h"

namespace radslam {

namespace {

using namespace ray_kernels;

constexpr int kP = PreviewField::kSubPoints;
static_assert(Field::kSubDim == 4, "2^3-cell groups: 2 per sub-block axis");
constexpr int kMaxChannels = 1 + 3 * 4;
// Offsets (in points) of a cell's 8 corners within a sub-block's points; corner c has
// dx = c & 1, dy = (c >> 1) & 1, dz = c >> 2 (as kCornerOffset).
constexpr int kCorner[8] = {0, 1, kP, kP + 1, kP* kP, kP* kP + 1, kP* kP + kP, kP* kP + kP + 1};
constexpr float kZeros[kMaxChannels] = {};

// Round to nearest even (the field's values are finite).
uint16_t toBfloat16(float x) {
  uint32_t bits;
  std::memcpy(&bits, &x, sizeof(bits));
  bits += 0x7FFFu + ((bits >> 16) & 1u);
  return static_cast<uint16_t>(bits >> 16);
}
[[gnu::always_inline]] inline float fromBfloat16(uint16_t h) {
  const uint32_t bits = uint32_t{h} << 16;
  float x;
  std::memcpy(&x, &bits, sizeof(x));
  return x;
}

int64_t floorDiv(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
int64_t ceilDiv(int64_t a, int64_t b) { return -floorDiv(-a, b); }

// A level's voxel size over the fine one's (an integer: FieldGeometry::validate).
int fineRatio(const Field& field, int level) {
  return static_cast<int>(
      std::lround(field.voxelSize(level) / field.voxelSize(field.numLevels() - 1)));
}

// The 8 corners of a level's lattice cell (channel pointers, zeros where unallocated), kept
// while consecutive points stay in the cell.
struct CellCorners {
  int64_t cell[3] = {INT64_MIN, 0, 0};
  const float* corner[8];

  void moveTo(const Field& field, int level, const int64_t* c) {
    if (c[0] == cell[0] && c[1] == cell[1] && c[2] == cell[2]) return;
    std::copy(c, c + 3, cell);
    const int channels = field.channels();
    for (int k = 0; k < 8; ++k) {
      const int x = static_cast<int>(c[0] + (k & 1)), y = static_cast<int>(c[1] + ((k >> 1) & 1)),
                z = static_cast<int>(c[2] + (k >> 2));
      const int b = field.findBlock(level, blockOf(x), blockOf(y), blockOf(z));
      corner[k] = b < 0 ? kZeros
                        : field.levelData(level) +
                              (static_cast<size_t>(b) * Field::kBlockVoxels +
                               Field::voxelInBlock(localOf(x), localOf(y), localOf(z))) *
                                  channels;
    }
  }
};

// The block holding a lattice point, remembered for the next point.
struct LastBlock {
  int key[3] = {INT32_MIN, 0, 0};
  int block = -1;

  int find(const Field& field, int level, const int64_t* g) {
    const int bx = blockOf(static_cast<int>(g[0])), by = blockOf(static_cast<int>(g[1])),
              bz = blockOf(static_cast<int>(g[2]));
    if (bx != key[0] || by != key[1] || bz != key[2]) {
      key[0] = bx;
      key[1] = by;
      key[2] = bz;
      block = field.findBlock(level, bx, by, bz);
    }
    return block;
  }
};

}  // namespace

PreviewField::PreviewField(float skip_thickness)
    : skip_thickness_(std::max(0.f, skip_thickness)),
      skip_raw_(skip_thickness_ > 0 ? std::log(std::expm1(skip_thickness_)) : -INFINITY) {}

void PreviewField::reset(const FieldGeometry& geometry) {
  geometry_ = geometry;
  have_geometry_ = true;
  channels_ = geometry.channels();
  blocks_.clear();
  seen_.assign(geometry.numLevels(), {});
  values_.clear();
  free_slots_.clear();
  dirty_.clear();
  dirty_flag_.clear();
  grid_.clear();
  grid_size_.setZero();
  grid_stale_ = true;
}

void PreviewField::markDirty(int fine_block) {
  if (dirty_flag_[fine_block]) return;
  dirty_flag_[fine_block] = 1;
  // Blocks never baked go first: a growing map shows its new parts at once.
  if (blocks_[fine_block].baked)
    dirty_.push_back(fine_block);
  else
    dirty_.push_front(fine_block);
}

void PreviewField::markDependents(const Field& field, int level, int block) {
  const int fine = field.numLevels() - 1;
  const Eigen::Vector3i& index = field.blockIndex(level, block);
  int64_t lo[3], hi[3];
  for (int k = 0; k < 3; ++k) {
    if (level == fine) {
      // A fine block's points are also the halo of the blocks before it on each axis.
      lo[k] = index[k] - 1;
      hi[k] = index[k];
    } else {
      // The block's points i = 8 B .. 8 B + 7 (level units) enter the interpolation over
      // [(8 B - 1) R, (8 B + 8) R] in fine lattice units; fine block F holds 8 F .. 8 F + 8.
      const int64_t R = fineRatio(field, level), B = index[k];
      lo[k] = ceilDiv((8 * B - 1) * R - Field::kBlockDim, Field::kBlockDim);
      hi[k] = floorDiv((8 * B + 8) * R, Field::kBlockDim);
    }
  }
  for (int64_t z = lo[2]; z <= hi[2]; ++z)
    for (int64_t y = lo[1]; y <= hi[1]; ++y)
      for (int64_t x = lo[0]; x <= hi[0]; ++x) {
        const int id = field.findBlock(fine, Eigen::Vector3i(x, y, z).cast<int>());
        if (id >= 0 && id < static_cast<int>(blocks_.size())) markDirty(id);
      }
}

int PreviewField::refresh(const Field& field, double budget_s) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  if (!field.initialized()) {
    have_geometry_ = false;
    blocks_.clear();
    dirty_.clear();
    grid_.clear();
    grid_size_.setZero();
    return 0;
  }
  const int fine = field.numLevels() - 1;
  if (!have_geometry_ || geometry_ != field.geometry() ||
      field.numBlocks(fine) < static_cast<int>(blocks_.size()))
    reset(field.geometry());
  FineBlock empty;
  std::fill(empty.slot, empty.slot + Field::kSubBlocks, -1);
  std::fill(empty.sigma_bound, empty.sigma_bound + Field::kSubBlocks, 0.f);
  std::fill(empty.empty_cells, empty.empty_cells + Field::kSubBlocks, 0xFF);
  empty.stored = 0;
  empty.baked = false;
  empty.index = Eigen::Vector3i::Zero();
  blocks_.resize(field.numBlocks(fine), empty);
  dirty_flag_.resize(blocks_.size(), 0);
  for (int l = 0; l < field.numLevels(); ++l) {
    std::vector<uint64_t>& seen = seen_[l];
    seen.resize(field.numBlocks(l), 0);
    for (int b = 0; b < field.numBlocks(l); ++b) {
      const uint64_t stamp = field.changeStamp(l, b);
      if (stamp == seen[b]) continue;
      seen[b] = stamp;
      if (l == fine && blocks_[b].baked && blocks_[b].index != field.blockIndex(fine, b)) {
        // The id now names another block (a snapshot replaced the field): empty until baked,
        // not the old block's values in the new place.
        FineBlock& entry = blocks_[b];
        for (int32_t& slot : entry.slot) {
          if (slot >= 0) free_slots_.push_back(slot);
          slot = -1;
        }
        grid_stale_ |= entry.stored != 0;
        entry.stored = 0;
        entry.baked = false;
      }
      markDependents(field, l, b);
    }
  }
  const auto deadline =
      start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(budget_s));
  // Room for every stale sub-block at once (address space only until written): growing one
  // slot at a time would copy the whole copy over and over.
  const size_t stride = size_t(kPointsPerSub) * channels_;
  values_.reserve(
      std::max(values_.capacity(), values_.size() + dirty_.size() * Field::kSubBlocks * stride));
  for (int baked = 0; !dirty_.empty(); ++baked) {
    // At least a batch per call, so that any budget makes progress.
    if (budget_s > 0 && baked > 0 && baked % 8 == 0 && Clock::now() >= deadline) break;
    const int b = dirty_.front();
    dirty_.pop_front();
    dirty_flag_[b] = 0;
    bakeBlock(field, b);
  }
  if (grid_stale_) buildGrid();
  return staleBlocks();
}

void PreviewField::buildGrid() {
  grid_stale_ = false;
  Eigen::Vector3i lo = Eigen::Vector3i::Constant(INT_MAX), hi = Eigen::Vector3i::Constant(INT_MIN);
  for (const FineBlock& entry : blocks_) {
    if (!entry.stored) continue;
    lo = lo.cwiseMin(entry.index);
    hi = hi.cwiseMax(entry.index);
  }
  grid_.clear();
  grid_size_.setZero();
  if (lo.x() > hi.x()) return;
  grid_min_ = lo;
  grid_size_ = hi - lo + Eigen::Vector3i::Ones();
  const int sx = grid_size_.x(), sy = grid_size_.y(), sz = grid_size_.z();
  grid_.assign(size_t(sx) * sy * sz, -kMaxSkip);
  for (int id = 0; id < static_cast<int>(blocks_.size()); ++id) {
    if (!blocks_[id].stored) continue;
    const Eigen::Vector3i c = blocks_[id].index - lo;
    grid_[(size_t(c.z()) * sy + c.y()) * sx + c.x()] = id;
  }
  // Chessboard distance by two raster passes over the 13 neighbours before (then after) a
  // cell: exact for unit steps to all 26 neighbours.
  auto pass = [&](int sign) {
    const int z0 = sign > 0 ? 0 : sz - 1, y0 = sign > 0 ? 0 : sy - 1, x0 = sign > 0 ? 0 : sx - 1;
    for (int z = z0; z >= 0 && z < sz; z += sign)
      for (int y = y0; y >= 0 && y < sy; y += sign)
        for (int x = x0; x >= 0 && x < sx; x += sign) {
          int32_t& cell = grid_[(size_t(z) * sy + y) * sx + x];
          if (cell >= 0) continue;
          int dist = -cell;
          for (int dz = -1; dz <= 0; ++dz)
            for (int dy = -1; dy <= 1; ++dy)
              for (int dx = -1; dx <= 1; ++dx) {
                if (dz == 0 && (dy > 0 || (dy == 0 && dx >= 0))) continue;  // not before
                const int nx = x + sign * dx, ny = y + sign * dy, nz = z + sign * dz;
                if (nx < 0 || ny < 0 || nz < 0 || nx >= sx || ny >= sy || nz >= sz) continue;
                const int32_t n = grid_[(size_t(nz) * sy + ny) * sx + nx];
                dist = std::min(dist, (n >= 0 ? 0 : -n) + 1);
              }
          cell = -dist;
        }
  };
  pass(1);
  pass(-1);
}

void PreviewField::bakeBlock(const Field& field, int fine_block) {
  const int levels = field.numLevels();
  const int fine = levels - 1;
  const int C = channels_;
  const Eigen::Vector3i& index = field.blockIndex(fine, fine_block);
  const float* bounds[Field::kMaxLevels];
  for (int l = 0; l < levels; ++l) bounds[l] = field.densityBounds(l);
  int ratio[Field::kMaxLevels];
  for (int l = 0; l < levels; ++l) ratio[l] = fineRatio(field, l);
  FineBlock& entry = blocks_[fine_block];
  const bool stored_before = entry.stored != 0;
  entry.baked = true;
  entry.index = index;
  uint16_t baked[kPointsPerSub * kMaxChannels];
  for (int s = 0; s < Field::kSubBlocks; ++s) {
    const int64_t g0[3] = {int64_t{index.x()} * Field::kBlockDim + Field::kSubDim * (s & 1),
                           int64_t{index.y()} * Field::kBlockDim + Field::kSubDim * ((s >> 1) & 1),
                           int64_t{index.z()} * Field::kBlockDim + Field::kSubDim * (s >> 2)};
    // The field's own density bounds (a sum of per-level bounds over the sub-block) settle most
    // empty sub-blocks without evaluating them.
    float upper = field.densityBias() + bounds[fine][size_t(fine_block) * Field::kSubBlocks + s];
    for (int l = 0; l < fine && upper < skip_raw_; ++l) {
      int64_t sub[3];
      for (int k = 0; k < 3; ++k) sub[k] = floorDiv(g0[k], ratio[l]) >> Field::kSubShift;
      const int b = field.findBlock(l, static_cast<int>(sub[0] >> 1), static_cast<int>(sub[1] >> 1),
                                    static_cast<int>(sub[2] >> 1));
      upper = b < 0 ? INFINITY
                    : upper + bounds[l][size_t(b) * Field::kSubBlocks + (sub[0] & 1) +
                                        ((sub[1] & 1) << 1) + ((sub[2] & 1) << 2)];
    }
    float bound = upper;
    if (upper >= skip_raw_) {
      bound = -INFINITY;
      float sum[kPointsPerSub * kMaxChannels];
      for (int p = 0; p < kPointsPerSub; ++p) {
        sum[p * C] = field.densityBias();
        for (int ch = 1; ch < C; ++ch) sum[p * C + ch] = 0;
      }
      // The fine level's own values.
      LastBlock fine_blocks;
      for (int z = 0, p = 0; z < kP; ++z)
        for (int y = 0; y < kP; ++y)
          for (int x = 0; x < kP; ++x, ++p) {
            const int64_t g[3] = {g0[0] + x, g0[1] + y, g0[2] + z};
            const int b = fine_blocks.find(field, fine, g);
            if (b < 0) continue;
            const float* value =
                field.levelData(fine) + (static_cast<size_t>(b) * Field::kBlockVoxels +
                                         Field::voxelInBlock(localOf(static_cast<int>(g[0])),
                                                             localOf(static_cast<int>(g[1])),
                                                             localOf(static_cast<int>(g[2])))) *
                                            C;
            for (int ch = 0; ch < C; ++ch) sum[p * C + ch] += value[ch];
          }
      // Each coarser level's trilinear interpolation at the points, with exact fractions.
      for (int l = 0; l < fine; ++l) {
        int64_t cell[3][kP];
        float frac[3][kP];
        for (int k = 0; k < 3; ++k)
          for (int i = 0; i < kP; ++i) {
            cell[k][i] = floorDiv(g0[k] + i, ratio[l]);
            frac[k][i] = static_cast<float>(g0[k] + i - cell[k][i] * ratio[l]) / ratio[l];
          }
        CellCorners corners;
        for (int z = 0, p = 0; z < kP; ++z)
          for (int y = 0; y < kP; ++y)
            for (int x = 0; x < kP; ++x, ++p) {
              const int64_t c[3] = {cell[0][x], cell[1][y], cell[2][z]};
              corners.moveTo(field, l, c);
              const float wx[2] = {1 - frac[0][x], frac[0][x]};
              const float wy[2] = {1 - frac[1][y], frac[1][y]};
              const float wz[2] = {1 - frac[2][z], frac[2][z]};
              for (int k = 0; k < 8; ++k) {
                const float w = wx[k & 1] * wy[(k >> 1) & 1] * wz[k >> 2];
                const float* corner = corners.corner[k];
                for (int ch = 0; ch < C; ++ch) sum[p * C + ch] += w * corner[ch];
              }
            }
      }
      for (int p = 0; p < kPointsPerSub; ++p)
        for (int ch = 0; ch < C; ++ch) baked[p * C + ch] = toBfloat16(sum[p * C + ch]);
      // Bounds of the 2^3-cell groups (their 3^3 points) and of the sub-block.
      uint8_t empty_cells = 0;
      for (int m = 0; m < 8; ++m) {
        float group = -INFINITY;
        for (int z = 2 * (m >> 2); z <= 2 * (m >> 2) + 2; ++z)
          for (int y = 2 * ((m >> 1) & 1); y <= 2 * ((m >> 1) & 1) + 2; ++y)
            for (int x = 2 * (m & 1); x <= 2 * (m & 1) + 2; ++x)
              group = std::max(group, fromBfloat16(baked[((z * kP + y) * kP + x) * C]));
        if (group < skip_raw_) empty_cells |= static_cast<uint8_t>(1u << m);
        bound = std::max(bound, group);
      }
      entry.empty_cells[s] = empty_cells;
    }
    entry.sigma_bound[s] = bound < skip_raw_ ? 0.f : softplus(bound) * field.densityScale();
    int32_t& slot = entry.slot[s];
    if (bound < skip_raw_) {
      if (slot >= 0) free_slots_.push_back(slot);
      slot = -1;
      entry.stored &= static_cast<uint8_t>(~(1u << s));
      continue;
    }
    entry.stored |= static_cast<uint8_t>(1u << s);
    if (slot < 0) {
      if (!free_slots_.empty()) {
        slot = free_slots_.back();
        free_slots_.pop_back();
      } else {
        slot = static_cast<int32_t>(values_.size() / (size_t(kPointsPerSub) * C));
        values_.resize(values_.size() + size_t(kPointsPerSub) * C);
      }
    }
    std::copy(baked, baked + kPointsPerSub * C, values_.data() + size_t(slot) * kPointsPerSub * C);
  }
  grid_stale_ |= (entry.stored != 0) != stored_before;
}

namespace {

// Where a ray leaves boxes of lattice cubes, in the fine lattice's units (p / voxel size): per
// axis the face ahead, with the division done once per ray. Axes the ray does not move along
// are never left.
struct LatticeExits {
  float origin[3], inv_dir[3];
  bool positive[3];

  LatticeExits(const Lanes& o, const Lanes& d) {
    for (int k = 0; k < 3; ++k) {
      origin[k] = o[k];
      positive[k] = d[k] > 0;
      inv_dir[k] = std::abs(d[k]) < 1e-12f ? 0.f : 1.f / d[k];
    }
  }
  // The box of cubes lo .. hi of `edge` lattice units each.
  float operator()(const int* lo, const int* hi, int edge) const {
    float t = INFINITY;
    for (int k = 0; k < 3; ++k) {
      if (inv_dir[k] == 0) continue;
      const float face = static_cast<float>((positive[k] ? hi[k] + 1 : lo[k]) * edge);
      t = std::min(t, (face - origin[k]) * inv_dir[k]);
    }
    return t;
  }
  float operator()(const int* cube, int edge) const { return (*this)(cube, cube, edge); }
};

}  // namespace

// The 4 channels of RGB fields: r += sum_k w[k] * corner k, on SSE2 lanes when there (the
// same products and sums in the same order as the scalar loop).
[[gnu::always_inline]] inline void gather4(const uint16_t* base, const float* w, float* r) {
#if defined(__SSE2__)
  const __m128i zero = _mm_setzero_si128();
  __m128 acc = _mm_setzero_ps();
  for (int k = 0; k < 8; ++k) {
    // bfloat16 -> float: the 16 bits become the upper half of each 32-bit lane.
    const __m128i h = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(base + kCorner[k] * 4));
    const __m128 v = _mm_castsi128_ps(_mm_unpacklo_epi16(zero, h));
    acc = _mm_add_ps(acc, _mm_mul_ps(_mm_set1_ps(w[k]), v));
  }
  _mm_storeu_ps(r, acc);
#else
  for (int ch = 0; ch < 4; ++ch) r[ch] = 0;
  for (int k = 0; k < 8; ++k)
    for (int ch = 0; ch < 4; ++ch) r[ch] += w[k] * fromBfloat16(base[kCorner[k] * 4 + ch]);
#endif
}

// The march of VolumeRenderer::march (volume_march.cc) on the baked sub-blocks: jumps over
// unallocated blocks and empty sub-blocks, and samples a stored sub-block with its own step
// (adaptive: from its density bound) from its points alone, past its empty 2^3-cell groups.
template <int NB>
RayOutput PreviewField::marchImpl(const Field& field, const Ray& ray, const MarchParams& params,
                                  const Eigen::Vector3f& bg, float t_start,
                                  float* first_sample_t) const {
  constexpr int C = 1 + 3 * NB;
  MarchAccumulator acc;
  if (first_sample_t) *first_sample_t = INFINITY;
  if (field.empty() || grid_.empty() || channels_ != C) return acc.finish(bg, params);
  const int fine = field.numLevels() - 1;
  const float voxel = static_cast<float>(field.voxelSize(fine));
  const float fine_edge = voxel * Field::kBlockDim;
  float t0, t1;
  if (!intersectBox(ray, grid_min_.cast<float>() * fine_edge,
                    (grid_min_ + grid_size_).cast<float>() * fine_edge, &t0, &t1))
    t1 = -1;
  t0 = std::max({t0, params.near, t_start});
  t1 = std::min(t1, params.far);
  const float inv = field.invVoxelSize(fine);
  const float scale = field.densityScale();
  const float fine_step = params.step_fine * voxel;
  const float max_step =
      std::max(fine_step, voxel * std::max(params.step_fine, params.max_step_fine));
  const bool adaptive = params.max_sample_thickness > 0;
  const float nudge = 1e-3f * fine_step;  // past a face (m: t is the ray's parameter)
  const float basis[4] = {1.f, ray.view_dir.x(), ray.view_dir.y(), ray.view_dir.z()};
  const float o[3] = {ray.origin.x(), ray.origin.y(), ray.origin.z()};
  const float d[3] = {ray.dir.x(), ray.dir.y(), ray.dir.z()};
  // Samples are gathered in batches of 4 (across sub-blocks), shaded on lanes and composited
  // in ray order, which stops where the transmittance does (a batch may overshoot by 3).
  float tb[4] = {}, db[4] = {};
  float raw[C][4] = {};
  int n = 0;
  bool opaque = false;
  auto flush = [&]() {
    const Lanes sigma = softplus4(Lanes(raw[0])) * scale;  // the bias is baked in
    const Lanes decay = fastExp4(-sigma * Lanes(db));
    opaque = !acc.addBatch<NB>(raw, decay, tb, n, basis, params.min_transmittance);
    n = 0;
  };
  // Positions in fine lattice units: o_lattice + t * d_lattice.
  const Lanes o_lattice = Lanes(o[0], o[1], o[2], 0) * inv;
  const Lanes d_lattice = Lanes(d[0], d[1], d[2], 0) * inv;
  const LatticeExits exits(o_lattice, d_lattice);
  constexpr float kBelowSub = Field::kSubDim * (1 - 1e-6f);  // in a sub-block's last cell
  float t = t0;
  while (!opaque && t < t1) {
    const Lanes q = o_lattice + t * d_lattice;
    int g[3], fb[3];
    bool inside = true;
    for (int k = 0; k < 3; ++k) {
      g[k] = floorToInt(q[k]);
      fb[k] = blockOf(g[k]);
      inside &= static_cast<unsigned>(fb[k] - grid_min_[k]) < static_cast<unsigned>(grid_size_[k]);
    }
    const int32_t cell =
        inside ? grid_[(size_t(fb[2] - grid_min_.z()) * grid_size_.y() + (fb[1] - grid_min_.y())) *
                           grid_size_.x() +
                       (fb[0] - grid_min_.x())]
               : -1;
    if (cell < 0) {
      // Nothing stored within -cell - 1 blocks: past that box of blocks.
      const int r = -cell - 1;
      const int lo[3] = {fb[0] - r, fb[1] - r, fb[2] - r},
                hi[3] = {fb[0] + r, fb[1] + r, fb[2] + r};
      t = std::max(t + nudge, exits(lo, hi, Field::kBlockDim) + nudge);
      continue;
    }
    const int id = cell;
    int sub[3];
    for (int k = 0; k < 3; ++k) sub[k] = g[k] >> Field::kSubShift;
    const float exit = std::min(t1, exits(sub, Field::kSubDim));
    const int s = (sub[0] & 1) | ((sub[1] & 1) << 1) | ((sub[2] & 1) << 2);
    const FineBlock& entry = blocks_[id];
    if (entry.slot[s] < 0 || !(t < exit)) {
      t = std::max(t + nudge, exit + nudge);
      continue;
    }
    const float step = adaptive ? std::clamp(params.max_sample_thickness / entry.sigma_bound[s],
                                             fine_step, max_step)
                                : fine_step;
    const uint16_t* values = values_.data() + size_t(entry.slot[s]) * kPointsPerSub * C;
    const uint8_t empty_cells = entry.empty_cells[s];
    const Lanes q0 = o_lattice - Lanes(static_cast<float>(sub[0] * Field::kSubDim),
                                       static_cast<float>(sub[1] * Field::kSubDim),
                                       static_cast<float>(sub[2] * Field::kSubDim), 0);
    while (t < exit) {
      // The cell within the sub-block (clamped to it: t may round past a face) and the
      // position in it.
      const Lanes qs = (q0 + t * d_lattice).max(0.f).min(kBelowSub);
      const Eigen::Array4i cell = qs.cast<int>();
      const Lanes f = qs - cell.cast<float>();
      const int group = (cell[0] >> 1) | ((cell[1] >> 1) << 1) | ((cell[2] >> 1) << 2);
      if (empty_cells >> group & 1) {
        const int cube[3] = {sub[0] * 2 + (cell[0] >> 1), sub[1] * 2 + (cell[1] >> 1),
                             sub[2] * 2 + (cell[2] >> 1)};
        t = std::max(t + nudge, exits(cube, 2) + nudge);
        continue;
      }
      const Lanes wxy =
          Lanes(1 - f[0], f[0], 1 - f[0], f[0]) * Lanes(1 - f[1], 1 - f[1], f[1], f[1]);
      alignas(16) float w[8];
      Eigen::Map<Lanes, Eigen::Aligned16>{w} = wxy * (1 - f[2]);
      Eigen::Map<Lanes, Eigen::Aligned16>{w + 4} = wxy * f[2];
      const uint16_t* base = values + ((cell[2] * kP + cell[1]) * kP + cell[0]) * C;
      float r[C];
      if constexpr (C == 4) {
        gather4(base, w, r);
      } else {
        for (int ch = 0; ch < C; ++ch) r[ch] = 0;
        for (int k = 0; k < 8; ++k)
          for (int ch = 0; ch < C; ++ch) r[ch] += w[k] * fromBfloat16(base[kCorner[k] * C + ch]);
      }
      for (int ch = 0; ch < C; ++ch) raw[ch][n] = r[ch];
      if (first_sample_t && *first_sample_t == INFINITY) *first_sample_t = t;
      tb[n] = t;
      db[n] = step;
      t += step;
      if (++n == 4) {
        flush();
        if (opaque) break;
      }
    }
  }
  if (n > 0) flush();
  return acc.finish(bg, params);
}

RayOutput PreviewField::march(const Field& field, const Ray& ray, const MarchParams& params,
                              const Eigen::Vector3f& background, float t_start,
                              float* first_sample_t) const {
  return field.colorBasis() == 4
             ? marchImpl<4>(field, ray, params, background, t_start, first_sample_t)
             : marchImpl<1>(field, ray, params, background, t_start, first_sample_t);
}

RenderImages PreviewField::render(const Field& field, const SE3& T_world_cam,
                                  const CameraModel& camera, const MarchParams& params,
                                  const Eigen::Vector3f& background, int threads) const {
  // Pass 1: pixel (i, j) of a camera of half the focal length looks along pixel (2i, 2j).
  CameraModel even = camera;
  even.width = (camera.width + 1) / 2;
  even.height = (camera.height + 1) / 2;
  even.fx /= 2;
  even.fy /= 2;
  even.cx /= 2;
  even.cy /= 2;
  std::vector<RayOutput> even_out(size_t(even.width) * even.height);
  std::vector<float> even_first(even_out.size());
  if (even.width > 0 && even.height > 0)
    renderPinhole(T_world_cam, even, threads, [&](const Ray& ray, int i, int j) {
      const size_t k = size_t(j) * even.width + i;
      even_out[k] = march(field, ray, params, background, -INFINITY, &even_first[k]);
      return even_out[k];
    });
  // Pass 2. t is the camera's z (rays are not normalised), so a margin of one block in t is at
  // least one block along the ray.
  const float margin =
      static_cast<float>(field.voxelSize(std::max(0, field.numLevels() - 1))) * Field::kBlockDim;
  return renderPinhole(T_world_cam, camera, threads, [&](const Ray& ray, int u, int v) {
    const int i0 = u / 2, j0 = v / 2;
    if (u % 2 == 0 && v % 2 == 0) return even_out[size_t(j0) * even.width + i0];
    const int i1 = std::min(even.width - 1, (u + 1) / 2),
              j1 = std::min(even.height - 1, (v + 1) / 2);
    const auto [nearest, farthest] = std::minmax(
        {even_first[size_t(j0) * even.width + i0], even_first[size_t(j0) * even.width + i1],
         even_first[size_t(j1) * even.width + i0], even_first[size_t(j1) * even.width + i1]});
    const float start = farthest < INFINITY ? nearest - margin : -INFINITY;
    return march(field, ray, params, background, start);
  });
}

}  // namespace radslam
