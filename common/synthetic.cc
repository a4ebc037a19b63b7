#include "common/synthetic.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <memory>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>

#include "common/parallel.h"
#include "common/synthetic_scene.h"

namespace radslam {
namespace {

constexpr double kNear = 0.05;         // m: surfaces closer than this (along z) are not rendered
constexpr int kTile = 8;               // pixels: screen tiles for box culling
constexpr double kDepthScale = 0.001;  // m per unit in the depth PNGs

/// A box prepared for one render: the camera ray in the box owner's frame (world for static
/// boxes, object frame for moving ones). With pixel (x, y) and d = M (x, y, 1), the ray is
/// origin + t d where t is the depth along the camera's z axis.
struct RayBox {
  const synth::Box* box = nullptr;
  Mat3 M;
  Vec3 origin;
  Mat3 R_world_owner;
  double z_min = 0;                    // m: no point of the box is nearer along the camera's z
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // pixels: screen rectangle [x0, x1) x [y0, y1)
};

struct Hit {
  double t = std::numeric_limits<double>::infinity();
  int box = -1;  // index into the render's boxes; -1 with ground = the ground plane
  int axis = 0;
  bool max_face = false;
  bool ground = false;
};

/// Enters box b along d from o after t > kNear and before hit->t: records the entry face.
inline void intersectBox(const RayBox& b, int index, const Vec3& d, Hit* hit) {
  double t_in = kNear, t_out = hit->t;
  int axis = -1;
  bool max_face = false;
  for (int k = 0; k < 3; ++k) {
    const double o = b.origin[k], lo = b.box->lo[k], hi = b.box->hi[k];
    if (std::abs(d[k]) < 1e-15) {
      if (o < lo || o > hi) return;
      continue;
    }
    const double inv = 1.0 / d[k];
    double t0 = (lo - o) * inv, t1 = (hi - o) * inv;
    const bool enters_at_max = inv < 0;
    if (enters_at_max) std::swap(t0, t1);
    if (t0 > t_in) {
      t_in = t0;
      axis = k;
      max_face = enters_at_max;
    }
    t_out = std::min(t_out, t1);
    if (t_in > t_out) return;
  }
  if (axis < 0) return;  // the camera is inside the box or it lies behind
  *hit = Hit{t_in, index, axis, max_face, false};
}

/// Exit face of a shell seen from inside (the room).
inline void intersectShell(const RayBox& b, int index, const Vec3& d, Hit* hit) {
  double t_exit = std::numeric_limits<double>::infinity();
  int axis = -1;
  bool max_face = false;
  for (int k = 0; k < 3; ++k) {
    if (d[k] > 1e-15) {
      const double t = (b.box->hi[k] - b.origin[k]) / d[k];
      if (t < t_exit) t_exit = t, axis = k, max_face = true;
    } else if (d[k] < -1e-15) {
      const double t = (b.box->lo[k] - b.origin[k]) / d[k];
      if (t < t_exit) t_exit = t, axis = k, max_face = false;
    }
  }
  if (axis >= 0 && t_exit > kNear && t_exit < hit->t)
    *hit = Hit{t_exit, index, axis, max_face, false};
}

/// M (x, y, 1), written out (Eigen's generic product is not inlined here).
inline Vec3 direction(const Mat3& M, double x, double y) {
  return Vec3(M(0, 0) * x + M(0, 1) * y + M(0, 2), M(1, 0) * x + M(1, 1) * y + M(1, 2),
              M(2, 0) * x + M(2, 1) * y + M(2, 2));
}

/// Runs body(row) for every row, rows interleaved over `threads` threads.
template <class Body>
void parallelRows(int rows, int threads, const Body& body) {
  threads = std::max(1, std::min(threads, rows));
  runOnThreads(threads, [&](int k) {
    for (int y = k; y < rows; y += threads) body(y);
  });
}

class Renderer {
 public:
  Renderer(const synth::SceneData& scene, const SE3& T_world_cam, const CameraModel& cam,
           double time_s)
      : scene_(scene), cam_(cam), T_world_cam_(T_world_cam) {
    Kinv_ << 1.0 / cam.fx, 0, -cam.cx / cam.fx, 0, 1.0 / cam.fy, -cam.cy / cam.fy, 0, 0, 1;
    pixel_angle_ = 1.0 / std::sqrt(cam.fx * cam.fy);
    tiles_x_ = (cam.width + kTile - 1) / kTile;
    tiles_y_ = (cam.height + kTile - 1) / kTile;
    M_world_ = T_world_cam.rotation() * Kinv_;
    for (const synth::Box& box : scene.boxes) addBox(box, SE3());
    for (const synth::MovingObject& o : scene.objects) {
      const SE3 T_world_object = synth::objectPose(scene, o, time_s);
      for (const synth::Box& box : o.boxes) addBox(box, T_world_object);
    }
    binBoxes();
  }

