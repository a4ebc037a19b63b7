#include "mapper/mesh_export.h"

#include <algorithm>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <unordered_map>

namespace radslam {

namespace {

// Cube corner c has offset (c & 1, (c >> 1) & 1, c >> 2). The six tetrahedra of the Kuhn
// split share the diagonal 0-7; every cube uses the same split, so faces match between cubes.
constexpr int kTets[6][4] = {{0, 1, 3, 7}, {0, 1, 5, 7}, {0, 2, 3, 7},
                             {0, 2, 6, 7}, {0, 4, 5, 7}, {0, 4, 6, 7}};

uint64_t latticeKey(int x, int y, int z) {
  const uint64_t m = (uint64_t{1} << 21) - 1;
  return (static_cast<uint64_t>(x) & m) | ((static_cast<uint64_t>(y) & m) << 21) |
         ((static_cast<uint64_t>(z) & m) << 42);
}

struct EdgeKey {
  uint64_t a, b;
  bool operator==(const EdgeKey& o) const { return a == o.a && b == o.b; }
};
struct EdgeHash {
  size_t operator()(const EdgeKey& k) const {
    return k.a * 0x9E3779B97F4A7C15ull ^ (k.b + (k.a << 6));
  }
};

std::array<uint8_t, 3> toRgb8(const Eigen::Vector3f& c) {
  std::array<uint8_t, 3> out;
  for (int k = 0; k < 3; ++k)
    out[k] = static_cast<uint8_t>(std::clamp(std::lround(c[k] * 255.f), 0l, 255l));
  return out;
}

class PlyWriter {
 public:
  PlyWriter(const std::string& path, size_t vertices, size_t faces) : path_(path) {
    out_.open(path, std::ios::binary);
    if (!out_) throw std::runtime_error("PLY " + path + ": cannot open for writing");
    out_ << "ply\nformat binary_little_endian 1.0\ncomment radslam mapper export\n"
         << "element vertex " << vertices << "\n"
         << "property float x\nproperty float y\nproperty float z\n"
         << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    if (faces > 0) out_ << "element face " << faces << "\nproperty list uchar int vertex_indices\n";
    out_ << "end_header\n";
  }
  void vertex(const Eigen::Vector3f& p, const std::array<uint8_t, 3>& c) {
    out_.write(reinterpret_cast<const char*>(p.data()), 3 * sizeof(float));
    out_.write(reinterpret_cast<const char*>(c.data()), 3);
  }
  void face(const Eigen::Vector3i& f) {
    const uint8_t n = 3;
    out_.write(reinterpret_cast<const char*>(&n), 1);
    out_.write(reinterpret_cast<const char*>(f.data()), 3 * sizeof(int32_t));
  }
  void close() {
    out_.flush();
    if (!out_) throw std::runtime_error("PLY " + path_ + ": write failed");
    out_.close();
  }

