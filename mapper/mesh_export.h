// Exports of the field: a coloured triangle mesh (iso-surface of the density) and a coloured
// point cloud (where rendered depth lands), written as binary little-endian PLY.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "common/lie.h"
#include "common/types.h"
#include "mapper/field.h"
#include "mapper/volume_renderer.h"

namespace radslam {

struct Mesh {
  std::vector<Eigen::Vector3f> vertices;       // world, m
  std::vector<std::array<uint8_t, 3>> colors;  // RGB per vertex
  std::vector<Eigen::Vector3i> faces;          // counter-clockwise seen from outside
  bool complete = true;                        // false: extraction stopped at the face budget
  int stride = 1;                              // lattice step, fine voxels
};

struct PointCloud {
  std::vector<Eigen::Vector3f> points;         // world, m
  std::vector<std::array<uint8_t, 3>> colors;  // RGB
};

/// Iso-surface of the optical thickness per fine voxel, softplus(bias + sum of levels), at
/// `iso` (1 = the density that absorbs 63% of the light over one fine voxel), sampled on the
/// fine lattice inside allocated fine blocks. Marching cubes with each cube split into six
/// tetrahedra around its main diagonal (no ambiguous cases, watertight; vertices shared
/// between cells). Faces are oriented with the normal pointing out of the dense side; vertex
/// colours are the field's view-independent colour. `stride` (dividing the block size) samples
/// every stride-th fine lattice point (a coarser mesh); extraction stops (complete = false) once
/// the mesh has more than max_faces faces.
Mesh extractMesh(const Field& field, float iso = 1.f, int stride = 1,
                 size_t max_faces = std::numeric_limits<size_t>::max());

/// The finest mesh (stride 1, 2, 4 or 8) within max_faces faces: a noisy monocular field's
/// iso-surface at the fine lattice can have tens of millions of faces (gigabytes to extract).
Mesh extractMeshWithin(const Field& field, float iso, size_t max_faces);

/// Surface points of rendered views: every `stride`-th pixel (in both directions) whose ray
/// is absorbed (weight >= 0.5, depth normalised by it) gives the point at its rendered depth with
/// its rendered colour; one point per fine voxel is kept (colours averaged). Fed with the renders
/// a run writes anyway, so the cloud costs no rendering of its own.
class SurfacePointCloud {
 public:
  explicit SurfacePointCloud(const Field& field);
  void add(const SE3& T_world_cam, const CameraModel& camera, const RenderImages& images,
           int stride);
  PointCloud points() const;

 private:
  struct Accum {
    Eigen::Vector3f p = Eigen::Vector3f::Zero(), c = Eigen::Vector3f::Zero();
    int n = 0;
  };
  float inv_voxel_;  // 1 / fine voxel size, 1/m
  std::unordered_map<uint64_t, int> slot_;
  std::vector<Accum> acc_;
};

/// Binary little-endian PLY (x y z float, red green blue uchar; faces as vertex_indices).
/// Throws std::runtime_error naming the file when it cannot be written.
void writePly(const std::string& path, const Mesh& mesh);
void writePly(const std::string& path, const PointCloud& cloud);

}  // namespace radslam