  RenderedView render(int threads) const {
    RenderedView view;
    view.color.create(cam_.height, cam_.width, CV_8UC3);
    view.depth.create(cam_.height, cam_.width, CV_32FC1);
    view.instance.create(cam_.height, cam_.width, CV_16UC1);
    view.class_id.create(cam_.height, cam_.width, CV_16UC1);
    parallelRows(cam_.height, threads, [&](int y) {
      auto* color = view.color.ptr<cv::Vec3b>(y);
      auto* depth = view.depth.ptr<float>(y);
      auto* instance = view.instance.ptr<uint16_t>(y);
      auto* class_id = view.class_id.ptr<uint16_t>(y);
      for (int x = 0; x < cam_.width; ++x) {
        Vec3 rgb;
        shadePixel(x, y, &rgb, &depth[x], &instance[x], &class_id[x]);
        for (int c = 0; c < 3; ++c)
          color[x][2 - c] = static_cast<uint8_t>(std::clamp(255.0 * rgb[c] + 0.5, 0.0, 255.0));
      }
    });
    return view;
  }

 private:
  void addBox(const synth::Box& box, const SE3& T_world_owner) {
    const SE3 T_owner_cam = T_world_owner.inverse() * T_world_cam_;
    RayBox rb;
    rb.box = &box;
    rb.M = T_owner_cam.rotation() * Kinv_;
    rb.origin = T_owner_cam.translation();
    rb.R_world_owner = T_world_owner.rotation();
    const int index = static_cast<int>(boxes_.size());
    if (box.inside) {
      boxes_.push_back(rb);
      shells_.push_back(index);
      return;
    }
    // Screen rectangle of the part of the box in front of the near plane: its corners there
    // and the points where its edges cross the plane.
    const SE3 T_cam_owner = T_owner_cam.inverse();
    Vec3 p[8];
    for (int c = 0; c < 8; ++c)
      p[c] =
          T_cam_owner * Vec3((c & 1) ? box.hi.x() : box.lo.x(), (c & 2) ? box.hi.y() : box.lo.y(),
                             (c & 4) ? box.hi.z() : box.lo.z());
    double u0 = 1e300, v0 = 1e300, u1 = -1e300, v1 = -1e300;
    bool visible = false;
    auto extend = [&](const Vec3& q) {
      const double u = cam_.fx * q.x() / q.z() + cam_.cx, v = cam_.fy * q.y() / q.z() + cam_.cy;
      u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
      visible = true;
    };
    for (int c = 0; c < 8; ++c) {
      if (p[c].z() >= kNear) extend(p[c]);
      for (int bit = 1; bit < 8; bit <<= 1) {
        if (c & bit) continue;
        const Vec3 &a = p[c], &b = p[c | bit];
        if ((a.z() >= kNear) != (b.z() >= kNear))
          extend(a + (kNear - a.z()) / (b.z() - a.z()) * (b - a));
      }
    }
    if (!visible) return;
    double z_min = std::numeric_limits<double>::infinity();
    for (const Vec3& q : p) z_min = std::min(z_min, q.z());
    rb.z_min = std::max(z_min, kNear);
    const int x0 = static_cast<int>(std::clamp(std::floor(u0) - 1, 0.0, 1.0 * cam_.width));
    const int y0 = static_cast<int>(std::clamp(std::floor(v0) - 1, 0.0, 1.0 * cam_.height));
    const int x1 = static_cast<int>(std::clamp(std::ceil(u1) + 2, 0.0, 1.0 * cam_.width));
    const int y1 = static_cast<int>(std::clamp(std::ceil(v1) + 2, 0.0, 1.0 * cam_.height));
    if (x0 >= x1 || y0 >= y1) return;
    rb.x0 = x0, rb.y0 = y0, rb.x1 = x1, rb.y1 = y1;
    boxes_.push_back(rb);
  }

