// The mapper on the bus: KEYFRAME, POSE and CONTROL in; FIELD, MAPPER_POSE and STATUS out.
// Trains continuously between messages on one thread (the core may use more, see threads).
// POSE only serves the final outputs: renders of every 10th non-keyframe at its tracked pose.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>

#include "common/bus.h"
#include "common/process_stats.h"
#include "mapper/mapper.h"
#include "mapper/mapper_params.h"

namespace radslam {

/// Keyframe poses refined by the mapper (PoseStamped, is_keyframe = true, frame_index = the
/// keyframe's; header = the keyframe's header). Not POSE: that is the tracker's stream.
inline constexpr const char* kMapperPoseChannel = "MAPPER_POSE";

class MapperNode {
 public:
  /// out_dir: where checkpoints and final outputs go ("" = no files).
  MapperNode(Bus* bus, const MapperNodeParams& params, std::string out_dir);
  ~MapperNode();

  /// Continues from a checkpoint of an earlier run of this mapper (restart after a crash):
  /// field, optimiser and keyframes; replicas get a snapshot. Throws std::runtime_error naming
  /// the file when it cannot be read (the mapper is then unchanged).
  void resume(const std::string& checkpoint);

  /// Asks the tracker for keyframes again (CONTROL REPUBLISH, argument "keyframes" = every one
  /// it still holds, "keyframes:3,7" = those ids). run() asks for all once at the start (those
  /// sent while this mapper was not running); lost ones are asked for as they are noticed.
  void requestKeyframes(const std::string& which = "keyframes");

  /// Loops until a stop (signal or CONTROL STOP for "mapper" or all) or the end of a file://
  /// log, then finishes (final training, outputs). Returns the process exit code.
  int run();

  /// One iteration: handle pending messages (waiting at most timeout_ms when idle), add
  /// queued keyframes, one training step, periodic publishing. Exposed for tests.
  /// Returns false when the bus failed or ended.
  bool spinOnce(int timeout_ms);
  /// Final training burst (bounded by final_training_s), last field update and poses, outputs.
  void finish();

  bool stopRequested() const { return stop_; }
  const Mapper& mapper() const { return mapper_; }
  int64_t publishedVersion() const { return delta_base_; }

 private:
  void onKeyframe(const Keyframe& keyframe);
  void onPose(const PoseStamped& pose);
  void onControl(const Control& control);
  void onStatus(const Status& status);
  /// After the final flush: serves snapshots until every renderer heard from in the last few
  /// seconds reports the final version, for at most final_sync_s.
  void awaitReplicas();
  /// Adds every queued keyframe the mapper does not hold yet, newest last, then at most
  /// max_refinements queued versions of keyframes it holds (all when negative). Refinements
  /// wait while the mapper trains, so versions queued meanwhile merge into one.
  void addQueuedKeyframes(int max_refinements);
  void addKeyframe(const Keyframe& keyframe);
  void requestMissingKeyframes();
  class Pacer;
  // One update period's FIELD messages: max_blocks_per_update blocks, of which a snapshot in
  // progress takes 3/4 in chunks, while the FIELD limit allows.
  void publishUpdate();
  // The final flush, one message: false once everything went out.
  bool publishFlushMessage();
  // Flush messages while the FIELD limit allows (to_end: until done, waiting for it).
  void flushField(bool to_end);
  /// Starts a snapshot (sent in chunks by publishUpdate and the final flush) or, without a
  /// field yet, sends the empty one.
  void startSnapshot();
  int publishSnapshotChunk();  // returns its blocks
  /// Publishes the catch-up asked for, or asks for a snapshot when it would be too large;
  /// returns its blocks.
  int publishCatchUp();
  // Blocks per FIELD message: at most max_blocks_per_update, and at most a quarter of a
  // second's FIELD limit even uncompressed. A message is one unit for the pacer, so its size
  // is how far a receiver that sees messages bunched can measure past the limit (250 trained
  // blocks made messages of 1.8 MB, and a receiver measured 2.0 MB/s at a limit of 1.8).
  int blocksPerMessage() const;
  // Refined poses that moved past the deadband since last published (all: every one not yet
  // published as it is).
  void publishPoses(bool all = false);
  void publishStatus();
  void heartbeat();  // publishStatus at most once per status period
  // Encoded as configured, when it fits the FIELD limit (waits until then).
  void publishField(FieldUpdate* update);
  void saveCheckpoint(const std::string& path);
  double now() const;

  Bus* bus_;
  MapperNodeParams params_;
  std::string out_dir_;
  Mapper mapper_;
  StatusReporter reporter_;
  std::map<int32_t, Keyframe> queue_;  // latest version per id, waiting to be added
  /// Latest tracked pose per frame index (the tracker re-publishes refined poses at the end).
  std::map<int64_t, PoseStamped> frame_poses_;
  std::map<int32_t, SE3> published_poses_;            // MAPPER_POSE: last sent per keyframe id
  std::map<int32_t, RefinedPose> unpublished_poses_;  // refined since, within the deadband
  int64_t delta_base_ = 0;                            // version of the last published delta update
  bool snapshot_requested_ = false;
  std::optional<SnapshotSender> snapshot_;       // chunks to send
  std::optional<SnapshotSender> sent_snapshot_;  // the last one sent, for chunks asked again
  // A catch-up asked for (the oldest version a replica is exact at; -1 = none) and the oldest
  // version this field's history can serve one from (a resumed or reset field starts anew).
  int64_t catch_up_since_ = -1;
  int64_t catch_up_floor_ = 0;
  bool flushing_ = false;  // the final flush is under way
  // Snapshot ids: from the start time (us), so that a restarted mapper's snapshots differ
  // from those replicas may still be assembling.
  int64_t snapshot_seq_ = 0;
  bool stop_ = false;
  std::string save_request_;  // checkpoint path asked for by CONTROL SAVE ("" = none)
  bool save_requested_ = false;
  std::chrono::steady_clock::time_point start_;
  std::unique_ptr<Pacer> field_pacer_;  // every FIELD message (field_max_mb_per_s)
  double last_update_ = -1e9, last_status_ = -1e9, last_snapshot_ = -1e9, last_checkpoint_ = 0;
  int32_t max_keyframe_id_ = -1;             // highest keyframe id received
  int64_t newest_keyframe_utime_ = 0;        // sensor time of the newest keyframe taken (us)
  std::map<int32_t, int> missing_requests_;  // times each missing id was asked for
  double last_missing_request_ = -1e9;
  struct ReplicaState {
    int64_t field_version = -1;
    bool waiting_snapshot = false;
    bool done = false;    // its run ended: it takes no more updates
    double heard_at = 0;  // listen_s_ when its last STATUS came
  };
  // Time spent waiting for renderers' STATUS after the final flush (s): a renderer silent for
  // kRecentS of it is gone (a count of wall time would also count the mapper's own busy time).
  double listen_s_ = 0;
  std::map<std::pair<std::string, int32_t>, ReplicaState> replicas_;  // by (process, pid)
  int64_t rays_ = 0;
  double train_s_ = 0;
  TrainStats last_stats_;
};

}  // namespace radslam
