#include "common/synthetic_scene.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace radslam::synth {
namespace {

constexpr double kTwoPi = 6.283185307179586;
inline double clamp01(double x) { return x < 0 ? 0 : (x > 1 ? 1 : x); }

}  // namespace

// ---------------------------------------------------------------------------------------------
// Scene construction.

namespace {

/// splitmix64: a tiny portable generator, so a seed gives the same scene on every platform.
class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed) {}
  uint64_t next() {
    uint64_t z = (state_ += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
  }
  double uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }
  double uniform(double a, double b) { return a + (b - a) * uniform(); }

 private:
  uint64_t state_;
};

// Static instance ids: one per surface group; moving objects use their object id (>= 100).
enum : uint16_t { kInstGround = 1, kInstWall = 2, kInstCeiling = 3, kInstFurniture = 4 };
enum : uint16_t { kInstRoad = 1, kInstSidewalk = 2, kInstBuilding = 3, kInstPole = 4 };
enum : uint16_t { kClassGround = 1, kClassWall = 2, kClassStuff = 3, kClassPole = 4 };
enum : uint16_t { kClassCar = 10, kClassDoor = 11, kClassTruck = 12 };

class Builder {
 public:
  Builder(SceneData* scene, uint64_t seed) : s_(scene), rng_(seed) {}

  Rng& rng() { return rng_; }

  /// A new material; colours jittered by a few percent so every surface is distinct.
  int16_t material(MaterialKind kind, const Vec3& a, const Vec3& b, double scale = 1,
                   bool windows = false) {
    Material m;
    m.kind = kind;
    m.color_a = jitter(a);
    m.color_b = jitter(b);
    m.scale = scale;
    m.seed = static_cast<uint32_t>(rng_.next());
    m.windows = windows;
    s_->materials.push_back(m);
    return static_cast<int16_t>(s_->materials.size() - 1);
  }

  static Box box(const Vec3& lo, const Vec3& hi, int16_t material, uint16_t instance,
                 uint16_t class_id) {
    Box b;
    b.lo = lo;
    b.hi = hi;
    for (Face& f : b.faces) f = Face{material, instance, class_id};
    return b;
  }

  void add(const Box& b) { s_->boxes.push_back(b); }

  int decal(int face, double u0, double u1, double v0, double v1, int16_t material) {
    s_->decals.push_back(Decal{face, u0, u1, v0, v1, material});
    return static_cast<int>(s_->decals.size() - 1);
  }

 private:
  Vec3 jitter(const Vec3& c) {
    Vec3 out;
    for (int i = 0; i < 3; ++i) out[i] = clamp01(c[i] * rng_.uniform(0.92, 1.08));
    return out;
  }

  SceneData* s_;
  Rng rng_;
};

void setAxis(Box* b, int axis, int16_t material) {
  b->faces[2 * axis].material = material;
  b->faces[2 * axis + 1].material = material;
}

SemanticClass semanticClass(int id, const std::string& name, bool dynamic = false,
                            JointType joint = JointType::kFree, const std::string& parent = "") {
  return SemanticClass{id, name, dynamic, joint, parent};
}

SE3 yawPose(double yaw, const Vec3& t) { return SE3(SO3::exp(Vec3(0, 0, yaw)), t); }

