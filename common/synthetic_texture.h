// Procedural materials of radslam's synthetic generator (common/synthetic.h): textures with
// detail at many scales (fBm value noise, stripes, bricks, tiles, windows...) so dense optical
// flow has something to track, filtered by the pixel footprint so they do not alias.
// Private to common/synthetic*.cc.
#pragma once

#include <cstdint>

#include "common/lie.h"

namespace radslam::synth {

enum class MaterialKind : uint8_t {
  kAsphalt,    // road with lane markings; (u, v) = world (x, y)
  kGround,     // verge, roofs: two-colour fBm
  kTiles,      // paving, ceiling tiles: grid of jittered tiles with grout
  kBricks,     // facade, optional windows
  kPlaster,    // facade with stains, optional windows
  kPlanks,     // wooden floor
  kWallpaper,  // striped wallpaper with posters and a skirting board
  kWood,       // furniture
  kBooks,      // bookshelf front
  kDoor,       // wood with a grid of panels
  kPaint,      // car body
  kGlass,      // car windows
  kRubber,     // tyres
  kFabric,     // checked fabric, cardboard
  kMetal,      // poles, truck roof
  kDoorway,    // the dark opening behind a door
  kGraffiti,   // colourful truck panels
};

struct Material {
  MaterialKind kind = MaterialKind::kGround;
  Vec3 color_a = Vec3(0.5, 0.5, 0.5);  // albedo, linear RGB in [0, 1]
  Vec3 color_b = Vec3(0.3, 0.3, 0.3);
  double scale = 1;  // the pattern's main size, m (tile, plank length, panel...)
  uint32_t seed = 0;
  bool windows = false;  // facades: a grid of windows
};

/// Albedo of a material at surface coordinates (u, v) in metres. footprint_m is the size of a
/// pixel on the surface: pattern detail finer than about two pixels is faded out (the cheap
/// equivalent of texture filtering), so distant surfaces neither alias nor flicker.
Vec3 materialAlbedo(const Material& material, double u, double v, double footprint_m);

/// Sky colour along a world direction (not normalised): horizon-to-zenith gradient and clouds.
Vec3 skyColor(const Vec3& dir_world, double pixel_angle_rad, uint32_t seed);

}  // namespace radslam::synth
