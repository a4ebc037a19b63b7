// A compact single-level copy of a Field for fast approximate renders (the renderer's live
// views).
//
/// Why one level is enough: the lattices nest (voxel sizes are integer multiples and lattice
/// points sit at i * voxel_size), so within one fine cell every coarser level's trilinear
/// interpolant is itself trilinear, and the field's sum of levels is the trilinear
/// interpolation of the summed values at the fine cell's corners. Baking those sums at the fine
/// lattice points turns a sample's per-level lookups and gathers into one gather.
///
/// Layout: per fine sub-block (Field::kSubDim^3 cells), the (kSubDim + 1)^3 lattice points its
/// cells read, stored together (no lookups across blocks), as bfloat16 (8 mantissa bits,
/// rounded to nearest: at most 0.2% off, which the preview accepts for half the memory), with
/// the raw density bias added. A sub-block whose density bound gives less than skip_thickness
/// optical thickness per fine voxel stores nothing and is stepped over; within a stored
/// sub-block, so are its 2^3-cell corners below that threshold.
///
/// Empty space: a dense grid over the fine blocks that store something holds, per block, its
/// id or its chessboard distance (in blocks) to the nearest such block, so a ray crosses free
/// space in jumps of up to that many blocks without a hash lookup.
#pragma once

#include <cmath>
#include <cstdint>
#include <deque>
#include <vector>

#include <Eigen/Core>

#include "common/lie.h"
#include "common/types.h"
#include "mapper/field.h"
#include "mapper/volume_renderer.h"

namespace radslam {

class PreviewField {
 public:
  static constexpr int kSubPoints = Field::kSubDim + 1;  // lattice points per sub-block axis
  static constexpr int kPointsPerSub = kSubPoints * kSubPoints * kSubPoints;

  /// skip_thickness: optical thickness per fine voxel below which a sub-block is empty here
  /// (MarchParams::skip_thickness; 0 keeps every allocated sub-block).
  explicit PreviewField(float skip_thickness = 0.05f);

  /// Brings the copy up to date with `field` (the field it was refreshed from, changed since,
  /// or one that replaced it): sub-blocks whose values depend on blocks changed since the last
  /// call (Field::changeStamp) are baked again, new blocks first and then the longest stale,
  /// until budget_s seconds have passed (<= 0: all of them; > 0: at least a few blocks). Until
  /// then a stale sub-block renders as baked last, a new one as empty. Returns the number of
  /// fine blocks still stale.
  int refresh(const Field& field, double budget_s = 0);
  int staleBlocks() const { return static_cast<int>(dirty_.size()); }
  /// Memory of the baked values (bytes).
  size_t bytes() const { return values_.size() * sizeof(uint16_t); }
  float skipThickness() const { return skip_thickness_; }

  /// VolumeRenderer::march on this copy of `field` (the field refresh() last saw; blocks
  /// allocated since are empty). params.skip_thickness is ignored: the one baked in applies.
  /// The march starts at t_start when that is past the ray's entry; first_sample_t (when
  /// given) receives the t of its first sample (+inf: none).
  RayOutput march(const Field& field, const Ray& ray, const MarchParams& params,
                  const Eigen::Vector3f& background, float t_start = -INFINITY,
                  float* first_sample_t = nullptr) const;
  /// A pinhole view, as VolumeRenderer::render, in two passes. Every second pixel of every
  /// second row is marched whole. Every other pixel starts one fine block before the first
  /// sample of the nearest of those pixels (up to 2 x 2 of them) when all of them took one,
  /// which steps over the free space in front of a surface without visiting it; a structure
  /// more than a block in front of all of them that only the pixels between them see is
  /// missed. A pixel next to one that met nothing is marched whole.
  RenderImages render(const Field& field, const SE3& T_world_cam, const CameraModel& camera,
                      const MarchParams& params, const Eigen::Vector3f& background,
                      int threads = 1) const;

 private:
  struct FineBlock {
    int32_t slot[Field::kSubBlocks];  // into values_ (kPointsPerSub * channels each), -1 = empty
    // softplus of the largest raw density (bias included) of a sub-block's points: its
    // density bound, times Field::densityScale().
    float sigma_bound[Field::kSubBlocks];
    // Per sub-block, bit m: its 2^3 cells m (m = x + 2 y + 4 z, in 2-cell units) stay below
    // the skip threshold, and samples there are skipped.
    uint8_t empty_cells[Field::kSubBlocks];
    uint8_t stored;         // bit s: sub-block s has a slot
    bool baked;             // at least once
    Eigen::Vector3i index;  // the block's index when baked
  };
  void reset(const FieldGeometry& geometry);
  void markDependents(const Field& field, int level, int block);
  void markDirty(int fine_block);
  void bakeBlock(const Field& field, int fine_block);
  void buildGrid();
  template <int NB>
  RayOutput marchImpl(const Field& field, const Ray& ray, const MarchParams& params,
                      const Eigen::Vector3f& background, float t_start,
                      float* first_sample_t) const;

  float skip_thickness_;
  float skip_raw_;  // raw density (bias included) below which a sub-block is empty
  FieldGeometry geometry_;
  bool have_geometry_ = false;
  int channels_ = 0;
  std::vector<FineBlock> blocks_;            // per fine block id of the field
  std::vector<std::vector<uint64_t>> seen_;  // per level and block: the stamp baked from
  std::vector<uint16_t> values_;             // bfloat16, slot-major, point, channel
  std::vector<int32_t> free_slots_;
  std::deque<int> dirty_;  // fine blocks to bake, oldest first
  std::vector<uint8_t> dirty_flag_;
  // The block grid (block units): cell (x, y, z) of grid_ is block grid_min_ + (x, y, z), x
  // fastest; >= 0 a fine block id that stores a sub-block, < 0 minus the chessboard distance
  // to the nearest one (at most kMaxSkip). Rebuilt when a block gains or loses its last
  // stored sub-block.
  static constexpr int kMaxSkip = 64;
  Eigen::Vector3i grid_min_ = Eigen::Vector3i::Zero(), grid_size_ = Eigen::Vector3i::Zero();
  std::vector<int32_t> grid_;
  bool grid_stale_ = true;
};

}  // namespace radslam