/// An 8 x 6 x 2.8 m room with floor, papered walls, tiled ceiling and furniture by the walls,
/// leaving the middle (|x| < 1.8, |y| < 1.6) free for the camera.
void buildRoom(Builder* b, SceneData* s) {
  using MK = MaterialKind;
  s->fps = 30;
  s->light_dir[0] = Vec3(0.35, 0.25, 1.0).normalized();
  s->light_dir[1] = Vec3(-0.6, -0.45, 0.35).normalized();
  s->light_intensity[0] = 0.5;
  s->light_intensity[1] = 0.3;
  s->ambient = 0.4;

  Box shell = Builder::box(Vec3(-4, -3, 0), Vec3(4, 3, 2.8), 0, kInstWall, kClassWall);
  shell.inside = true;
  const Vec3 papers[4][2] = {{{0.75, 0.7, 0.55}, {0.55, 0.45, 0.35}},
                             {{0.6, 0.7, 0.75}, {0.35, 0.45, 0.6}},
                             {{0.8, 0.75, 0.7}, {0.6, 0.35, 0.3}},
                             {{0.65, 0.75, 0.6}, {0.4, 0.5, 0.35}}};
  for (int f = 0; f < 4; ++f)
    shell.faces[f].material = b->material(MK::kWallpaper, papers[f][0], papers[f][1]);
  shell.faces[4] = Face{b->material(MK::kPlanks, {0.55, 0.36, 0.2}, {0.3, 0.18, 0.09}, 1.8),
                        kInstGround, kClassGround};
  shell.faces[5] = Face{b->material(MK::kTiles, {0.85, 0.85, 0.8}, {0.7, 0.72, 0.7}, 0.6),
                        kInstCeiling, kClassWall};
  b->add(shell);

  uint16_t inst = kInstFurniture;
  const int16_t oak = b->material(MK::kWood, {0.6, 0.42, 0.25}, {0.35, 0.22, 0.1});
  const int16_t walnut = b->material(MK::kWood, {0.42, 0.28, 0.18}, {0.2, 0.12, 0.07});
  // Bookshelf against the y = +3 wall.
  Box shelf = Builder::box({-1.6, 2.62, 0}, {0.4, 3.0, 2.0}, walnut, inst++, kClassStuff);
  shelf.faces[2].material = b->material(MK::kBooks, {0.42, 0.28, 0.18}, {0.2, 0.12, 0.07});
  b->add(shelf);
  // Table with four legs (one instance).
  const uint16_t table = inst++;
  b->add(Builder::box({2.3, 1.3, 0.72}, {3.5, 2.5, 0.77}, oak, table, kClassStuff));
  for (double x : {2.35, 3.39})
    for (double y : {1.35, 2.39})
      b->add(Builder::box({x, y, 0}, {x + 0.06, y + 0.06, 0.72}, oak, table, kClassStuff));
  // Cabinet with panelled doors against the x = -4 wall.
  Box cabinet = Builder::box({-3.95, -2.2, 0}, {-3.45, -0.6, 1.1}, oak, inst++, kClassStuff);
  cabinet.faces[1].material = b->material(MK::kDoor, {0.55, 0.4, 0.25}, {0.32, 0.2, 0.1}, 0.4);
  b->add(cabinet);
  // Sofa against the y = -3 wall.
  const uint16_t sofa = inst++;
  const int16_t cloth = b->material(MK::kFabric, {0.55, 0.15, 0.12}, {0.25, 0.08, 0.1}, 0.12);
  b->add(Builder::box({-2.6, -2.95, 0}, {-0.8, -2.2, 0.45}, cloth, sofa, kClassStuff));
  b->add(Builder::box({-2.6, -2.95, 0.45}, {-0.8, -2.75, 0.95}, cloth, sofa, kClassStuff));
  for (double x : {-2.6, -1.0})
    b->add(Builder::box({x, -2.75, 0.45}, {x + 0.2, -2.2, 0.65}, cloth, sofa, kClassStuff));
  // Cardboard boxes, stacked.
  const int16_t card = b->material(MK::kFabric, {0.62, 0.48, 0.3}, {0.5, 0.38, 0.22}, 0.05);
  b->add(Builder::box({1.5, -2.95, 0}, {2.1, -2.4, 0.5}, card, inst++, kClassStuff));
  b->add(Builder::box({1.6, -2.9, 0.5}, {2.0, -2.5, 0.8}, card, inst++, kClassStuff));
  // Floor lamp.
  const uint16_t lamp = inst++;
  b->add(Builder::box({3.5, -2.7, 0}, {3.56, -2.64, 1.5},
                      b->material(MK::kMetal, {0.6, 0.6, 0.62}, {0.3, 0.3, 0.3}, 0.5), lamp,
                      kClassStuff));
  b->add(Builder::box({3.35, -2.85, 1.5}, {3.71, -2.49, 1.8},
                      b->material(MK::kFabric, {0.9, 0.85, 0.6}, {0.8, 0.7, 0.45}, 0.03), lamp,
                      kClassStuff));
  // Rug in the middle.
  b->add(Builder::box({-1.3, -1.5, 0}, {1.1, 0.6, 0.01},
                      b->material(MK::kFabric, {0.2, 0.3, 0.55}, {0.7, 0.6, 0.4}, 0.2), inst++,
                      kClassStuff));
  s->classes = {semanticClass(kClassGround, "floor"), semanticClass(kClassWall, "wall"),
                semanticClass(kClassStuff, "furniture")};
}

