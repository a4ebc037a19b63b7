// Field updates (channel FIELD): how the renderer's replica stays bitwise identical to the
// mapper's field.
//
/// Protocol: the mapper commits its changed blocks as a new version (Field::commit) and sends
/// the blocks committed after the replica's version (base_version) with their current values.
/// A replica at version r applies an update (base b, version v) when b <= r < v: every block
/// that changed in (b, v] is in it, every other block is as it was at b. A snapshot carries
/// every block and replaces the replica. Applying a mapper's updates in version order, then
/// one made after its last change, reproduces its field bitwise. A replica that lost updates
/// after version e, where it was last exact, is exact again with a catch-up: an update based
/// at e (makeFieldCatchUp), or a snapshot when more changed since than a message holds.
///
/// Snapshots travel in chunks (SnapshotSender), so that no message outgrows what the bus
/// delivers: each chunk carries the current values of its blocks. A replica assembles the
/// chunks of one snapshot (SnapshotAssembler), asks for the ones it lost again, and takes the
/// result once every chunk arrived, at the version v of the latest; blocks changed after their
/// chunk went out come again in the mapper's next update, which it bases at v or earlier.
///
/// Payload layout "rsvox1": per block, kBlockVoxels * channels float32 values, little-endian,
/// voxel-major (x fastest, then y, then z) and channel-minor as in Field. The layout string
/// also names the encoding (f32le: the values as they are; f32le+zstd: each block one zstd
/// frame of them, lossless), the channel count, the SH degree and the density bias (C99 hex
/// float, exact).
#pragma once

#include <cstdint>
#include <deque>
#include <string>
#include <vector>

#include "common/types.h"
#include "mapper/field.h"

namespace radslam {

/// How block payloads travel. Voxels that no ray reached keep their initial values, so a
/// block compresses about 4x (TUM fr1/rpy fields) at a few percent of a core per MB/s.
enum class FieldEncoding { kRaw, kZstd };

/// "rsvox1 f32le ch=C sh=S bias=HEX" (kRaw) or "rsvox1 f32le+zstd ..." (kZstd).
std::string fieldLayout(const FieldGeometry& geometry,
                        FieldEncoding encoding = FieldEncoding::kRaw);
/// Parses a layout and the update's voxel sizes into a geometry (and *encoding if given);
/// false with *error on a layout this code does not understand.
bool parseFieldLayout(const std::string& layout, const std::vector<double>& voxel_size,
                      FieldGeometry* geometry, std::string* error,
                      FieldEncoding* encoding = nullptr);

/// Re-encodes the blocks of an update made by this file's functions (raw) in place; a no-op
/// for kRaw. applyFieldUpdate reads either encoding.
void encodeFieldUpdate(FieldEncoding encoding, FieldUpdate* update);

/// Commits up to max_blocks pending changes (<= 0: all), then returns the blocks committed
/// after since_version (not a snapshot). An empty block list means nothing changed.
FieldUpdate makeFieldUpdate(Field* field, int64_t since_version, int max_blocks = 0);
/// Commits every pending change and returns all blocks (one message).
FieldUpdate makeFieldSnapshot(Field* field);
/// A catch-up for a replica exact at since_version that lost updates after it: the blocks
/// committed after since_version, as an update based there, at a new version (a block is
/// committed again if nothing else is pending), so that it also follows every later update
/// the replica applied. Any replica at since_version or later applies it. Empty (no blocks)
/// when more than max_blocks blocks changed since: a snapshot is the cheaper repair then.
FieldUpdate makeFieldCatchUp(Field* field, int64_t since_version, int max_blocks);

/// A snapshot in chunks of at most max_blocks blocks each: the block list is taken (after a
/// commit) at construction, each chunk reads the blocks' values when it is made. The field must
/// outlive the sender and keep its blocks (blocks are only ever added). Chunks a replica lost
/// are sent again on request (resend), with the content they have then.
class SnapshotSender {
 public:
  SnapshotSender(Field* field, int64_t snapshot_id, int max_blocks);
  /// Every chunk asked for so far was sent (resend() makes a sender busy again).
  bool done() const { return pending_.empty(); }
  int64_t id() const { return snapshot_id_; }
  /// The field version when the last chunk so far was sent: a replica that assembled the whole
  /// snapshot is at version() of its last chunk, so the deltas sent meanwhile, based on the
  /// same version, follow it without a gap.
  int64_t version() const { return version_; }
  int chunkCount() const { return chunk_count_; }
  /// The next chunk (is_snapshot, chunk_index, chunk_count, version = the field's now): the
  /// blocks' current content. With the last chunk asked for, blocks committed after their own
  /// chunk went out are marked changed again, so that deltas bring the assembled replica up to
  /// date (sending the snapshot does not hold the deltas back). Throws std::logic_error when
  /// done().
  FieldUpdate next();
  /// Queues chunks to send again (indices outside [0, chunkCount()) and chunks already queued
  /// are ignored); returns how many were queued.
  int resend(const std::vector<int>& chunks);