 private:
  std::string path_;
  std::ofstream out_;
};

void checkLittleEndian() {
  const uint16_t one = 1;
  uint8_t first;
  std::memcpy(&first, &one, 1);
  if (first != 1) throw std::runtime_error("PLY export: big-endian hosts are not supported");
}

}  // namespace

Mesh extractMesh(const Field& field, float iso, int stride, size_t max_faces) {
  Mesh mesh;
  if (!field.initialized() || field.empty()) return mesh;
  if (stride < 1 || Field::kBlockDim % stride != 0)
    throw std::invalid_argument("extractMesh: stride must divide the block size");
  const int fine = field.numLevels() - 1;
  const float s = static_cast<float>(field.voxelSize(fine));
  const int B = Field::kBlockDim / stride;  // cells per block and axis
  const int N = B + 1;                      // lattice points per axis for the block's cells
  std::vector<float> value(N * N * N);
  std::vector<Eigen::Vector3f> color(N * N * N);
  std::unordered_map<EdgeKey, int, EdgeHash> vertex_of_edge;

  for (int b = 0; b < field.numBlocks(fine); ++b) {
    if (mesh.faces.size() > max_faces) {
      mesh.complete = false;
      break;
    }
    const Eigen::Vector3i base = field.blockIndex(fine, b) * Field::kBlockDim;
    // Thickness and colour at the (B+1)^3 lattice points of this block's cells.
    bool any_in = false, any_out = false;
    for (int z = 0; z < N; ++z)
      for (int y = 0; y < N; ++y)
        for (int x = 0; x < N; ++x) {
          const Eigen::Vector3f p = (base + stride * Eigen::Vector3i(x, y, z)).cast<float>() * s;
          const Field::Value v = field.query(p, Eigen::Vector3f::Zero());
          const int i = (z * N + y) * N + x;
          value[i] = v.occupied ? softplus(v.raw_density) : 0.f;
          color[i] = Eigen::Vector3f(v.color[0], v.color[1], v.color[2]);
          (value[i] >= iso ? any_in : any_out) = true;
        }
    if (!any_in || !any_out) continue;
    auto vertexOn = [&](int ia, int ib, const Eigen::Vector3i& la, const Eigen::Vector3i& lb) {
      uint64_t ka = latticeKey(la.x(), la.y(), la.z()), kb = latticeKey(lb.x(), lb.y(), lb.z());
      if (ka > kb) {
        std::swap(ka, kb);
        std::swap(ia, ib);
      }
      const auto it = vertex_of_edge.find({ka, kb});
      if (it != vertex_of_edge.end()) return it->second;
      // Recompute the order-independent interpolation from the sorted ends.
      const Eigen::Vector3i& pa = ka == latticeKey(la.x(), la.y(), la.z()) ? la : lb;
      const Eigen::Vector3i& pb = ka == latticeKey(la.x(), la.y(), la.z()) ? lb : la;
      const float va = value[ia], vb = value[ib];
      const float t = std::clamp((iso - va) / (vb - va), 0.f, 1.f);
      const int id = static_cast<int>(mesh.vertices.size());
      mesh.vertices.push_back((pa.cast<float>() + t * (pb - pa).cast<float>()) * s);
      mesh.colors.push_back(toRgb8(color[ia] + t * (color[ib] - color[ia])));
      vertex_of_edge.emplace(EdgeKey{ka, kb}, id);
      return id;
    };
    for (int z = 0; z < B; ++z)
      for (int y = 0; y < B; ++y)
        for (int x = 0; x < B; ++x) {
          int idx[8];
          bool in[8];
          int count = 0;
          for (int c = 0; c < 8; ++c) {
            idx[c] = ((z + (c >> 2)) * N + (y + ((c >> 1) & 1))) * N + (x + (c & 1));
            in[c] = value[idx[c]] >= iso;
            count += in[c];
          }
          if (count == 0 || count == 8) continue;
          for (const auto& tet : kTets) {
            int inside[4], outside[4], ni = 0, no = 0;
            for (int c : tet) (in[c] ? inside[ni++] : outside[no++]) = c;
            if (ni == 0 || no == 0) continue;
            auto lattice = [&](int c) {
              return Eigen::Vector3i(base.x() + stride * (x + (c & 1)),
                                     base.y() + stride * (y + ((c >> 1) & 1)),
                                     base.z() + stride * (z + (c >> 2)));
            };
            auto edge = [&](int a, int c) {
              return vertexOn(idx[a], idx[c], lattice(a), lattice(c));
            };
            // Out of the dense side: from the inside corners' centroid to the outside ones'.
            Eigen::Vector3f c_in = Eigen::Vector3f::Zero(), c_out = Eigen::Vector3f::Zero();
            for (int k = 0; k < ni; ++k) c_in += lattice(inside[k]).cast<float>() / ni;
            for (int k = 0; k < no; ++k) c_out += lattice(outside[k]).cast<float>() / no;
            const Eigen::Vector3f out_dir = c_out - c_in;
            auto emit = [&](int a, int b2, int c) {
              const Eigen::Vector3f n =
                  (mesh.vertices[b2] - mesh.vertices[a]).cross(mesh.vertices[c] - mesh.vertices[a]);
              if (a == b2 || b2 == c || a == c || n.squaredNorm() == 0.f) return;
              if (n.dot(out_dir) >= 0)
                mesh.faces.emplace_back(a, b2, c);
              else
                mesh.faces.emplace_back(a, c, b2);
            };
            if (ni == 1) {
              emit(edge(inside[0], outside[0]), edge(inside[0], outside[1]),
                   edge(inside[0], outside[2]));
            } else if (no == 1) {
              emit(edge(outside[0], inside[0]), edge(outside[0], inside[1]),
                   edge(outside[0], inside[2]));
            } else {
              const int ac = edge(inside[0], outside[0]), ad = edge(inside[0], outside[1]);
              const int bd = edge(inside[1], outside[1]), bc = edge(inside[1], outside[0]);
              emit(ac, ad, bd);
              emit(ac, bd, bc);
            }
          }
        }
  }
  mesh.stride = stride;
  return mesh;
}

Mesh extractMeshWithin(const Field& field, float iso, size_t max_faces) {
  Mesh mesh;
  for (int stride = 1; stride <= Field::kBlockDim; stride *= 2) {
    mesh = extractMesh(field, iso, stride, max_faces);
    if (mesh.complete) break;
  }
  return mesh;
}

SurfacePointCloud::SurfacePointCloud(const Field& field)
    : inv_voxel_(field.initialized() ? field.invVoxelSize(field.numLevels() - 1) : 0.f) {}

void SurfacePointCloud::add(const SE3& T_world_cam, const CameraModel& cam,
                            const RenderImages& images, int stride) {
  if (!(inv_voxel_ > 0)) return;
  stride = std::max(1, stride);
  for (int v = 0; v < cam.height; v += stride) {
    const float* depth = images.depth.ptr<float>(v);
    const float* weight = images.weight.ptr<float>(v);
    const cv::Vec3f* color = images.color.ptr<cv::Vec3f>(v);
    for (int u = 0; u < cam.width; u += stride) {
      if (weight[u] < 0.5f || !(depth[u] > 0)) continue;
      const Ray ray = makeRay(T_world_cam, Vec3((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1));
      const Eigen::Vector3f p = ray.origin + depth[u] * ray.dir;
      const Eigen::Vector3i cell = (p * inv_voxel_).array().floor().cast<int>();
      auto [it, added] =
          slot_.emplace(latticeKey(cell.x(), cell.y(), cell.z()), static_cast<int>(acc_.size()));
      if (added) acc_.emplace_back();
      Accum& a = acc_[it->second];
      a.p += p;
      a.c += Eigen::Vector3f(color[u][0], color[u][1], color[u][2]);
      ++a.n;
    }
  }
}

PointCloud SurfacePointCloud::points() const {
  PointCloud cloud;
  for (const Accum& a : acc_) {
    cloud.points.push_back(a.p / a.n);
    cloud.colors.push_back(toRgb8(a.c / a.n));
  }
  return cloud;
}

void writePly(const std::string& path, const Mesh& mesh) {
  checkLittleEndian();
  PlyWriter w(path, mesh.vertices.size(), mesh.faces.size());
  for (size_t i = 0; i < mesh.vertices.size(); ++i) w.vertex(mesh.vertices[i], mesh.colors[i]);
  for (const Eigen::Vector3i& f : mesh.faces) w.face(f);
  w.close();
}

void writePly(const std::string& path, const PointCloud& cloud) {
  checkLittleEndian();
  PlyWriter w(path, cloud.points.size(), 0);
  for (size_t i = 0; i < cloud.points.size(); ++i) w.vertex(cloud.points[i], cloud.colors[i]);
  w.close();
}

}  // namespace radslam