/// Adds a door panel turning about a vertical hinge at `hinge` (world), lying along
/// `along` (+/-x or +/-y of the world) when closed, opening towards `open_side`.
void addDoor(Builder* b, SceneData* s, int32_t id, const SE3& T_world_joint, double width,
             double height, double z0, double max_angle, double period, int16_t material,
             const std::string& parent) {
  MovingObject o;
  o.object_id = id;
  o.class_id = kClassDoor;
  o.name = "door";
  o.joint = JointType::kRevolute;
  o.T_world_joint = T_world_joint;
  o.boxes.push_back(Builder::box({0, 0, z0}, {width, 0.045, z0 + height}, material,
                                 static_cast<uint16_t>(id), kClassDoor));
  o.motion = MotionKind::kHingeSwing;
  o.p[0] = max_angle;
  o.p[1] = period;
  o.p[2] = b->rng().uniform(0, kTwoPi);
  s->objects.push_back(o);
  s->classes.push_back(semanticClass(kClassDoor, "door", true, JointType::kRevolute, parent));
}

/// Street along +x: road |y| < 4 with markings, sidewalks to |y| = 9.5, building rows from
/// |y| = 7 (plus a setback), a second row of tall buildings behind, lamp posts. `length` is
/// how far the camera drives (m).
void buildStreet(Builder* b, SceneData* s, double length) {
  using MK = MaterialKind;
  Rng& rng = b->rng();
  s->fps = 10;
  s->has_ground = true;
  s->has_sky = true;
  s->haze_start = 60;
  s->haze_length = 500;
  s->light_dir[0] = Vec3(-0.45, 0.55, 0.7).normalized();
  s->light_dir[1] = Vec3(0, 0, 1);
  s->light_intensity[0] = 0.65;
  s->light_intensity[1] = 0.15;
  s->ambient = 0.35;
  s->road = Face{b->material(MK::kAsphalt, {0.3, 0.3, 0.31}, {0.86, 0.86, 0.82}, 4.0), kInstRoad,
                 kClassGround};
  s->verge = Face{b->material(MK::kGround, {0.3, 0.36, 0.18}, {0.42, 0.36, 0.25}), kInstRoad,
                  kClassGround};
  const double x0 = -60, x1 = length + 250;
  for (int side : {1, -1}) {
    Box walk = Builder::box({x0, side > 0 ? 4.0 : -9.5, 0}, {x1, side > 0 ? 9.5 : -4.0, 0.15},
                            b->material(MK::kTiles, {0.6, 0.58, 0.55}, {0.45, 0.42, 0.4}, 1.0),
                            kInstSidewalk, kClassStuff);
    walk.faces[5].material =
        b->material(MK::kTiles, side > 0 ? Vec3(0.62, 0.55, 0.5) : Vec3(0.55, 0.56, 0.6),
                    {0.4, 0.38, 0.36}, side > 0 ? 0.5 : 0.4);
    b->add(walk);
    // Front row: contiguous buildings with the odd alley.
    const Vec3 bricks[3] = {{0.55, 0.25, 0.18}, {0.6, 0.42, 0.3}, {0.45, 0.3, 0.28}};
    const Vec3 plasters[4] = {
        {0.85, 0.8, 0.65}, {0.7, 0.75, 0.8}, {0.85, 0.7, 0.6}, {0.75, 0.78, 0.7}};
    for (double x = x0; x < x1;) {
      const double w = rng.uniform(8, 22), setback = rng.uniform() < 0.4 ? rng.uniform(0, 1.5) : 0;
      const double h = rng.uniform(6, 22), y_front = 7 + setback;
      int16_t facade;
      if (rng.uniform() < 0.5) {
        const Vec3 c = bricks[static_cast<int>(rng.uniform(0, 3))];
        facade = b->material(MK::kBricks, c, 0.7 * c, 1, true);
      } else {
        const Vec3 c = plasters[static_cast<int>(rng.uniform(0, 4))];
        facade = b->material(MK::kPlaster, c, 0.85 * c, 1, true);
      }
      Box house = Builder::box({x, side > 0 ? y_front : -y_front - 12, 0},
                               {x + w, side > 0 ? y_front + 12 : -y_front, h}, facade,
                               kInstBuilding, kClassWall);
      setAxis(&house, 2, b->material(MK::kGround, {0.35, 0.33, 0.32}, {0.5, 0.45, 0.42}));
      b->add(house);
      x += w + (rng.uniform() < 0.2 ? rng.uniform(2, 5) : 0);
    }
    // Back row, seen through alleys and above low houses.
    for (double x = x0 - 40; x < x1 + 40;) {
      const double w = rng.uniform(15, 35), h = rng.uniform(14, 32), y = rng.uniform(28, 34);
      Box tower =
          Builder::box({x, side > 0 ? y : -y - 14, 0}, {x + w, side > 0 ? y + 14 : -y, h},
                       b->material(MK::kPlaster, plasters[static_cast<int>(rng.uniform(0, 4))],
                                   {0.5, 0.5, 0.5}, 1, true),
                       kInstBuilding, kClassWall);
      b->add(tower);
      x += w + rng.uniform(0, 6);
    }
    // Lamp posts with an arm over the road.
    const int16_t steel = b->material(MK::kMetal, {0.45, 0.47, 0.5}, {0.2, 0.2, 0.22}, 1.2);
    for (double x = x0 + rng.uniform(0, 20); x < x1; x += 28) {
      const double y = side * 4.6;
      b->add(Builder::box({x - 0.08, y - 0.08, 0}, {x + 0.08, y + 0.08, 5.6}, steel, kInstPole,
                          kClassPole));
      b->add(Builder::box({x - 0.05, std::min(y, side * 3.2), 5.45},
                          {x + 0.05, std::max(y, side * 3.2), 5.6}, steel, kInstPole, kClassPole));
    }
  }
  s->classes = {semanticClass(kClassGround, "road"), semanticClass(kClassWall, "building"),
                semanticClass(kClassStuff, "sidewalk"), semanticClass(kClassPole, "pole")};
}

