// The mapper core (no bus): keyframes in, training steps, refined poses, field updates,
// renders and checkpoints out. mapper/mapper_node.h wires it to the bus.
#pragma once

#include <cstdint>
#include <set>
#include <string>
#include <vector>

#include "common/types.h"
#include "mapper/field.h"
#include "mapper/field_io.h"
#include "mapper/keyframe_store.h"
#include "mapper/trainer.h"
#include "mapper/volume_renderer.h"

namespace radslam {

struct MapperParams {
  // Field. The fine voxel size is fixed by the first keyframe with depth unless given.
  double fine_voxel_size = 0;  // m; 0 = fine_voxel_rel * median depth
  double fine_voxel_rel = 0.01;
  int levels = 2;
  int level_ratio = 4;
  int sh_degree = 0;
  double density_bias = -4.6;  // raw density offset: softplus(-4.6) = 0.01 per fine voxel
  // Allocation around each keyframe's depth.
  int alloc_stride = 4;         // pixels
  float alloc_sigma_range = 3;  // depth sigmas either side of the depth
  /// ... but at most this many fine voxels either side: a pixel whose depth is that uncertain
  /// (monocular, low parallax) would allocate long, mostly empty segments for little gain.
  float alloc_max_band_voxels = 8;
  /// Memory bound: no fine blocks are allocated past this many (about 8 KB each with RGB), and
  /// pixels deeper than this many times the keyframe's median depth are not allocated for
  /// (monocular depth outliers would otherwise allocate long empty segments).
  int max_fine_blocks = 60000;
  /// Memory bound on keyframes (about 1.5 MB each at 320x240): past it, the keyframe whose
  /// pose is closest to another's (the older of the pair; never the gauge or the newest) is
  /// retired, and later versions of it are ignored.
  int max_keyframes = 300;
  float alloc_max_depth_ratio = 4;
  /// Newly allocated fine voxels at a keyframe's depth start opaque (this raw density) with
  /// the pixel's colour, so training starts from the depth prior instead of fog; 0 = off.
  double seed_density = 8;
  /// Lattice points of those blocks that the keyframe's measured depth sees through (in front
  /// of the surface, beyond the seeded colour band) start at this raw density; 0 = off. The
  /// default density (density_bias: 0.01 per fine voxel) in the allocated space in front of
  /// the surfaces (bands up to 3 x 16 voxels deep for far, noisy depths, and whole 8-voxel
  /// blocks) put much of the render weight in front of the surface (fr1/rpy, one keyframe at
  /// its own pose: depth L1 14 cm before training; 4 cm with -4).
  double seed_free_density = -4;
  /// Pixels without depth (sensor holes: beyond range, dark or specular surfaces) get the
  /// depth of their nearest surroundings with infinite variance: no depth loss, but the field is
  /// allocated there (within alloc_hole_sigmas of the widest sampling sigma) and training
  /// samples go there, so their colour is learnt instead of staying background. false = holes
  /// stay unallocated.
  bool fill_depth_holes = true;
  /// A new keyframe's exposure starts from an affine fit of its image to the field's render at
  /// its pose, on every n-th pixel in x and y (0 = start at zero). That render was the largest
  /// cost of adding a keyframe (monocular street, live: 0.33 s of 0.55 s at stride 4); fr1/rpy
  /// scores the same at 8 (docs/mapper.md).
  int exposure_init_stride = 8;
  float alloc_hole_sigmas = 1;
  TrainerParams trainer;
  // Render-only path (renders of keyframes, the renderer process).
  float render_step_fine = 0.5f;  // fine voxels
  int render_threads = 1;
};

/// A keyframe pose refined by the mapper.
struct RefinedPose {
  int32_t keyframe_id = 0;
  int32_t version = 0;
  Header header;  // the keyframe's
  SE3 T_world_cam;
};

class Mapper {
 public:
  /// Throws std::invalid_argument on inconsistent parameters.
  explicit Mapper(const MapperParams& params = MapperParams());

  /// Stores (or replaces, by version) a keyframe and allocates the field around its depth.
  /// The first keyframe with depth fixes the voxel sizes. A re-sent keyframe (same image) costs
  /// little: its exposure is kept and only the blocks its new depth adds are seeded. Throws
  /// std::invalid_argument on a malformed keyframe (KeyframeStore::insert).
  KeyframeStore::InsertResult addKeyframe(const Keyframe& keyframe);