  /// Lists the boxes overlapping each screen tile (compressed rows), nearest first: a pixel
  /// stops testing boxes once the next cannot be nearer than its hit.
  void binBoxes() {
    std::vector<int> order;
    for (int i = 0; i < static_cast<int>(boxes_.size()); ++i)
      if (!boxes_[i].box->inside) order.push_back(i);
    std::stable_sort(order.begin(), order.end(),
                     [&](int a, int b) { return boxes_[a].z_min < boxes_[b].z_min; });
    auto forTiles = [&](const RayBox& b, const auto& f) {
      for (int ty = b.y0 / kTile; ty <= (b.y1 - 1) / kTile; ++ty)
        for (int tx = b.x0 / kTile; tx <= (b.x1 - 1) / kTile; ++tx) f(ty * tiles_x_ + tx);
    };
    bin_start_.assign(static_cast<size_t>(tiles_x_) * tiles_y_ + 1, 0);
    for (int i : order) forTiles(boxes_[i], [&](int tile) { ++bin_start_[tile + 1]; });
    for (size_t t = 1; t < bin_start_.size(); ++t) bin_start_[t] += bin_start_[t - 1];
    bin_items_.resize(bin_start_.back());
    std::vector<int> next(bin_start_.begin(), bin_start_.end() - 1);
    for (int i : order) forTiles(boxes_[i], [&](int tile) { bin_items_[next[tile]++] = i; });
  }

  void shadePixel(int x, int y, Vec3* rgb, float* depth, uint16_t* instance,
                  uint16_t* class_id) const {
    Hit hit;
    const Vec3 d_world = direction(M_world_, x, y);
    const Vec3& c = T_world_cam_.translation();
    if (scene_.has_ground && d_world.z() < 0 && c.z() > 0) {
      const double t = -c.z() / d_world.z();
      if (t > kNear) hit = Hit{t, -1, 2, true, true};
    }
    const int tile = (y / kTile) * tiles_x_ + x / kTile;
    for (int k = bin_start_[tile]; k < bin_start_[tile + 1]; ++k) {
      const int index = bin_items_[k];
      const RayBox& b = boxes_[index];
      if (b.z_min >= hit.t) break;
      if (x < b.x0 || x >= b.x1 || y < b.y0 || y >= b.y1) continue;
      intersectBox(b, index, direction(b.M, x, y), &hit);
    }
    for (int index : shells_)
      intersectShell(boxes_[index], index, direction(boxes_[index].M, x, y), &hit);

    const double ray_length_per_t = direction(Kinv_, x, y).norm();
    if (!hit.ground && hit.box < 0) {
      *rgb = scene_.has_sky ? synth::skyColor(d_world, pixel_angle_, scene_.seed) : Vec3::Zero();
      *depth = 0;
      *instance = 0;
      *class_id = 0;
      return;
    }
    Vec3 albedo, normal_world;
    const synth::Face* face;
    const double length = hit.t * ray_length_per_t;  // m along the ray
    if (hit.ground) {
      const Vec3 p = c + hit.t * d_world;
      normal_world = Vec3::UnitZ();
      face = std::abs(p.y()) < scene_.road_half_width ? &scene_.road : &scene_.verge;
      const double fw = footprint(length, normal_world, d_world);
      albedo = synth::materialAlbedo(scene_.materials[face->material], p.x(), p.y(), fw);
    } else {
      const RayBox& b = boxes_[hit.box];
      const Vec3 d = direction(b.M, x, y);
      const Vec3 p = b.origin + hit.t * d;
      Vec3 normal = Vec3::Zero();
      // Outward normal of the entry face, or inward for a shell's exit face.
      normal[hit.axis] = (hit.max_face != b.box->inside) ? 1.0 : -1.0;
      normal_world = b.R_world_owner * normal;
      const int face_index = 2 * hit.axis + (hit.max_face ? 1 : 0);
      face = &b.box->faces[face_index];
      double u, v;
      synth::faceCoordinates(hit.axis, p, &u, &v);
      const double fw = footprint(length, normal, d);
      albedo = synth::materialAlbedo(scene_.materials[face->material], u, v, fw);
      if (b.box->decal >= 0) {
        const synth::Decal& decal = scene_.decals[b.box->decal];
        if (decal.face == face_index && u > decal.u0 - fw && u < decal.u1 + fw &&
            v > decal.v0 - fw && v < decal.v1 + fw) {
          const double cover =
              std::clamp((std::min(u + 0.5 * fw, decal.u1) - std::max(u - 0.5 * fw, decal.u0)) / fw,
                         0.0, 1.0) *
              std::clamp((std::min(v + 0.5 * fw, decal.v1) - std::max(v - 0.5 * fw, decal.v0)) / fw,
                         0.0, 1.0);
          albedo +=
              cover * (synth::materialAlbedo(scene_.materials[decal.material], u, v, fw) - albedo);
        }
      }
    }
    double shade = scene_.ambient;
    for (int k = 0; k < 2; ++k)
      shade += scene_.light_intensity[k] * std::max(0.0, normal_world.dot(scene_.light_dir[k]));
    *rgb = albedo * shade;
    if (scene_.haze_length > 0 && length > scene_.haze_start) {
      const double haze = 1.0 - std::exp(-(length - scene_.haze_start) / scene_.haze_length);
      *rgb += haze * (scene_.sky_haze - *rgb);
    }
    *depth = static_cast<float>(hit.t);
    *instance = face->instance;
    *class_id = face->class_id;
  }