void addCar(Builder* b, SceneData* s, int32_t id, const Vec3& color, const double p[8]) {
  using MK = MaterialKind;
  MovingObject o;
  o.object_id = id;
  o.class_id = kClassCar;
  o.name = "car";
  o.joint = JointType::kPlanar;  // on the road plane z = 0: joint frame = world
  const uint16_t inst = static_cast<uint16_t>(id);
  const int16_t body = b->material(MK::kPaint, color, {0.9, 0.9, 0.85});
  const int16_t roof = b->material(MK::kMetal, color, 0.6 * color, 0.7);
  const int16_t windows = b->material(MK::kGlass, 0.8 * color, color, 0.9);
  const int16_t tyre = b->material(MK::kRubber, {0.06, 0.06, 0.06}, {0.1, 0.1, 0.1});
  Box hull = Builder::box({-2.15, -0.88, 0.32}, {2.15, 0.88, 1.05}, body, inst, kClassCar);
  setAxis(&hull, 2, roof);
  o.boxes.push_back(hull);
  Box cabin = Builder::box({-1.2, -0.78, 1.05}, {0.85, 0.78, 1.5}, windows, inst, kClassCar);
  setAxis(&cabin, 2, roof);
  o.boxes.push_back(cabin);
  for (double x : {-1.35, 1.35})
    for (double y : {-0.92, 0.72})
      o.boxes.push_back(
          Builder::box({x - 0.33, y, 0}, {x + 0.33, y + 0.2, 0.66}, tyre, inst, kClassCar));
  o.motion = MotionKind::kFollow;
  std::copy(p, p + 8, o.p);
  s->objects.push_back(o);
}

