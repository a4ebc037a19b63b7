// Mesh and point-cloud export of a field holding a ball of known radius.
#include "mapper/mesh_export.h"

#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include <gtest/gtest.h>

namespace radslam {
namespace {

const Eigen::Vector3f kCentre(0.1f, 0.2f, 1.0f);
constexpr float kRadius = 0.3f;

// An opaque red ball in an allocated region around it (fine voxel 2 cm).
Field ballField() {
  Field field(FieldGeometry::make(0.02, 2, 4, 0, -4.6f));
  for (float x = -0.45f; x <= 0.45f; x += 0.02f)
    for (float y = -0.45f; y <= 0.45f; y += 0.02f)
      for (float z = -0.45f; z <= 0.45f; z += 0.02f)
        field.allocateAround(kCentre + Eigen::Vector3f(x, y, z));
  const int fine = field.numLevels() - 1;
  for (int b = 0; b < field.numBlocks(fine); ++b) {
    const Eigen::Vector3i base = field.blockIndex(fine, b) * Field::kBlockDim;
    float* data = field.blockData(fine, b);
    for (int v = 0; v < Field::kBlockVoxels; ++v) {
      const Eigen::Vector3f p =
          (base + Eigen::Vector3i(v % 8, (v / 8) % 8, v / 64)).cast<float>() * 0.02f;
      const float d = (p - kCentre).norm() - kRadius;  // signed distance, m
      float* vox = data + v * field.channels();
      vox[0] = std::clamp(-d / 0.02f * 4.f + 4.6f, -10.f, 15.f);  // thickness 1 near d = 0
      vox[1] = 4;
      vox[2] = -4;
      vox[3] = -4;
    }
  }
  return field;
}

// Closed: every undirected edge belongs to exactly two faces, once in each direction.
void expectClosed(const Mesh& mesh) {
  std::map<std::pair<int, int>, int> directed;
  for (const Eigen::Vector3i& f : mesh.faces)
    for (int k = 0; k < 3; ++k) ++directed[{f[k], f[(k + 1) % 3]}];
  for (const auto& [edge, count] : directed) {
    EXPECT_EQ(count, 1);
    EXPECT_EQ(directed.count({edge.second, edge.first}), 1u) << "open edge";
  }
}

TEST(MeshExport, BallIsClosedOrientedAndOnTheSurface) {
  const Field field = ballField();
  const Mesh mesh = extractMesh(field, 1.f);
  ASSERT_GT(mesh.faces.size(), 1000u);
  ASSERT_EQ(mesh.colors.size(), mesh.vertices.size());
  for (const Eigen::Vector3f& v : mesh.vertices) EXPECT_NEAR((v - kCentre).norm(), kRadius, 0.02f);
  for (const auto& c : mesh.colors) {
    EXPECT_GT(c[0], 240);
    EXPECT_LT(c[1], 15);
  }
  expectClosed(mesh);
  // Oriented outwards: the signed volume is the ball's.
  double volume = 0;
  for (const Eigen::Vector3i& f : mesh.faces)
    volume += (mesh.vertices[f[0]] - kCentre)
                  .cast<double>()
                  .dot((mesh.vertices[f[1]] - kCentre)
                           .cast<double>()
                           .cross((mesh.vertices[f[2]] - kCentre).cast<double>())) /
              6;
  EXPECT_NEAR(volume, 4.0 / 3 * M_PI * std::pow(kRadius, 3), 0.05 * volume);
}

TEST(MeshExport, PointsLieOnTheRenderedSurface) {
  const Field field = ballField();
  CameraModel cam;
  cam.width = 40;
  cam.height = 30;
  cam.fx = cam.fy = 40;
  cam.cx = 19.5;
  cam.cy = 14.5;
  const SE3 T_world_cam(SO3(), Vec3(0.1, 0.2, -0.5));  // 1.5 m in front of the centre
  SurfacePointCloud surface(field);
  surface.add(T_world_cam, cam, VolumeRenderer().render(field, T_world_cam, cam, MarchParams()), 1);
  const PointCloud cloud = surface.points();
  ASSERT_GT(cloud.points.size(), 100u);
  for (size_t i = 0; i < cloud.points.size(); ++i) {
    EXPECT_NEAR((cloud.points[i] - kCentre).norm(), kRadius, 0.03f);
    EXPECT_LT(cloud.points[i].z(), kCentre.z());  // the near side only
    EXPECT_GT(cloud.colors[i][0], 200);
  }
}

TEST(MeshExport, FaceBudgetTakesACoarserLattice) {
  const Field field = ballField();
  const Mesh full = extractMesh(field, 1.f);
  EXPECT_TRUE(full.complete);
  EXPECT_FALSE(extractMesh(field, 1.f, 1, full.faces.size() / 2).complete);
  EXPECT_THROW(extractMesh(field, 1.f, 3), std::invalid_argument);
  const Mesh coarse = extractMeshWithin(field, 1.f, full.faces.size() / 2);
  ASSERT_TRUE(coarse.complete);
  EXPECT_EQ(coarse.stride, 2);
  EXPECT_LE(coarse.faces.size(), full.faces.size() / 2);
  EXPECT_GT(coarse.faces.size(), full.faces.size() / 8);
  for (const Eigen::Vector3f& v : coarse.vertices)
    EXPECT_NEAR((v - kCentre).norm(), kRadius, 0.04f);
  expectClosed(coarse);
  EXPECT_EQ(extractMeshWithin(field, 1.f, full.faces.size()).stride, 1);
}

TEST(MeshExport, WritesBinaryPly) {
  const Mesh mesh = extractMesh(ballField(), 1.f);
  const std::string path = ::testing::TempDir() + "/ball.ply";
  writePly(path, mesh);
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t header_end = bytes.find("end_header\n");
  ASSERT_NE(header_end, std::string::npos);
  const std::string header = bytes.substr(0, header_end);
  EXPECT_NE(header.find("format binary_little_endian 1.0"), std::string::npos);
  EXPECT_NE(header.find("element vertex " + std::to_string(mesh.vertices.size())),
            std::string::npos);
  EXPECT_NE(header.find("element face " + std::to_string(mesh.faces.size())), std::string::npos);
  EXPECT_EQ(bytes.size(), header_end + 11 + mesh.vertices.size() * 15 + mesh.faces.size() * 13);
  // The first vertex reads back.
  float xyz[3];
  std::memcpy(xyz, bytes.data() + header_end + 11, sizeof(xyz));
  EXPECT_EQ(xyz[0], mesh.vertices[0].x());
  EXPECT_EQ(xyz[2], mesh.vertices[0].z());
  EXPECT_THROW(writePly("/nonexistent_dir/x.ply", mesh), std::runtime_error);
  // Empty fields export empty meshes.
  EXPECT_TRUE(extractMesh(Field()).faces.empty());
}

}  // namespace
}  // namespace radslam
