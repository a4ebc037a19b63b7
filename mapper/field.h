// The probabilistic volumetric radiance field of the mapper (DESIGN section 4): hierarchical,
// block-sparse, explicit voxel grids.
//
/// Conventions:
///  - Level 0 is the coarsest; each level's voxel size is the next finer one's times an integer
///    ratio. Voxel values live on lattice points x = i * voxel_size (world frame, metres), and
///    block b holds the points i = b * kBlockDim + (0..kBlockDim-1) per axis.
///  - Per voxel, channels() float32 values: [0] raw density, then colour coefficients
///    coefficient-major: [1 + 3 j + k] = coefficient j of colour k (k = R, G, B). j = 0 is the
///    view-independent term; with sh_degree 1, j = 1..3 multiply the x, y, z components of the
///    unit viewing direction (world frame).
///  - The field at a point sums every level's trilinear interpolation (coarse + fine residuals):
///      density sigma = softplus(density_bias + sum_l a_l(x)) / fine_voxel_size   (1/m)
///      colour c_k    = sigmoid(sum_l sum_j coef_jk(x) Y_j(dir))                   (RGB, [0, 1])
///    so one fine voxel of raw value a has optical thickness softplus(bias + a): the parameters
///    are scale-free, which matters in monocular mode where the map scale is arbitrary.
///  - Space whose finest-level block is unallocated is empty (density 0): empty-space skipping.
///    Allocation follows the keyframe depths, so this is a shell around the surfaces; coarser
///    levels add low-frequency terms inside it. Lattice points of unallocated blocks read 0.
#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "mapper/large_vector.h"

namespace radslam {

/// What fixes the layout and meaning of a field's parameters. Two fields with equal geometry
/// exchange blocks (FieldUpdate) and checkpoints.
struct FieldGeometry {
  std::vector<double> voxel_size;  // m, per level, coarse to fine
  int sh_degree = 0;               // 0 (RGB) or 1 (degree-1 spherical harmonics)
  float density_bias = -4.6f;      // raw density offset: softplus(-4.6) = 0.01 per fine voxel

  int numLevels() const { return static_cast<int>(voxel_size.size()); }
  int colorBasis() const { return sh_degree == 1 ? 4 : 1; }
  int channels() const { return 1 + 3 * colorBasis(); }
  double fineVoxelSize() const { return voxel_size.back(); }
  /// Levels coarse to fine: fine_voxel_size * ratio^(levels-1-l).
  static FieldGeometry make(double fine_voxel_size, int levels, int level_ratio, int sh_degree,
                            float density_bias);
  /// Throws std::invalid_argument saying what is wrong (no levels, sizes not positive or not
  /// coarse-to-fine integer multiples, sh_degree not 0/1, bias not finite).
  void validate() const;
  bool operator==(const FieldGeometry& o) const;
  bool operator!=(const FieldGeometry& o) const { return !(*this == o); }
};

class Field {
 public:
  static constexpr int kBlockDim = 8;
  static constexpr int kBlockShift = 3;  // log2(kBlockDim)
  static constexpr int kBlockVoxels = kBlockDim * kBlockDim * kBlockDim;
  /// Keys pack each block coordinate in 21 bits: |index| < 2^20 blocks per axis.
  static constexpr int kMaxBlockIndex = (1 << 20) - 1;
  /// Every coordinate within +-kMaxBlockIndex (compared as they are: |INT_MIN| overflows).
  static bool blockIndexInRange(const Eigen::Vector3i& index) {
    return (index.array() >= -kMaxBlockIndex).all() && (index.array() <= kMaxBlockIndex).all();
  }
  static constexpr int kMaxLevels = 4;

  Field() = default;
  /// Throws std::invalid_argument when the geometry is invalid (FieldGeometry::validate).
  explicit Field(const FieldGeometry& geometry);

  bool initialized() const { return !levels_.empty(); }
  const FieldGeometry& geometry() const { return geometry_; }
  int numLevels() const { return static_cast<int>(levels_.size()); }
  int channels() const { return channels_; }
  int colorBasis() const { return color_basis_; }
  double voxelSize(int level) const { return levels_[level].voxel_size; }
  float invVoxelSize(int level) const { return levels_[level].inv_voxel_size; }
  float densityBias() const { return geometry_.density_bias; }
  /// 1 / fine voxel size: converts softplus(raw) to a density in 1/m.
  float densityScale() const { return density_scale_; }

