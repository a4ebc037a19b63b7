// Exports of the field: a coloured triangle mesh (iso-surface of the density) and a coloured
// point cloud (where rendered depth lands), written as binary little-endian PLY.
#pragma once

#include <array>
#include <cstdint>
#include <string>
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
/// colours are the field's view-independent colour.
Mesh extractMesh(const Field& field, float iso = 1.f);

/// Surface points of rendered views: every `stride`-th pixel whose ray is absorbed (weight >=
/// 0.5) gives the point at its rendered depth with its rendered colour; one point per fine
/// voxel is kept (colours averaged).
PointCloud surfacePoints(const Field& field, const std::vector<std::pair<SE3, CameraModel>>& views,
                         const MarchParams& params, int stride = 2);

/// Binary little-endian PLY (x y z float, red green blue uchar; faces as vertex_indices).
/// Throws std::runtime_error naming the file when it cannot be written.
void writePly(const std::string& path, const Mesh& mesh);
void writePly(const std::string& path, const PointCloud& cloud);

}  // namespace radslam
