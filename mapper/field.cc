#include "mapper/field.h"

#include <algorithm>
#include <cstring>
#include <stdexcept>

namespace radslam {

namespace {
// Above this many cells (4 bytes each, per level) the dense block index gives way to the hash
// map: lookups get slower but memory stays bounded for very long trajectories.
constexpr size_t kMaxDenseCells = size_t{1} << 24;
// Blocks of margin added around the dense box when it grows, so that it rarely regrows.
constexpr int kDenseMargin = 4;
}  // namespace

FieldGeometry FieldGeometry::make(double fine_voxel_size, int levels, int level_ratio,
                                  int sh_degree, float density_bias) {
  FieldGeometry g;
  g.sh_degree = sh_degree;
  g.density_bias = density_bias;
  for (int l = 0; l < levels; ++l)
    g.voxel_size.push_back(fine_voxel_size * std::pow(double(level_ratio), levels - 1 - l));
  g.validate();
  return g;
}

void FieldGeometry::validate() const {
  if (voxel_size.empty() || numLevels() > Field::kMaxLevels)
    throw std::invalid_argument("field geometry: need 1 to " + std::to_string(Field::kMaxLevels) +
                                " levels, got " + std::to_string(numLevels()));
  for (int l = 0; l < numLevels(); ++l) {
    if (!(voxel_size[l] > 0) || !std::isfinite(voxel_size[l]))
      throw std::invalid_argument("field geometry: voxel size of level " + std::to_string(l) +
                                  " is not a positive number");
    if (l > 0) {
      const double ratio = voxel_size[l - 1] / voxel_size[l];
      if (ratio < 1 || std::abs(ratio - std::round(ratio)) > 1e-9 * ratio)
        throw std::invalid_argument(
            "field geometry: voxel sizes must go coarse to fine by integer ratios (level " +
            std::to_string(l - 1) + " / level " + std::to_string(l) + " = " +
            std::to_string(ratio) + ")");
    }
  }
  if (sh_degree != 0 && sh_degree != 1)
    throw std::invalid_argument("field geometry: sh_degree must be 0 or 1, got " +
                                std::to_string(sh_degree));
  if (!std::isfinite(density_bias))
    throw std::invalid_argument("field geometry: density_bias is not finite");
}

bool FieldGeometry::operator==(const FieldGeometry& o) const {
  return voxel_size == o.voxel_size && sh_degree == o.sh_degree &&
         std::memcmp(&density_bias, &o.density_bias, sizeof(float)) == 0;
}

Field::Field(const FieldGeometry& geometry) : geometry_(geometry) {
  geometry_.validate();
  color_basis_ = geometry_.colorBasis();
  channels_ = geometry_.channels();
  density_scale_ = static_cast<float>(1.0 / geometry_.fineVoxelSize());
  levels_.resize(geometry_.numLevels());
  for (int l = 0; l < numLevels(); ++l) {
    levels_[l].voxel_size = geometry_.voxel_size[l];
    levels_[l].inv_voxel_size = static_cast<float>(1.0 / geometry_.voxel_size[l]);
  }
}

void Field::reserveBlocks(int blocks_per_level) {
  for (Level& lv : levels_) {
    lv.blocks.reserve(blocks_per_level);
    lv.data.reserve(size_t(blocks_per_level) * kBlockVoxels * channels_);
  }
}

size_t Field::totalBlocks() const {
  size_t n = 0;
  for (const Level& level : levels_) n += level.blocks.size();
  return n;
}

void Field::Level::growDense(const Eigen::Vector3i& index) {
  if (!use_dense) return;
  Eigen::Vector3i lo = index, hi = index;
  if (dense_dim.minCoeff() > 0) {
    lo = lo.cwiseMin(dense_min);
    hi = hi.cwiseMax(dense_min + dense_dim - Eigen::Vector3i::Ones());
  }
  // Grow by a margin proportional to the size so that a steadily growing map regrows
  // O(log n) times.
  const Eigen::Vector3i size = hi - lo + Eigen::Vector3i::Ones();
  const Eigen::Vector3i margin = (size / 4).cwiseMax(Eigen::Vector3i::Constant(kDenseMargin));
  lo -= margin;
  hi += margin;
  const Eigen::Vector3i dim = hi - lo + Eigen::Vector3i::Ones();
  const size_t cells = size_t(dim.x()) * size_t(dim.y()) * size_t(dim.z());
  if (cells > kMaxDenseCells) {
    use_dense = false;
    std::vector<int>().swap(dense);
    return;
  }
  std::vector<int> grown(cells, -1);
  for (size_t b = 0; b < blocks.size(); ++b) {
    const Eigen::Vector3i r = blocks[b].index - lo;
    grown[(size_t(r.z()) * dim.y() + r.y()) * dim.x() + r.x()] = static_cast<int>(b);
  }
  dense.swap(grown);
  dense_min = lo;
  dense_dim = dim;
}

int Field::allocateBlock(int level, const Eigen::Vector3i& index) {
  Level& lv = levels_[level];
  const int existing = lv.find(index.x(), index.y(), index.z());
  if (existing >= 0) return existing;
  if (!blockIndexInRange(index))
    throw std::out_of_range("field: block index out of range at level " + std::to_string(level) +
                            " (the map extends beyond 2^20 blocks from the origin)");
  const int id = static_cast<int>(lv.blocks.size());
  BlockInfo info;
  info.index = index;
  lv.blocks.push_back(info);
  lv.data.resize(lv.data.size() + size_t(kBlockVoxels) * channels_, 0.f);
  lv.map.emplace(key(index.x(), index.y(), index.z()), id);
  if (lv.use_dense) {
    const Eigen::Vector3i r = index - lv.dense_min;
    const bool inside = lv.dense_dim.minCoeff() > 0 && r.minCoeff() >= 0 &&
                        (r.array() < lv.dense_dim.array()).all();
    if (inside)
      lv.dense[(size_t(r.z()) * lv.dense_dim.y() + r.y()) * lv.dense_dim.x() + r.x()] = id;
    else
      lv.growDense(index);
  }
  markChanged(level, id);
  if (level == 0) {
    const float edge = static_cast<float>(lv.voxel_size * kBlockDim);
    const Eigen::Vector3f lo = index.cast<float>() * edge;
    bounds_min_ = bounds_min_.cwiseMin(lo);
    bounds_max_ = bounds_max_.cwiseMax(lo + Eigen::Vector3f::Constant(edge));
  }
  return id;
}

int Field::allocateAround(const Eigen::Vector3f& p) {
  int added = 0;
  for (int l = 0; l < numLevels(); ++l) {
    const Eigen::Vector3f q = p * levels_[l].inv_voxel_size;
    const int x0 = static_cast<int>(std::floor(q.x()));
    const int y0 = static_cast<int>(std::floor(q.y()));
    const int z0 = static_cast<int>(std::floor(q.z()));
    // The 8 lattice points span at most 2 blocks per axis.
    const int bx0 = blockOf(x0), bx1 = blockOf(x0 + 1);
    const int by0 = blockOf(y0), by1 = blockOf(y0 + 1);
    const int bz0 = blockOf(z0), bz1 = blockOf(z0 + 1);
    for (int bz = bz0; bz <= bz1; ++bz)
      for (int by = by0; by <= by1; ++by)
        for (int bx = bx0; bx <= bx1; ++bx) {
          if (levels_[l].find(bx, by, bz) >= 0) continue;
          allocateBlock(l, Eigen::Vector3i(bx, by, bz));
          ++added;
        }
  }
  return added;
}

Field::Value Field::query(const Eigen::Vector3f& p, const Eigen::Vector3f& dir) const {
  Value out;
  if (!initialized()) return out;
  float raw[1 + 3 * 4] = {};
  {
    // Empty unless the finest block holding p is allocated.
    const Level& fine = levels_.back();
    const Eigen::Vector3i i0 = (p * fine.inv_voxel_size).array().floor().cast<int>();
    if (fine.find(blockOf(i0.x()), blockOf(i0.y()), blockOf(i0.z())) < 0) return out;
    out.occupied = true;
  }
  for (int l = 0; l < numLevels(); ++l) {
    const Level& lv = levels_[l];
    const Eigen::Vector3f q = p * lv.inv_voxel_size;
    const Eigen::Vector3f f0 = q.array().floor();
    const Eigen::Vector3i i0 = f0.cast<int>();
    const Eigen::Vector3f f = q - f0;

    for (int c = 0; c < 8; ++c) {
      const int dx = c & 1, dy = (c >> 1) & 1, dz = c >> 2;
      const int x = i0.x() + dx, y = i0.y() + dy, z = i0.z() + dz;
      const int b = lv.find(blockOf(x), blockOf(y), blockOf(z));
      if (b < 0) continue;
      const float w =
          (dx ? f.x() : 1 - f.x()) * (dy ? f.y() : 1 - f.y()) * (dz ? f.z() : 1 - f.z());
      const float* v =
          lv.data.data() +
          (size_t(b) * kBlockVoxels + voxelInBlock(localOf(x), localOf(y), localOf(z))) * channels_;
      for (int ch = 0; ch < channels_; ++ch) raw[ch] += w * v[ch];
    }
  }
  out.raw_density = geometry_.density_bias + raw[0];
  out.density = softplus(out.raw_density) * density_scale_;
  const float basis[4] = {1.f, dir.x(), dir.y(), dir.z()};
  for (int k = 0; k < 3; ++k) {
    float r = 0;
    for (int j = 0; j < color_basis_; ++j) r += raw[1 + 3 * j + k] * basis[j];
    out.color[k] = sigmoid(r);
  }
  return out;
}

void Field::markDensityChanged(int level, int block) {
  static std::atomic<uint64_t> last_stamp{0};
  Level& lv = levels_[level];
  lv.blocks[block].stamp = last_stamp.fetch_add(1, std::memory_order_relaxed) + 1;
  if (lv.bounds_stale_flag.size() < lv.blocks.size()) lv.bounds_stale_flag.resize(lv.blocks.size());
  uint8_t& flag = lv.bounds_stale_flag[block];
  if (!flag) {
    flag = 1;
    lv.bounds_stale.push_back(block);
  }
  bounds_sync_.stale.store(true, std::memory_order_release);
}

void Field::refreshBoundsIfStale() const {
  if (!bounds_sync_.stale.load(std::memory_order_acquire)) return;
  std::lock_guard<std::mutex> lock(bounds_sync_.mutex);
  if (!bounds_sync_.stale.load(std::memory_order_relaxed)) return;
  for (int l = 0; l < numLevels(); ++l) refreshBounds(l);
  bounds_sync_.stale.store(false, std::memory_order_release);
}

const float* Field::densityBounds(int level) const {
  refreshBoundsIfStale();
  return levels_[level].bounds.data();
}

const uint8_t* Field::zeroSubBlocks(int level) const {
  refreshBoundsIfStale();
  return levels_[level].zero_sub.data();
}

void Field::refreshBounds(int level) const {
  const Level& lv = levels_[level];
  lv.bounds.resize(lv.blocks.size() * kSubBlocks, 0.f);
  lv.zero_sub.resize(lv.blocks.size() * kSubBlocks, 1);
  lv.bounds_stale_flag.resize(lv.blocks.size(), 0);
  // A block's sub-blocks read the first lattice layer of its +x, +y, +z neighbours, so a
  // changed block changes its lower neighbours' bounds too.
  std::vector<int> todo = lv.bounds_stale;
  for (const int b : lv.bounds_stale) {
    const Eigen::Vector3i& i = lv.blocks[b].index;
    for (int c = 1; c < 8; ++c) {
      const int n = lv.find(i.x() - (c & 1), i.y() - ((c >> 1) & 1), i.z() - (c >> 2));
      if (n >= 0 && !lv.bounds_stale_flag[n]) {
        lv.bounds_stale_flag[n] = 1;
        todo.push_back(n);
      }
    }
  }
  constexpr int kGrid = kBlockDim + 1;     // lattice points per axis read by a block's cells
  float grid[kGrid * kGrid * kGrid];       // raw density
  uint8_t nonzero[kGrid * kGrid * kGrid];  // some channel != 0
  for (const int b : todo) {
    const Eigen::Vector3i& i = lv.blocks[b].index;
    int neighbour[8];  // the block and its +x, +y, +z neighbours, indexed like cell corners
    for (int c = 0; c < 8; ++c)
      neighbour[c] =
          c == 0 ? b : lv.find(i.x() + (c & 1), i.y() + ((c >> 1) & 1), i.z() + (c >> 2));
    for (int z = 0; z < kGrid; ++z)
      for (int y = 0; y < kGrid; ++y)
        for (int x = 0; x < kGrid; ++x) {
          const int n =
              neighbour[(x >> kBlockShift) | ((y >> kBlockShift) << 1) | ((z >> kBlockShift) << 2)];
          const int g = (z * kGrid + y) * kGrid + x;
          grid[g] = 0.f;
          nonzero[g] = 0;
          if (n < 0) continue;
          const float* v = lv.data.data() + (size_t(n) * kBlockVoxels +
                                             voxelInBlock(localOf(x), localOf(y), localOf(z))) *
                                                channels_;
          grid[g] = v[0];
          for (int ch = 0; ch < channels_; ++ch) nonzero[g] |= v[ch] != 0.f;
        }
    for (int sub = 0; sub < kSubBlocks; ++sub) {
      const int ox = kSubDim * (sub & 1), oy = kSubDim * ((sub >> 1) & 1),
                oz = kSubDim * (sub >> 2);
      float m = -INFINITY;
      uint8_t any = 0;
      for (int z = oz; z <= oz + kSubDim; ++z)
        for (int y = oy; y <= oy + kSubDim; ++y)
          for (int x = ox; x <= ox + kSubDim; ++x) {
            m = std::max(m, grid[(z * kGrid + y) * kGrid + x]);
            any |= nonzero[(z * kGrid + y) * kGrid + x];
          }
      lv.bounds[size_t(b) * kSubBlocks + sub] = m;
      lv.zero_sub[size_t(b) * kSubBlocks + sub] = !any;
    }
    lv.bounds_stale_flag[b] = 0;
  }
  lv.bounds_stale.clear();
}

void Field::markChanged(int level, int block) {
  markDensityChanged(level, block);
  BlockInfo& info = levels_[level].blocks[block];
  if (info.changed) return;
  info.changed = true;
  info.changed_since = commit_counter_;
}

int Field::commit(int max_blocks) {
  std::vector<std::pair<int, int>> changed;  // (level, block)
  for (int l = 0; l < numLevels(); ++l)
    for (int b = 0; b < numBlocks(l); ++b)
      if (levels_[l].blocks[b].changed) changed.emplace_back(l, b);
  ++commit_counter_;
  if (changed.empty()) return 0;
  if (max_blocks > 0 && static_cast<int>(changed.size()) > max_blocks) {
    std::stable_sort(changed.begin(), changed.end(), [&](const auto& a, const auto& b) {
      return levels_[a.first].blocks[a.second].changed_since <
             levels_[b.first].blocks[b.second].changed_since;
    });
    changed.resize(max_blocks);
  }
  ++version_;
  for (const auto& [l, b] : changed) {
    BlockInfo& info = levels_[l].blocks[b];
    info.changed = false;
    info.version = version_;
  }
  return static_cast<int>(changed.size());
}

void Field::setVersion(int64_t version) {
  version_ = version;
  for (Level& lv : levels_)
    for (BlockInfo& info : lv.blocks) {
      info.changed = false;
      info.version = version;
    }
}

int Field::pendingBlocks() const {
  int n = 0;
  for (const Level& lv : levels_)
    for (const BlockInfo& info : lv.blocks) n += info.changed ? 1 : 0;
  return n;
}

bool Field::sameContent(const Field& other) const {
  if (geometry_ != other.geometry_ || numLevels() != other.numLevels()) return false;
  const size_t block_floats = size_t(kBlockVoxels) * channels_;
  for (int l = 0; l < numLevels(); ++l) {
    const Level& a = levels_[l];
    const Level& b = other.levels_[l];
    if (a.blocks.size() != b.blocks.size()) return false;
    // By block index: a replica may hold the same blocks under other ids.
    for (size_t i = 0; i < a.blocks.size(); ++i) {
      const Eigen::Vector3i& index = a.blocks[i].index;
      const int j = b.find(index.x(), index.y(), index.z());
      if (j < 0 ||
          std::memcmp(a.data.data() + i * block_floats, b.data.data() + size_t(j) * block_floats,
                      block_floats * sizeof(float)) != 0)
        return false;
    }
  }
  return true;
}

}  // namespace radslam