  // ---- Blocks ----
  int numBlocks(int level) const { return static_cast<int>(levels_[level].blocks.size()); }
  size_t totalBlocks() const;
  const Eigen::Vector3i& blockIndex(int level, int block) const {
    return levels_[level].blocks[block].index;
  }
  /// Block id, or -1 when the block is not allocated.
  int findBlock(int level, const Eigen::Vector3i& index) const {
    return levels_[level].find(index.x(), index.y(), index.z());
  }
  int findBlock(int level, int bx, int by, int bz) const { return levels_[level].find(bx, by, bz); }
  /// Id of the block (allocated with every value 0 and marked changed when new). Ids are
  /// dense, in allocation order, and never change. Throws std::out_of_range beyond kMaxBlockIndex.
  int allocateBlock(int level, const Eigen::Vector3i& index);
  /// Allocates, at every level, the blocks holding the 8 lattice points around p (world, m),
  /// so that trilinear interpolation at p reads allocated voxels only. Returns the number of
  /// blocks newly allocated.
  int allocateAround(const Eigen::Vector3f& p);

  /// Reserves address space for this many blocks per level, so that growing up to it never
  /// moves the parameters (a move of hundreds of MB stalls training for seconds). Pages are
  /// committed only as blocks are allocated.
  void reserveBlocks(int blocks_per_level);
  /// Blocks a level holds before its parameters move.
  int blockCapacity(int level) const {
    return static_cast<int>(levels_[level].data.capacity() / (size_t(kBlockVoxels) * channels_));
  }

  /// Parameters of a level: numBlocks(level) * kBlockVoxels * channels() floats, block-major,
  /// then voxel (x fastest, then y, then z), then channel. Pointers stay valid until the next
  /// allocation. Whoever writes through levelData() calls markChanged() (or
  /// markDensityChanged()) for the blocks written, so that the density bounds stay current;
  /// blockData() marks its block itself.
  float* levelData(int level) { return levels_[level].data.data(); }
  const float* levelData(int level) const { return levels_[level].data.data(); }
  size_t levelSize(int level) const { return levels_[level].data.size(); }
  float* blockData(int level, int block) {
    markDensityChanged(level, block);
    return levels_[level].data.data() + static_cast<size_t>(block) * kBlockVoxels * channels_;
  }
  const float* blockData(int level, int block) const {
    return levels_[level].data.data() + static_cast<size_t>(block) * kBlockVoxels * channels_;
  }
  static int voxelInBlock(int x, int y, int z) { return (z * kBlockDim + y) * kBlockDim + x; }

  /// World bounds of the allocated coarse blocks (m), which contain every finer block; empty
  /// (min > max) when none.
  Eigen::Vector3f boundsMin() const { return bounds_min_; }
  Eigen::Vector3f boundsMax() const { return bounds_max_; }
  bool empty() const { return levels_.empty() || levels_[0].blocks.empty(); }

  // ---- Density bounds, for skipping space that cannot contribute to a render ----
  /// Each block splits into kSubBlocks sub-blocks of kSubDim^3 cells (sub-block s has local
  /// cell origin 4 * (s & 1, (s >> 1) & 1, s >> 2)). Its bound is the largest raw density
  /// (channel 0, bias not added) of the (kSubDim + 1)^3 lattice points that trilinear
  /// interpolation in its cells reads, 0 for unallocated points: an upper bound of the level's
  /// interpolated raw density anywhere in the sub-block.
  static constexpr int kSubDim = 4;
  static constexpr int kSubShift = 2;  // log2(kSubDim)
  static constexpr int kSubBlocks = 8;
  /// kSubBlocks bounds per block of the level (block-major), brought up to date first for
  /// blocks changed since the last call. Thread-safe; pointer valid until the next change.
  const float* densityBounds(int level) const;
  /// kSubBlocks flags per block, like densityBounds(): 1 where every channel of every lattice
  /// point the sub-block's cells read is exactly 0 (never trained: the level adds nothing
  /// there).
  const uint8_t* zeroSubBlocks(int level) const;
  /// Marks a block's density as changed (its bounds and its lower neighbours' are recomputed
  /// on the next densityBounds()). markChanged() and allocateBlock() call it.
  void markDensityChanged(int level, int block);

