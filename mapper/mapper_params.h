// Parameters of the radslam-mapper process: the core's (MapperParams) and the node's, loaded
// from the "mapper" section of the YAML config (every key optional, unknown keys an error).
#pragma once

#include <string>
#include <vector>

#include "mapper/field_io.h"
#include "mapper/mapper.h"

namespace radslam {

struct MapperNodeParams {
  MapperParams core;
  double update_period_s = 1.0;  // FIELD updates at most this often
  // Bounds a FIELD message (8 KB per RGB block raw, about 2 KB compressed): 250 blocks a second
  // keep FIELD within 2 MB/s even raw, so that bursts do not overrun the receivers' socket
  // buffers (a lost update costs a snapshot).
  int max_blocks_per_update = 250;
  FieldEncoding field_encoding = FieldEncoding::kZstd;  // "zstd" | "raw" (lossless either way)
  // FIELD traffic in any 1 s window stays within this (live updates wait for the next period,
  // the final flush between the final outputs for room), so that receivers' socket buffers do
  // not overrun and FIELD fits a network shared with the sensors. Below 2 so that a receiver,
  // which sees messages bunched by the bus and its own scheduling, still measures under 2.
  double field_max_mb_per_s = 1.8;
  double snapshot_min_period_s = 10.0;  // snapshot requests in between are served together
  double status_period_s = 0.5;         // STATUS heartbeat
  // Training after a stop request (the sensors are done, and with them the tracker): at least
  // final_training_s, then on until the keyframes have drawn final_rays_per_keyframe rays each
  // on average since they arrived, for at most final_training_max_s in all, on
  // final_training_threads threads (0 = every core). A live run trains far fewer rays than its
  // map can use: fr1/rpy trains about 0.5M rays while its 5.7 s play, and its keyframes pass
  // 25 dB at about 6M (200k per keyframe; docs/mapper.md).
  double final_training_s = 5.0;
  int final_rays_per_keyframe = 200000;
  double final_training_max_s = 60.0;
  int final_training_threads = 0;
  // After the final flush, snapshots are served until every renderer heard from reports the
  // final field version, for at most this long (s): a replica that lost the last update has no
  // later one to reveal the gap, only this STATUS's version.
  double final_sync_s = 20.0;
  bool checkpoint_images = true;  // checkpoints carry the keyframe images (to resume)
  // A checkpoint (OUT/mapper.ckpt) this often while running, for a restart to resume from
  // (s, 0 = only at the end; each is about 3 copies of the field).
  double checkpoint_period_s = 0;
  int render_stride = 2;  // final point cloud: every n-th pixel of each keyframe
  // Threads of the final renders (0 = every core: the tracker is done by then).
  int final_render_threads = 0;
  float mesh_iso = 1.f;          // final mesh: optical thickness per fine voxel
  int mesh_max_faces = 4000000;  // final mesh: a coarser lattice beyond (~100 MB PLY)
  bool publish_poses = true;     // refined keyframe poses on MAPPER_POSE
  // A refined pose is published again once it moved this far from the last one sent (m, deg),
  // and at the end of the run whatever it moved.
  double pose_publish_min_m = 1e-3;
  double pose_publish_min_deg = 0.05;
};

/// Reads yaml_path's "mapper" section ("" = defaults) with "key=value" overrides; *dump gets
/// every value in force (YAML) and *source where they came from. Throws std::runtime_error
/// naming the file and key on bad values (and std::invalid_argument on inconsistent ones).
MapperNodeParams loadMapperParams(const std::string& yaml_path,
                                  const std::vector<std::string>& overrides, std::string* dump,
                                  std::string* source);

}  // namespace radslam
