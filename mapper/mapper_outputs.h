// What the mapper leaves in the run folder: checkpoint, point cloud and mesh (PLY), renders of
// every keyframe and the refined keyframe trajectory. No bus: the node calls it at the end.
#pragma once

#include <cstdint>
#include <string>

#include "mapper/mapper.h"

namespace radslam {

struct MapperOutputOptions {
  bool checkpoint_images = true;
  int cloud_stride = 2;  // pixels
  float mesh_iso = 1.f;
};

struct MapperOutputSummary {
  std::string checkpoint, cloud, mesh, trajectory;
  int renders = 0;
  size_t cloud_points = 0, mesh_faces = 0;
};

/// "%.6f" seconds of a sensor time in microseconds: the file stem of a keyframe's renders.
std::string renderStem(int64_t utime);

/// Writes into out_dir (created if needed): mapper.ckpt, map_points.ply, map_mesh.ply,
/// mapper_keyframes.txt (TUM, refined poses), renders/rgb/<stem>.png (colour) and
/// renders/depth/<stem>.exr (channels "depth" and "sigma", m) of every keyframe at its refined
/// pose and camera. Throws std::runtime_error naming the file that cannot be written.
MapperOutputSummary writeMapperOutputs(const Mapper& mapper, const std::string& out_dir,
                                       const MapperOutputOptions& options);

}  // namespace radslam
