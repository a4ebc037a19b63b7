// Scene definitions of radslam's synthetic generator (common/synthetic.h): the analytic
// primitives, procedural materials, camera paths and object motions of each named scene.
// Private to common/synthetic*.cc; other code uses SyntheticScene.
//
/// World frame: z up, the ground (road, floor) is the plane z = 0. Every box is axis-aligned
/// in its owner's frame (the world for static boxes, the object frame for moving objects),
/// and textures are functions of the owner-frame coordinates, so they move with the object.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "common/dataset.h"
#include "common/lie.h"
#include "common/synthetic_texture.h"

namespace radslam::synth {

/// Face f = 2 * axis + (1 if the face at the box's maximum along axis, else 0).
struct Face {
  int16_t material = 0;
  uint16_t instance = 0;
  uint16_t class_id = 0;
};

/// A rectangle painted on one face of a box, in the face's (u, v) coordinates.
struct Decal {
  int face = 0;
  double u0 = 0, u1 = 0, v0 = 0, v1 = 0;  // m
  int16_t material = 0;
};

/// Face (u, v) coordinates from owner-frame point p: faces normal to x use (y, z), normal to
/// y use (x, z), normal to z use (x, y); on walls v is the height.
inline void faceCoordinates(int axis, const Vec3& p, double* u, double* v) {
  *u = axis == 0 ? p.y() : p.x();
  *v = axis == 2 ? p.y() : p.z();
}

struct Box {
  Vec3 lo = Vec3::Zero(), hi = Vec3::Zero();  // m, owner frame
  Face faces[6];
  bool inside = false;  // a shell seen from inside (the room): rays hit its far side
  int decal = -1;       // index into SceneData::decals, -1 = none
};

enum class CameraPathKind : uint8_t { kRoomOrbit, kRoomFacing, kStreet };

struct CameraPath {
  CameraPathKind kind = CameraPathKind::kRoomOrbit;
  double speed = 0;      // m/s (street)
  double phase[6] = {};  // rad, seed-dependent phases of the sinusoids
};

enum class MotionKind : uint8_t {
  // Drives ahead of the camera on the road: x = camera x + p0 + p1 sin(p2 t + p6),
  // y = p3 + p4 sin(p5 t + p7), heading along the velocity.
  kFollow,
  // Turns about its hinge: angle = p0 (1 - cos(2 pi t / p1 + p2)) / 2.
  kHingeSwing,
};

struct MovingObject {
  int32_t object_id = 0;  // also its instance id in the masks (>= 100)
  int32_t class_id = 0;
  std::string name;
  JointType joint = JointType::kFree;
  /// Joint frame: z is the plane normal (planar) or the hinge axis (revolute); for a hinge
  /// the origin lies on the axis and T_world_object = T_world_joint * Rz(angle).
  SE3 T_world_joint;
  std::vector<Box> boxes;  // object frame: x forward, y left, z up, origin on the ground
  MotionKind motion = MotionKind::kFollow;
  double p[8] = {};  // motion parameters (see objectPose)
};

struct SceneData {
  std::string name;
  double fps = 30;  // Hz
  CameraPath path;
  std::vector<Material> materials;
  std::vector<Decal> decals;
  std::vector<Box> boxes;  // static, world frame
  // Optional infinite ground plane z = 0 (street): asphalt for |y| < road_half_width.
  bool has_ground = false;
  double road_half_width = 4;  // m
  Face road, verge;
  bool has_sky = false;
  double haze_start = 0, haze_length = 0;  // m; aerial perspective beyond haze_start (0 = off)
  Vec3 sky_haze = Vec3(0.8, 0.84, 0.9);
  Vec3 light_dir[2];  // unit, world, pointing towards the light
  double light_intensity[2] = {0, 0};
  double ambient = 0.35;
  std::vector<MovingObject> objects;
  std::vector<SemanticClass> classes;
  uint32_t seed = 0;
};

/// Builds the named scene ("room", "street", "car", "door", "multi", "large") for a sequence
/// of `frames` frames at `fps` Hz (0 = the scene's own rate: 30 rooms, 10 streets). Throws
/// std::invalid_argument on an unknown name.
SceneData buildScene(const std::string& name, uint64_t seed, int frames, double fps = 0);

/// T_world_cam at time t (s); camera axes x right, y down, z forward.
SE3 cameraPose(const SceneData& scene, double t);

/// T_world_object at time t (s).
SE3 objectPose(const SceneData& scene, const MovingObject& object, double t);

}  // namespace radslam::synth