  // ---- Point queries (slow path, for export and tests; the renderer has its own loop) ----
  struct Value {
    float raw_density = 0;  // bias + sum of levels; meaningless when !occupied
    float density = 0;      // 1/m
    float color[3] = {0, 0, 0};
    bool occupied = false;  // inside allocated space
  };
  /// The field at p (world, m) seen along unit direction dir (world; used with SH only).
  Value query(const Eigen::Vector3f& p,
              const Eigen::Vector3f& dir = Eigen::Vector3f(0, 0, 1)) const;

  // ---- Change tracking for FieldUpdate (see mapper/field_io.h) ----
  /// Marks a block as changed since the last commit (and its density bounds as stale).
  void markChanged(int level, int block);
  /// Content version: increments on each commit that publishes at least one changed block.
  int64_t version() const { return version_; }
  /// Publishes changed blocks as the next version: at most max_blocks of them (those changed
  /// longest ago first; <= 0 = all). Returns the number committed (0 = version unchanged).
  int commit(int max_blocks = 0);
  /// Version at which the block was last committed (0 = never).
  int64_t blockVersion(int level, int block) const { return levels_[level].blocks[block].version; }
  bool blockChanged(int level, int block) const { return levels_[level].blocks[block].changed; }
  /// Sets the content version and marks every block committed at it (replicas, checkpoints).
  void setVersion(int64_t version);
  /// Checkpoint loading: the content version alone, and a block's change state.
  void restoreVersion(int64_t version) { version_ = version; }
  void restoreBlockState(int level, int block, int64_t version, bool changed) {
    BlockInfo& info = levels_[level].blocks[block];
    info.version = version;
    info.changed = changed;
    info.changed_since = 0;
  }
  /// Number of blocks changed and not yet committed.
  int pendingBlocks() const;

  /// A stamp that changes whenever the block's values may have changed (markDensityChanged),
  /// for caches derived from the field (PreviewField). Stamps come from one process-wide
  /// counter, so no block of another field (a snapshot replacing a replica) repeats one.
  uint64_t changeStamp(int level, int block) const { return levels_[level].blocks[block].stamp; }

  /// Bitwise equality of geometry, blocks (same ids) and parameters.
  bool sameContent(const Field& other) const;

 private:
  struct BlockInfo {
    Eigen::Vector3i index;
    int64_t version = 0;
    int64_t changed_since = 0;  // commit counter when it became changed (oldest first)
    uint64_t stamp = 0;         // changeStamp()
    bool changed = false;
  };
  struct Level {
    double voxel_size = 0;
    float inv_voxel_size = 0;
    std::vector<BlockInfo> blocks;
    LargeVector<float> data;
    std::unordered_map<uint64_t, int> map;  // key -> block id
    // Dense index over a box of block coordinates: fast lookups in the hot loops. Falls back to
    // the hash map when the box would be too large.
    std::vector<int> dense;
    Eigen::Vector3i dense_min = Eigen::Vector3i::Zero();
    Eigen::Vector3i dense_dim = Eigen::Vector3i::Zero();
    bool use_dense = true;
    // Density bounds (densityBounds()): kSubBlocks per block, and the blocks whose bounds are
    // stale (each listed once, flagged in bounds_stale_flag).
    mutable std::vector<float> bounds;
    mutable std::vector<uint8_t> zero_sub;
    mutable std::vector<uint8_t> bounds_stale_flag;
    mutable std::vector<int> bounds_stale;