  /// Forgets every keyframe and the field (CONTROL RESET).
  void reset();

  /// `steps` training steps; statistics of the last one.
  TrainStats train(int steps = 1);
  /// Training threads from now on (>= 1; the gradients' sum is in thread order, so a given
  /// count is deterministic).
  void setTrainingThreads(int threads);

  /// Poses refined since the last call (the gauge keyframe never is).
  std::vector<RefinedPose> takeRefinedPoses();

  /// Blocks changed since `since_version` (commits at most max_blocks pending changes first,
  /// <= 0 = all); see mapper/field_io.h.
  FieldUpdate makeUpdate(int64_t since_version, int max_blocks = 0);
  /// makeFieldCatchUp on the field (mapper/field_io.h); no blocks without a field.
  FieldUpdate makeCatchUp(int64_t since_version, int max_blocks);
  FieldUpdate makeSnapshot();
  /// A snapshot in chunks of at most max_blocks blocks (mapper/field_io.h). The field must be
  /// initialized; the sender is invalid after reset().
  SnapshotSender makeSnapshotSender(int64_t snapshot_id, int max_blocks);

  /// Renders any pinhole view (deterministic given the field), through a rolling shutter when
  /// one is given. threads: 0 = params().render_threads.
  RenderImages render(const SE3& T_world_cam, const CameraModel& camera, int threads = 0,
                      const RollingShutterView& rolling_shutter = {}) const;
  MarchParams marchParams() const;

  /// Checkpoint: field, optimiser state, keyframe poses and statistics, trainer counters and,
  /// with images, the keyframe images (enough to resume training exactly).
  void saveCheckpoint(const std::string& path, bool with_images = true) const;
  /// Replaces the state by a checkpoint's. Throws std::runtime_error naming the file.
  void loadCheckpoint(const std::string& path);
  /// Moves the field version past every version this mapper can have published before a
  /// restart (a resumed field is older than what replicas may hold: its updates must not look
  /// stale to them).
  void skipVersionsAfterRestart();

  const MapperParams& params() const { return params_; }
  const Field& field() const { return field_; }
  Field& field() { return field_; }
  const KeyframeStore& keyframes() const { return keyframes_; }
  /// True for a keyframe retired by the max_keyframes bound.
  bool retired(int32_t keyframe_id) const { return retired_.count(keyframe_id) > 0; }
  KeyframeStore& keyframes() { return keyframes_; }
  const Trainer& trainer() const { return trainer_; }
  Trainer& trainer() { return trainer_; }

 private:
  void initializeField();
  /// Pixels deeper than this (alloc_max_depth_ratio times the keyframe's median depth) are
  /// neither allocated for nor seeded; 0 when the keyframe has no depth.
  float allocationDepthLimit(const Keyframe& kf) const;
  /// Allocates around the keyframe's depth and seeds the surface it sees: in any untouched
  /// voxel, or only in the new blocks when `new_blocks_only` (a re-sent keyframe, whose earlier
  /// version seeded the rest).
  void allocateFor(const KeyframeEntry& entry, bool new_blocks_only = false);
  /// max_depth: allocationDepthLimit of the keyframe (pixels past it are not seeded).
  void seedSurface(const KeyframeEntry& entry, int first_new_block, bool new_blocks_only,
                   float max_depth);
  void initExposure(KeyframeEntry* entry) const;
  void retireMostRedundant(int32_t newest_id);

  MapperParams params_;
  Field field_;
  KeyframeStore keyframes_;
  Trainer trainer_;
  VolumeRenderer renderer_;
  int64_t version_floor_ = 0;  // field versions stay monotonic across resets
  std::set<int32_t> retired_;  // keyframe ids dropped by max_keyframes
  bool block_budget_warned_ = false;
};

/// depth with its holes (<= 0) filled from the nearest valid depths (the farthest of them, as
/// holes are mostly beyond the sensor's range); unchanged when it has no valid depth. Filled
/// values are a guess for allocation and sampling, not a measurement.
cv::Mat fillDepthHoles(const cv::Mat& depth);

/// Median of the valid (> 0, finite) depths of a keyframe, 0 when none.
double medianDepth(const Keyframe& keyframe);

}  // namespace radslam
