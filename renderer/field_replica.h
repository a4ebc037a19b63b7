// The renderer's copy of the mapper's field, kept in step through FIELD updates
// (mapper/field_io.h) and rendered with the mapper's own volume renderer, so a view of the
// replica is the view the mapper would render of the same field.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "common/lie.h"
#include "common/types.h"
#include "mapper/field.h"
#include "mapper/field_io.h"
#include "mapper/preview_field.h"
#include "mapper/volume_renderer.h"

namespace radslam {

/// March parameters in fine voxels, as the mapper's (MapperParams::render_step_fine and
/// TrainerParams::near_voxels; far is 1e5 fine voxels there too).
struct ReplicaRenderParams {
  float step_fine = 0.5f;
  float near_voxels = 5;
  float far_voxels = 1e5f;
  int threads = 1;
};

class FieldReplica {
 public:
  /// What the replica asks the mapper for when an update cannot be applied because earlier
  /// ones are missing (late join, lost message): the chunks of snapshot_id it lost (chunks not
  /// empty), else the blocks changed since since_version, where it was last exact (a catch-up,
  /// mapper/field_io.h makeFieldCatchUp; the mapper sends a snapshot when that is more), or a
  /// whole snapshot (since_version -1). `reason` says why.
  struct SnapshotAsk {
    std::string reason;
    int64_t since_version = -1;
    int64_t snapshot_id = -1;
    std::vector<int> chunks;
  };
  using SnapshotRequest = std::function<void(const SnapshotAsk& ask)>;

  explicit FieldReplica(ReplicaRenderParams params = ReplicaRenderParams()) : params_(params) {}
  void setSnapshotRequest(SnapshotRequest callback) { request_snapshot_ = std::move(callback); }

  /// Applies an update in version order or a snapshot whole. A non-snapshot update whose
  /// base_version is ahead of the replica (a late join, a lost message) is a gap: its blocks are
  /// applied all the same (GapPolicy::kApply, so a live view stays live) and a catch-up since
  /// the version where it was last exact is asked for (once until it or a snapshot arrives),
  /// which makes the replica exact again. A snapshot chunk past chunks that did not come asks
  /// for those again at once. Returns the result; *error says what was wrong on kGap and
  /// kInvalid.
  ApplyResult apply(const FieldUpdate& update, std::string* error = nullptr);

  const Field& field() const { return field_; }
  int64_t version() const { return field_.initialized() ? field_.version() : version_empty_; }
  bool waitingForSnapshot() const { return waiting_snapshot_; }
  /// Asks again when a repair asked for more than stall_s ago (s) made no progress since (a
  /// lost request or lost chunks): the missing chunks of the snapshot in progress, else the
  /// catch-up (or snapshot) again. now_s: any monotonic clock, s.
  void retryStalledSnapshot(double now_s, double stall_s);
  /// An update known to exist that never arrived (the mapper's STATUS reports a newer version
  /// than the last update received: the last update of a run leaves no later one to show the
  /// gap). Counts as a gap; asks for a snapshot unless one is on its way.
  void missedUpdate(const std::string& reason);
  int64_t gaps() const { return gaps_; }

  /// The mapper's march parameters for this field (what render() uses by default).
  MarchParams marchParams() const;
  /// Renders a pinhole view (as Mapper::render: background and depth 0 before any field),
  /// with marchParams() or the given parameters (faster previews). Throws
  /// std::invalid_argument on a camera without positive size and focal lengths. threads: 0 =
  /// the replica's own (ReplicaRenderParams::threads).
  RenderImages render(const SE3& T_world_cam, const CameraModel& camera,
                      const MarchParams* params = nullptr, int threads = 0) const;
  /// A live-view render with params (the preview's march) from the replica's baked copy
  /// (PreviewField, its skip threshold params.skip_thickness), brought up to date first for
  /// at most refresh_budget_s seconds (<= 0: all). Previews wait for each other; the replica
  /// must not change meanwhile (as for render()).
  RenderImages renderPreview(const SE3& T_world_cam, const CameraModel& camera,
                             const MarchParams& params, double refresh_budget_s) const;
  /// Fine blocks of the baked copy the last preview left stale (does not wait for previews).
  int previewStaleBlocks() const { return preview_stale_.load(std::memory_order_relaxed); }

 private:
  ReplicaRenderParams params_;
  Field field_;
  mutable std::mutex preview_mutex_;
  mutable PreviewField preview_;
  mutable std::atomic<int> preview_stale_{0};
  VolumeRenderer renderer_;
  SnapshotRequest request_snapshot_;
  int64_t version_empty_ = 0;  // version of an (empty) replica before the field exists
  void requestRepair(const std::string& reason);
  /// Asks for the chunks of the snapshot in progress that a chunk just received shows lost.
  void requestLostChunks(const FieldUpdate& chunk);
  void requestChunks(const std::vector<int>& chunks, const std::string& reason);

  bool waiting_snapshot_ = false;  // lost updates: waiting for a catch-up or a snapshot
  // Version at which the replica was last exact (every update since applied; -1: never, or
  // its geometry changed). An empty replica is exact at 0, where a mapper starts.
  int64_t exact_version_ = 0;
  SnapshotAssembler assembler_;
  // Chunks of the snapshot in progress asked for again, by when they were last asked for.
  std::map<int, int64_t> asked_order_;
  int64_t asked_count_ = 0;
  double now_s_ = 0;            // last time seen by retryStalledSnapshot
  double last_progress_s_ = 0;  // last request or snapshot chunk
  int64_t gaps_ = 0;
};

}  // namespace radslam