  /// Pixel footprint on the surface (m): the ray's spread, stretched by the obliquity (the
  /// square root: a compromise between blurring across and aliasing along the stretch).
  double footprint(double length, const Vec3& normal, const Vec3& d) const {
    const double cosine = std::abs(normal.dot(d)) / d.norm();
    return length * pixel_angle_ / std::sqrt(std::max(cosine, 0.02));
  }

  const synth::SceneData& scene_;
  CameraModel cam_;
  SE3 T_world_cam_;
  Mat3 Kinv_, M_world_;
  double pixel_angle_ = 0;
  int tiles_x_ = 0, tiles_y_ = 0;
  std::vector<RayBox> boxes_;
  std::vector<int> shells_;
  std::vector<int> bin_start_, bin_items_;  // tile t: bin_items_[bin_start_[t] .. [t + 1])
};

// Counter-based Gaussian noise: the value at (key, index) does not depend on the order in
// which pixels are visited, so noisy frames are identical for any thread count.
uint64_t splitmix(uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

/// Two independent standard normal samples (Box-Muller).
std::pair<double, double> gaussianPair(uint64_t key, uint64_t index) {
  const uint64_t a = splitmix(key + 2 * index), b = splitmix(key + 2 * index + 1);
  const double u1 = (static_cast<double>(a >> 11) + 1.0) * 0x1.0p-53;  // (0, 1]
  const double u2 = static_cast<double>(b >> 11) * 0x1.0p-53;
  const double r = std::sqrt(-2.0 * std::log(u1)), phi = 6.283185307179586 * u2;
  return {r * std::cos(phi), r * std::sin(phi)};
}

uint64_t noiseKey(uint64_t seed, int frame, int stream) {
  return splitmix(splitmix(seed ^ 0x6e6f697365ULL) + static_cast<uint64_t>(frame) * 4 + stream);
}

void addImageNoise(cv::Mat* image, double sigma, uint64_t key, int threads) {
  const int channels = image->channels();
  const int row_values = image->cols * channels;
  parallelRows(image->rows, threads, [&](int y) {
    uint8_t* row = image->ptr<uint8_t>(y);
    const uint64_t base = static_cast<uint64_t>(y) * row_values;
    for (int i = 0; i < row_values; i += 2) {
      const auto [n0, n1] = gaussianPair(key, (base + i) / 2);
      row[i] = static_cast<uint8_t>(std::clamp(row[i] + sigma * n0 + 0.5, 0.0, 255.0));
      if (i + 1 < row_values)
        row[i + 1] = static_cast<uint8_t>(std::clamp(row[i + 1] + sigma * n1 + 0.5, 0.0, 255.0));
    }
  });
}

void addDepthNoise(cv::Mat* depth, double rel, uint64_t key, int threads) {
  parallelRows(depth->rows, threads, [&](int y) {
    float* row = depth->ptr<float>(y);
    for (int x = 0; x < depth->cols; ++x) {
      const double z = row[x];
      if (z <= 0) continue;
      const double n = gaussianPair(key, static_cast<uint64_t>(y) * depth->cols + x).first;
      row[x] = static_cast<float>(std::max(0.0, z + rel * z * z * n));
    }
  });
}

void validate(const SyntheticConfig& c) {
  const auto& names = SyntheticScene::sceneNames();
  if (std::find(names.begin(), names.end(), c.scene) == names.end())
    throw std::invalid_argument("synthetic: unknown scene '" + c.scene +
                                "' (room, street, car, door, multi, large)");
  auto require = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument("synthetic: " + what);
  };
  require(c.frames >= 1, "frames must be >= 1, got " + std::to_string(c.frames));
  require(c.width >= 8 && c.height >= 8 && c.width <= 16384 && c.height <= 16384,
          "image size must be within 8..16384 pixels, got " + std::to_string(c.width) + "x" +
              std::to_string(c.height));
  require(c.baseline_m > 0 && c.baseline_m < 10, "baseline_m must be in (0, 10) m");
  require(c.image_noise_sigma >= 0 && c.image_noise_sigma < 100,
          "image_noise_sigma must be in [0, 100) grey levels");
  require(c.depth_noise_rel >= 0 && c.depth_noise_rel < 1, "depth_noise_rel must be in [0, 1)");
  require(c.threads >= 1 && c.threads <= 256, "threads must be in 1..256");
  require(c.fps == 0 || (c.fps >= 1 && c.fps <= 1000), "fps must be 0 (the scene's) or 1..1000");
  require(c.readout_s >= 0 && c.readout_s < 1, "readout_s must be in [0, 1) s");
}

}  // namespace

SyntheticScene SyntheticScene::make(const SyntheticConfig& config) {
  validate(config);
  SyntheticScene s;
  s.config_ = config;
  s.scene_ = std::make_shared<const synth::SceneData>(
      synth::buildScene(config.scene, config.seed, config.frames, config.fps));
  return s;
}

const std::vector<std::string>& SyntheticScene::sceneNames() {
  static const std::vector<std::string> names = {"room", "street", "car", "door", "multi", "large"};
  return names;
}

double SyntheticScene::fps() const { return scene_->fps; }

double SyntheticScene::timestamp(int frame) const { return frame / scene_->fps; }

CameraModel SyntheticScene::camera() const {
  CameraModel cam;
  cam.width = config_.width;
  cam.height = config_.height;
  cam.fx = cam.fy = 0.8 * config_.width;
  cam.cx = 0.5 * (config_.width - 1);
  cam.cy = 0.5 * (config_.height - 1);
  cam.readout_s = config_.readout_s;
  return cam;
}

SE3 SyntheticScene::cameraPose(int frame) const {
  return synth::cameraPose(*scene_, timestamp(frame));
}

double SyntheticScene::objectTime(int frame) const {
  // Frozen at the last frame's pose: objects that drive ahead of the camera stay ahead of it
  // for the whole sequence (frozen at the first pose, the camera would drive into them).
  return config_.freeze_objects ? timestamp(std::max(config_.frames - 1, 0)) : timestamp(frame);
}

SE3 SyntheticScene::rightCameraPose(int frame) const { return cameraPose(frame) * leftToRight(); }

std::vector<ObjectPoseSample> SyntheticScene::objectPoses(int frame) const {
  std::vector<ObjectPoseSample> poses;
  const double t = timestamp(frame);
  const double t_objects = objectTime(frame);
  for (const synth::MovingObject& o : scene_->objects)
    poses.push_back(
        ObjectPoseSample{t, o.object_id, o.class_id, synth::objectPose(*scene_, o, t_objects)});
  return poses;
}

std::vector<SyntheticObject> SyntheticScene::objects() const {
  std::vector<SyntheticObject> out;
  for (const synth::MovingObject& o : scene_->objects)
    out.push_back(SyntheticObject{o.object_id, o.class_id, o.name, o.joint, o.T_world_joint});
  return out;
}

std::vector<SemanticClass> SyntheticScene::classes() const { return scene_->classes; }

RenderedView SyntheticScene::render(const SE3& T_world_cam, const CameraModel& camera,
                                    int frame) const {
  bool distorted = false;
  for (double k : camera.distortion) distorted |= k != 0;
  if (camera.type != CameraModel::Type::kPinhole || distorted)
    throw std::invalid_argument("SyntheticScene::render: only undistorted pinhole cameras");
  if (camera.width <= 0 || camera.height <= 0 || !(camera.fx > 0) || !(camera.fy > 0))
    throw std::invalid_argument("SyntheticScene::render: bad camera " +
                                std::to_string(camera.width) + "x" + std::to_string(camera.height) +
                                " fx " + std::to_string(camera.fx));
  const double t_objects = objectTime(frame);
  return Renderer(*scene_, T_world_cam, camera, t_objects).render(config_.threads);
}

RenderedView SyntheticScene::renderFrame(int frame, const SE3& T_cam_sensor) const {
  if (config_.readout_s <= 0) return render(cameraPose(frame) * T_cam_sensor, camera(), frame);
  // Each row on its own: a one-row camera whose principal point puts the row at y = 0, posed
  // (with the objects) at the row's exposure time.
  const CameraModel cam = camera();
  RenderedView view;
  view.color.create(cam.height, cam.width, CV_8UC3);
  view.depth.create(cam.height, cam.width, CV_32FC1);
  view.instance.create(cam.height, cam.width, CV_16UC1);
  view.class_id.create(cam.height, cam.width, CV_16UC1);
  parallelRows(cam.height, config_.threads, [&](int y) {
    const double dt =
        (static_cast<double>(y) / std::max(1, cam.height - 1) - 0.5) * config_.readout_s;
    const double t = timestamp(frame) + dt;
    const double t_objects = config_.freeze_objects ? objectTime(frame) : t;
    CameraModel row = cam;
    row.height = 1;
    row.cy = cam.cy - y;
    const RenderedView line =
        Renderer(*scene_, synth::cameraPose(*scene_, t) * T_cam_sensor, row, t_objects).render(1);
    line.color.copyTo(view.color.row(y));
    line.depth.copyTo(view.depth.row(y));
    line.instance.copyTo(view.instance.row(y));
    line.class_id.copyTo(view.class_id.row(y));
  });
  return view;
}

Frame SyntheticScene::frame(int i) const {
  RenderedView left = renderFrame(i, SE3());
  Frame f;
  f.header.utime = std::llround(timestamp(i) * 1e6);
  f.header.seq = i;
  f.header.sender = "synthetic";
  f.frame_index = i;
  f.camera = camera();
  f.color = left.color;
  f.depth = left.depth;
  f.instance = left.instance;
  f.class_id = left.class_id;
  if (config_.stereo) {
    f.right = renderFrame(i, leftToRight()).color;
    f.baseline_m = config_.baseline_m;
  }
  if (config_.image_noise_sigma > 0) {
    addImageNoise(&f.color, config_.image_noise_sigma, noiseKey(config_.seed, i, 0),
                  config_.threads);
    if (!f.right.empty())
      addImageNoise(&f.right, config_.image_noise_sigma, noiseKey(config_.seed, i, 1),
                    config_.threads);
  }
  if (config_.depth_noise_rel > 0)
    addDepthNoise(&f.depth, config_.depth_noise_rel, noiseKey(config_.seed, i, 2), config_.threads);
  return f;
}

// ---------------------------------------------------------------------------------------------
// Dataset writer.

namespace {

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

File openText(const std::string& path) {
  File f(std::fopen(path.c_str(), "w"));
  if (!f) throw std::runtime_error("synthetic dataset: cannot write " + path);
  return f;
}

void closeText(File f, const std::string& path) {
  const bool failed = std::ferror(f.get()) != 0;
  if (std::fclose(f.release()) != 0 || failed)
    throw std::runtime_error("synthetic dataset: error writing " + path);
}

/// "tx ty tz qx qy qz qw" with qw >= 0.
void printPose(std::FILE* f, const SE3& T) {
  Eigen::Quaterniond q = T.quaternion();
  if (q.w() < 0) q.coeffs() *= -1;
  const Vec3& t = T.translation();
  std::fprintf(f, "%.9f %.9f %.9f %.9f %.9f %.9f %.9f", t.x(), t.y(), t.z(), q.x(), q.y(), q.z(),
               q.w());
}

void writePng(const std::string& path, const cv::Mat& image) {
  bool ok = false;
  try {
    // OpenCV's default PNG settings (SUB filter, level 1, RLE) are its fastest.
    ok = cv::imwrite(path, image);
  } catch (const cv::Exception& e) {
    throw std::runtime_error("synthetic dataset: cannot write " + path + ": " + e.what());
  }
  if (!ok) throw std::runtime_error("synthetic dataset: cannot write " + path);
}

cv::FileStorage openYamlForWriting(const std::string& path) {
  cv::FileStorage fs;
  try {
    fs.open(path, cv::FileStorage::WRITE | cv::FileStorage::FORMAT_YAML);
  } catch (const cv::Exception&) {
  }
  if (!fs.isOpened()) throw std::runtime_error("synthetic dataset: cannot write " + path);
  return fs;
}

/// Depth in metres to uint16 units of kDepthScale; 0 (invalid) where out of range.
cv::Mat depthToUint16(const cv::Mat& depth) {
  cv::Mat out(depth.size(), CV_16UC1);
  for (int y = 0; y < depth.rows; ++y) {
    const float* in = depth.ptr<float>(y);
    uint16_t* row = out.ptr<uint16_t>(y);
    for (int x = 0; x < depth.cols; ++x) {
      const double units = std::round(in[x] / kDepthScale);
      row[x] = (units > 0 && units <= 65535) ? static_cast<uint16_t>(units) : 0;
    }
  }
  return out;
}

}  // namespace

void generateSyntheticDataset(const SyntheticConfig& config, const std::string& out_dir,
                              const std::function<void(int, int)>& progress) {
  const SyntheticScene scene = SyntheticScene::make(config);
  namespace fs = std::filesystem;
  std::vector<std::string> folders = {"rgb", "depth", "instance", "class"};
  if (config.stereo) folders.push_back("right");
  for (const std::string& sub : folders) {
    const fs::path dir = fs::path(out_dir) / sub;
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec || !fs::is_directory(dir))
      throw std::runtime_error("synthetic dataset: cannot create folder " + dir.string() +
                               (ec ? ": " + ec.message() : ""));
  }
  auto path = [&](const std::string& name) { return (fs::path(out_dir) / name).string(); };

