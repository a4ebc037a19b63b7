// Parameters of the radslam-mapper process: the core's (MapperParams) and the node's, loaded
// from the "mapper" section of the YAML config (every key optional, unknown keys an error).
#pragma once

#include <string>
#include <vector>

#include "mapper/mapper.h"

namespace radslam {

struct MapperNodeParams {
  MapperParams core;
  double update_period_s = 1.0;  // FIELD updates at most this often
  // Bounds a FIELD message (about 8 KB per RGB block): 250 blocks a second keep FIELD near
  // 2 MB/s, so that bursts do not overrun the receivers' socket buffers (a lost update costs
  // a snapshot).
  int max_blocks_per_update = 250;
  double snapshot_min_period_s = 10.0;  // snapshot requests in between are served together
  double status_period_s = 0.5;         // STATUS heartbeat
  double final_training_s = 5.0;        // training burst after a stop request
  bool checkpoint_images = true;        // checkpoints carry the keyframe images (to resume)
  int render_stride = 2;                // final point cloud: every n-th pixel of each keyframe
  float mesh_iso = 1.f;                 // final mesh: optical thickness per fine voxel
  bool publish_poses = true;            // refined keyframe poses on MAPPER_POSE
};

/// Reads yaml_path's "mapper" section ("" = defaults) with "key=value" overrides; *dump gets
/// every value in force (YAML) and *source where they came from. Throws std::runtime_error
/// naming the file and key on bad values (and std::invalid_argument on inconsistent ones).
MapperNodeParams loadMapperParams(const std::string& yaml_path,
                                  const std::vector<std::string>& overrides, std::string* dump,
                                  std::string* source);

}  // namespace radslam