void addTruck(Builder* b, SceneData* s, int32_t id, const double p[8]) {
  using MK = MaterialKind;
  MovingObject o;
  o.object_id = id;
  o.class_id = kClassTruck;
  o.name = "truck";
  o.joint = JointType::kPlanar;
  const uint16_t inst = static_cast<uint16_t>(id);
  const int16_t art = b->material(MK::kGraffiti, {0.5, 0.5, 0.5}, {0.2, 0.2, 0.2});
  const int16_t steel = b->material(MK::kMetal, {0.55, 0.56, 0.58}, {0.3, 0.3, 0.3}, 1.0);
  const int16_t cab = b->material(MK::kPaint, {0.15, 0.3, 0.6}, {0.9, 0.8, 0.2});
  const int16_t tyre = b->material(MK::kRubber, {0.06, 0.06, 0.06}, {0.1, 0.1, 0.1});
  // Origin on the road under the middle of the rear bumper; the rear faces the camera.
  Box cargo = Builder::box({0, -1.25, 0.9}, {6.5, 1.25, 3.9}, art, inst, kClassTruck);
  setAxis(&cargo, 2, steel);
  o.boxes.push_back(cargo);
  o.boxes.push_back(Builder::box({6.7, -1.2, 0.6}, {8.5, 1.2, 3.0}, cab, inst, kClassTruck));
  o.boxes.push_back(Builder::box({0.2, -1.0, 0.5}, {8.3, 1.0, 0.9}, steel, inst, kClassTruck));
  o.boxes.push_back(Builder::box({-0.1, -1.2, 0.45}, {0.1, 1.2, 0.65}, steel, inst, kClassTruck));
  for (double x : {1.0, 6.8})
    for (double y : {-1.25, 0.95})
      o.boxes.push_back(Builder::box({x, y, 0}, {x + 1.1, y + 0.3, 1.0}, tyre, inst, kClassTruck));
  o.motion = MotionKind::kFollow;
  std::copy(p, p + 8, o.p);
  s->objects.push_back(o);
}

double streetX(const CameraPath& path, double t) {
  return path.speed * t + 1.5 * std::sin(0.2 * t + path.phase[0]);
}

/// Camera orientation from yaw (about world z), pitch (nose up) and roll, for a camera whose
/// optical axis lies along the body's x (forward) axis.
Eigen::Quaterniond cameraRotation(double yaw, double pitch, double roll) {
  // Columns: the camera's x (right), y (down), z (forward) axes in the body frame.
  Mat3 R_body_cam;
  R_body_cam << 0, 0, 1, -1, 0, 0, 0, -1, 0;
  return Eigen::AngleAxisd(yaw, Vec3::UnitZ()) * Eigen::AngleAxisd(-pitch, Vec3::UnitY()) *
         Eigen::AngleAxisd(roll, Vec3::UnitX()) * Eigen::Quaterniond(R_body_cam);
}

}  // namespace