 private:
  Field* field_;
  int64_t snapshot_id_;
  int64_t version_;
  int max_blocks_;
  int chunk_count_;
  std::vector<std::pair<int, int>> blocks_;  // (level, block)
  std::vector<int64_t> sent_at_;             // field version when each block's chunk went out
  std::deque<int> pending_;                  // chunk indices still to send, in order
};

/// Collects the chunks of a snapshot into a field of its own, in any order: chunks of another
/// snapshot start over with that one. missing() says which chunks to ask for again; the
/// snapshot is complete, at the version of the latest chunk, once every chunk arrived.
class SnapshotAssembler {
 public:
  enum class Result { kIncomplete, kComplete, kInvalid };
  /// Takes a snapshot chunk (update.is_snapshot). kComplete: field() holds the snapshot.
  Result add(const FieldUpdate& chunk, std::string* error);
  Field& field() { return field_; }
  bool inProgress() const { return snapshot_id_ >= 0; }
  int64_t snapshotId() const { return snapshot_id_; }
  /// The chunk indices of the snapshot in progress that have not arrived, ascending.
  std::vector<int> missing() const;
  /// Drops the snapshot in progress.
  void reset();

 private:
  Field field_;
  int64_t snapshot_id_ = -1;  // -1: none in progress
  std::vector<bool> received_;
  int received_count_ = 0;
};

/// CONTROL SNAPSHOT argument asking for the updates since a version (makeFieldCatchUp):
/// "since VERSION".
std::string catchUpArgument(int64_t since_version);
/// Parses catchUpArgument's format; false (output unchanged) for anything else.
bool parseCatchUpArgument(const std::string& argument, int64_t* since_version);
/// CONTROL SNAPSHOT argument asking for chunks of a snapshot again: "chunks ID I,J,...".
/// Any other argument asks for a whole new snapshot.
std::string snapshotChunksArgument(int64_t snapshot_id, const std::vector<int>& chunks);
/// Parses snapshotChunksArgument's format; false (outputs unchanged) for anything else.
bool parseSnapshotChunksArgument(const std::string& argument, int64_t* snapshot_id,
                                 std::vector<int>* chunks);

enum class ApplyResult {
  kApplied,  // the replica is at update.version now
  kStale,    // update.version <= replica version: nothing to do
  kGap,      // base_version > replica version: updates are missing, ask for a snapshot
             // (with GapPolicy::kApply the blocks were applied all the same)
  kInvalid,  // malformed or incompatible (error says what); the replica is unchanged
  kPartial,  // a snapshot chunk was stored; the replica changes with the last one
};
const char* applyResultName(ApplyResult result);

/// What a delta that skips lost updates does to the replica. Each block of an update carries
/// its whole state, so applying it leaves only the blocks that changed in the lost updates (and
/// not since) stale: a live view stays close to the mapper's while a snapshot is on its way.
enum class GapPolicy {
  kReject,  // the replica is unchanged
  kApply,   // the blocks are applied and the replica moves to update.version
};

/// Applies an update to a replica (an uninitialised replica takes the update's geometry).
ApplyResult applyFieldUpdate(const FieldUpdate& update, Field* replica, std::string* error,
                             GapPolicy gap_policy = GapPolicy::kReject);

/// Writes a snapshot chunk's blocks into a replica of the same geometry, its version unchanged:
/// a replica that lost updates repairs the blocks of every chunk it gets, also of a snapshot
/// that lost other chunks (at 5% loss, a snapshot of 60 chunks rarely arrives whole). kApplied,
/// or kInvalid (replica unchanged) for a malformed chunk or another geometry.
ApplyResult repairFromSnapshotChunk(const FieldUpdate& chunk, Field* replica, std::string* error);

}  // namespace radslam