  const CameraModel cam = scene.camera();
  {
    cv::FileStorage fs = openYamlForWriting(path("camera.yaml"));
    fs << "width" << cam.width << "height" << cam.height << "fx" << cam.fx << "fy" << cam.fy << "cx"
       << cam.cx << "cy" << cam.cy << "baseline_m" << (config.stereo ? config.baseline_m : 0.0)
       << "depth_scale" << kDepthScale;
    if (cam.readout_s > 0) fs << "readout_s" << cam.readout_s;
  }
  {
    cv::FileStorage fs = openYamlForWriting(path("classes.yaml"));
    fs << "classes"
       << "[";
    for (const SemanticClass& c : scene.classes())
      fs << "{"
         << "id" << c.id << "name" << c.name << "dynamic" << (c.dynamic ? 1 : 0) << "joint"
         << jointTypeName(c.joint) << "parent" << c.parent << "}";
    fs << "]";
  }
  {
    cv::FileStorage fs = openYamlForWriting(path("generator.yaml"));
    fs << "generator"
       << "radslam-synth"
       << "scene" << config.scene << "frames" << config.frames << "seed"
       << std::to_string(config.seed) << "fps" << scene.fps() << "image_noise_sigma"
       << config.image_noise_sigma << "depth_noise_rel" << config.depth_noise_rel
       << "freeze_objects" << static_cast<int>(config.freeze_objects) << "readout_s"
       << config.readout_s;
  }