SceneData buildScene(const std::string& name, uint64_t seed, int frames, double fps) {
  SceneData s;
  s.name = name;
  s.seed = static_cast<uint32_t>(seed ^ (seed >> 32));
  Builder b(&s, seed * 0x9e3779b97f4a7c15ULL + 0x1234567ULL);
  for (double& phase : s.path.phase) phase = b.rng().uniform(0, kTwoPi);
  if (name == "room" || name == "door") {
    s.path.kind = name == "room" ? CameraPathKind::kRoomOrbit : CameraPathKind::kRoomFacing;
    buildRoom(&b, &s);
    if (name == "door") {
      // Hinge at (4, -0.2) on the x = +4 wall: the closed panel lies along +y and opens into
      // the room. A dark doorway behind it, and a frame on the latch side and the top.
      const int16_t dark =
          b.material(MaterialKind::kDoorway, {0.05, 0.045, 0.04}, {0.05, 0.04, 0.03});
      s.boxes[0].decal = b.decal(1, -0.2, 0.7, 0.0, 2.05, dark);
      const int16_t trim = b.material(MaterialKind::kWood, {0.85, 0.83, 0.78}, {0.7, 0.68, 0.62});
      b.add(Builder::box({3.975, 0.7, 0}, {4.0, 0.78, 2.13}, trim, kInstWall, kClassWall));
      b.add(Builder::box({3.975, -0.28, 2.05}, {4.0, 0.78, 2.13}, trim, kInstWall, kClassWall));
      addDoor(&b, &s, 100, yawPose(M_PI / 2, Vec3(4.0, -0.2, 0)), 0.9, 2.04, 0.005, 1.35, 7.0,
              b.material(MaterialKind::kDoor, {0.62, 0.38, 0.2}, {0.4, 0.22, 0.1}, 0.45), "wall");
    }
    if (fps > 0) s.fps = fps;
    return s;
  }
  if (name != "street" && name != "car" && name != "multi" && name != "large")
    throw std::invalid_argument("synthetic scene '" + name +
                                "' is unknown (room, street, car, door, multi, large)");
  s.path.kind = CameraPathKind::kStreet;
  s.path.speed = name == "multi" ? 8.0 : (name == "large" ? 10.0 : 12.0);
  const double duration = std::max(frames - 1, 1) / (fps > 0 ? fps : 10.0);
  buildStreet(&b, &s, streetX(s.path, duration) + 10);
  Rng& rng = b.rng();
  if (name == "car") {
    const double p[8] = {
        13, 4, 0.27, 0.0, 2.0, 0.55, rng.uniform(0, kTwoPi), rng.uniform(0, kTwoPi)};
    addCar(&b, &s, 100, {0.75, 0.1, 0.08}, p);
  } else if (name == "multi") {
    const double a[8] = {
        12, 3, 0.27, -2.0, 0.6, 0.6, rng.uniform(0, kTwoPi), rng.uniform(0, kTwoPi)};
    addCar(&b, &s, 100, {0.75, 0.1, 0.08}, a);
    const double c[8] = {
        24, 10, 0.15, 2.0, 1.0, 0.5, rng.uniform(0, kTwoPi), rng.uniform(0, kTwoPi)};
    addCar(&b, &s, 101, {0.1, 0.3, 0.7}, c);
    // A gate in the right-hand facade (the camera's side) ahead of the camera's half-way
    // point. Its building is rebuilt flush with the sidewalk so the hinge sits on the facade
    // (y = -7), and lamp posts within its swing are removed.
    const double xg = streetX(s.path, 0.5 * duration) + 30, w = 2.6;
    s.boxes.erase(std::remove_if(s.boxes.begin(), s.boxes.end(),
                                 [&](const Box& box) {
                                   const uint16_t id = box.faces[0].instance;
                                   return (id == kInstBuilding || id == kInstPole) &&
                                          box.hi.y() < -4 && box.hi.y() > -10 &&
                                          box.hi.x() > xg - 4 && box.lo.x() < xg + w + 4;
                                 }),
                  s.boxes.end());
    Box house = Builder::box(
        {xg - 4, -19, 0}, {xg + w + 4, -7, 9},
        b.material(MaterialKind::kBricks, {0.6, 0.32, 0.22}, {0.42, 0.22, 0.15}, 1, true),
        kInstBuilding, kClassWall);
    setAxis(&house, 2, b.material(MaterialKind::kGround, {0.35, 0.33, 0.32}, {0.5, 0.45, 0.42}));
    house.decal =
        b.decal(3, xg, xg + w, 0.0, 3.0,
                b.material(MaterialKind::kDoorway, {0.05, 0.05, 0.05}, {0.04, 0.04, 0.04}));
    b.add(house);
    // Hinge at the gate's -x end; closed, the panel runs along +x; it opens towards the street.
    addDoor(&b, &s, 102, yawPose(0.0, Vec3(xg, -7.0, 0)), w, 2.8, 0.16, 1.2, 6.0,
            b.material(MaterialKind::kDoor, {0.35, 0.5, 0.4}, {0.2, 0.3, 0.25}, 0.65), "building");
  } else if (name == "large") {
    // A truck in the lane beside the camera's, a few metres ahead: it fills much of the left
    // half of the view, and frozen at its first pose it is passed, not driven into.
    const double p[8] = {
        3.5, 1.5, 0.3, 0.6, 0.4, 0.35, rng.uniform(0, kTwoPi), rng.uniform(0, kTwoPi)};
    addTruck(&b, &s, 100, p);
  }
  bool has_car = false, has_truck = false;
  for (const MovingObject& o : s.objects) {
    has_car |= o.class_id == kClassCar;
    has_truck |= o.class_id == kClassTruck;
  }
  if (has_car)
    s.classes.push_back(semanticClass(kClassCar, "car", true, JointType::kPlanar, "road"));
  if (has_truck)
    s.classes.push_back(semanticClass(kClassTruck, "truck", true, JointType::kPlanar, "road"));
  if (fps > 0) s.fps = fps;
  return s;
}