    int find(int bx, int by, int bz) const {
      if (use_dense) {
        const unsigned x = static_cast<unsigned>(bx - dense_min.x());
        const unsigned y = static_cast<unsigned>(by - dense_min.y());
        const unsigned z = static_cast<unsigned>(bz - dense_min.z());
        if (x >= static_cast<unsigned>(dense_dim.x()) ||
            y >= static_cast<unsigned>(dense_dim.y()) || z >= static_cast<unsigned>(dense_dim.z()))
          return -1;
        return dense[(static_cast<size_t>(z) * dense_dim.y() + y) * dense_dim.x() + x];
      }
      const auto it = map.find(key(bx, by, bz));
      return it == map.end() ? -1 : it->second;
    }
    void growDense(const Eigen::Vector3i& index);
  };
  static uint64_t key(int bx, int by, int bz) {
    const uint64_t m = (1u << 21) - 1;
    return (static_cast<uint64_t>(bx) & m) | ((static_cast<uint64_t>(by) & m) << 21) |
           ((static_cast<uint64_t>(bz) & m) << 42);
  }

  // A mutex and a flag that copies of the field get fresh (the bounds themselves are copied).
  struct BoundsSync {
    std::mutex mutex;
    std::atomic<bool> stale{false};
    BoundsSync() = default;
    BoundsSync(const BoundsSync& o) : stale(o.stale.load()) {}
    BoundsSync& operator=(const BoundsSync& o) {
      stale.store(o.stale.load());
      return *this;
    }
  };
  void refreshBounds(int level) const;
  void refreshBoundsIfStale() const;

  FieldGeometry geometry_;
  std::vector<Level> levels_;
  mutable BoundsSync bounds_sync_;
  int channels_ = 0;
  int color_basis_ = 0;
  float density_scale_ = 0;
  Eigen::Vector3f bounds_min_ = Eigen::Vector3f::Constant(INFINITY);
  Eigen::Vector3f bounds_max_ = Eigen::Vector3f::Constant(-INFINITY);
  int64_t version_ = 0;
  int64_t commit_counter_ = 0;
};

/// floor(x / kBlockDim) for the lattice index x (arithmetic shift: floors negatives too).
inline int blockOf(int x) { return x >> Field::kBlockShift; }
inline int localOf(int x) { return x & (Field::kBlockDim - 1); }

/// exp(x) to about 1e-6 relative error, inline (libm's expf is a call per sample and
/// dominated the training profile): 2^(x log2 e) split into an integer power of two and a
/// degree-6 Taylor polynomial of exp(f), |f| <= ln(2) / 2.
inline float fastExp(float x) {
  x = std::clamp(x, -87.f, 88.f);
  // Round to nearest even through the float adder (|x log2 e| < 2^22): the same value as
  // std::nearbyint, which is a libm call per exp without SSE4.1.
  const float r = (x * 1.44269504089f + 12582912.f) - 12582912.f;
  // f = x - r ln 2 with ln 2 split in two (Cody-Waite): r * 0.693145751953125 is exact.
  const float f = (x - r * 0.693145751953125f) - r * 1.428606765330187e-06f;
  float p = 1.f / 720;
  p = p * f + 1.f / 120;
  p = p * f + 1.f / 24;
  p = p * f + 1.f / 6;
  p = p * f + 0.5f;
  p = p * f + 1.f;
  p = p * f + 1.f;
  const int32_t bits = (static_cast<int32_t>(r) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof(scale));
  return p * scale;
}
/// log(1 + e) for e in [0, 1] to about 1e-6 relative: 2 atanh(s), s = e / (2 + e) <= 1/3.
inline float log1pUnit(float e) {
  const float s = e / (2.f + e);
  const float s2 = s * s;
  float p = 1.f / 11;
  p = p * s2 + 1.f / 9;
  p = p * s2 + 1.f / 7;
  p = p * s2 + 1.f / 5;
  p = p * s2 + 1.f / 3;
  p = p * s2 + 1.f;
  return 2.f * s * p;
}
inline float softplus(float x) { return std::max(x, 0.f) + log1pUnit(fastExp(-std::abs(x))); }
inline float sigmoid(float x) { return 1.f / (1.f + fastExp(-x)); }
/// softplus(x) and its derivative sigmoid(x) from one exp.
inline void softplusAndSigmoid(float x, float* sp, float* sig) {
  const float e = fastExp(-std::abs(x));
  *sp = std::max(x, 0.f) + log1pUnit(e);
  const float inv = 1.f / (1.f + e);
  *sig = x >= 0 ? inv : e * inv;
}

}  // namespace radslam