  File times = openText(path("times.txt"));
  File groundtruth = openText(path("groundtruth.txt"));
  File objects = openText(path("objects.txt"));
  std::fprintf(groundtruth.get(), "# timestamp tx ty tz qx qy qz qw (T_world_cam)\n");
  char name[32];
  for (int i = 0; i < config.frames; ++i) {
    const Frame f = scene.frame(i);
    std::snprintf(name, sizeof(name), "%06d.png", i);
    writePng(path("rgb/") + name, f.color);
    if (config.stereo) writePng(path("right/") + name, f.right);
    writePng(path("depth/") + name, depthToUint16(f.depth));
    writePng(path("instance/") + name, f.instance);
    writePng(path("class/") + name, f.class_id);
    const double t = scene.timestamp(i);
    std::fprintf(times.get(), "%.9f\n", t);
    std::fprintf(groundtruth.get(), "%.9f ", t);
    printPose(groundtruth.get(), scene.cameraPose(i));
    std::fprintf(groundtruth.get(), "\n");
    for (const ObjectPoseSample& o : scene.objectPoses(i)) {
      std::fprintf(objects.get(), "%.9f %d %d ", t, o.object_id, o.class_id);
      printPose(objects.get(), o.T_world_object);
      std::fprintf(objects.get(), "\n");
    }
    if (progress) progress(i + 1, config.frames);
  }
  closeText(std::move(times), path("times.txt"));
  closeText(std::move(groundtruth), path("groundtruth.txt"));
  closeText(std::move(objects), path("objects.txt"));
}

}  // namespace radslam