SE3 cameraPose(const SceneData& scene, double t) {
  const CameraPath& p = scene.path;
  const double* ph = p.phase;
  Vec3 position;
  double yaw, pitch, roll;
  switch (p.kind) {
    case CameraPathKind::kRoomOrbit: {
      // An ellipse round the room's middle in 14 s (about 0.45 m/s), looking along the
      // direction of travel give or take 20 degrees.
      const double a = kTwoPi / 14.0 * t + ph[0];
      position =
          Vec3(1.2 * std::cos(a), 0.75 * std::sin(a), 1.35 + 0.12 * std::sin(0.9 * t + ph[1]));
      yaw = std::atan2(0.75 * std::cos(a), -1.2 * std::sin(a)) + 0.35 * std::sin(0.45 * t + ph[2]);
      pitch = -0.12 + 0.1 * std::sin(0.6 * t + ph[3]);
      roll = 0.06 * std::sin(0.8 * t + ph[4]);
      break;
    }
    case CameraPathKind::kRoomFacing:
      // Sways in front of the x = +4 wall, 3 to 4 m away, looking at it.
      position = Vec3(0.5 + 0.45 * std::sin(kTwoPi / 9.0 * t + ph[0]),
                      0.25 + 0.95 * std::sin(kTwoPi / 12.0 * t + ph[1]),
                      1.4 + 0.1 * std::sin(0.7 * t + ph[2]));
      yaw = 0.25 * std::sin(kTwoPi / 10.0 * t + ph[3]);
      pitch = -0.08 + 0.06 * std::sin(0.5 * t + ph[4]);
      roll = 0.05 * std::sin(0.9 * t + ph[5]);
      break;
    case CameraPathKind::kStreet:
    default: {
      // Drives along +x in the right lane (y = -2), 1.65 m above the road.
      position = Vec3(streetX(p, t), -2.0 + 0.3 * std::sin(0.35 * t + ph[1]),
                      1.65 + 0.02 * std::sin(2.3 * t + ph[2]));
      const double vx = p.speed + 0.3 * std::cos(0.2 * t + ph[0]);
      const double vy = 0.105 * std::cos(0.35 * t + ph[1]);
      yaw = std::atan2(vy, vx) + 0.03 * std::sin(0.6 * t + ph[3]);
      pitch = 0.012 * std::sin(1.1 * t + ph[4]);
      roll = 0.01 * std::sin(1.7 * t + ph[5]);
      break;
    }
  }
  return SE3(cameraRotation(yaw, pitch, roll), position);
}

SE3 objectPose(const SceneData& scene, const MovingObject& o, double t) {
  if (o.motion == MotionKind::kHingeSwing) {
    const double angle = o.p[0] * 0.5 * (1.0 - std::cos(kTwoPi * t / o.p[1] + o.p[2]));
    return o.T_world_joint * yawPose(angle, Vec3::Zero());
  }
  auto position = [&](double tt) {
    return Eigen::Vector2d(
        streetX(scene.path, tt) + o.p[0] + o.p[1] * std::sin(o.p[2] * tt + o.p[6]),
        o.p[3] + o.p[4] * std::sin(o.p[5] * tt + o.p[7]));
  };
  const Eigen::Vector2d xy = position(t);
  const Eigen::Vector2d velocity = position(t + 1e-3) - position(t - 1e-3);
  // On the road plane (z = 0), heading along the velocity: a planar joint.
  return yawPose(std::atan2(velocity.y(), velocity.x()), Vec3(xy.x(), xy.y(), 0.0));
}

}  // namespace radslam::synth
