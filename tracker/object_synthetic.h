// Object correspondences from the synthetic dataset's ground truth, with configurable sensor
// noise: the test and benchmark input of object tracking (the product gets them from depth and
// dense flow, see objectCorrespondencesFromFlow).
#pragma once

#include <cstdint>
#include <random>
#include <vector>

#include "common/lie.h"
#include "common/synthetic.h"
#include "tracker/object_tracking.h"
#include "tracker/object_window_ba.h"

namespace radslam {

struct ObjectNoise {
  double pixel_sigma = 0;      // px, Gaussian noise on the pixel in frame i+1
  double depth_sigma_rel = 0;  // 1/m, depth noise sigma = depth_sigma_rel * z^2 (Kinect-like)
  double outlier_ratio = 0;    // fraction of correspondences replaced by wrong pixels
  double outlier_px = 30;      // px, outliers are displaced uniformly up to this far
};

/// The object's pixels in `view0` (rendered from T_world_cam0, every `stride`-th pixel with
/// instance == object_id and depth > 0) moved by the object's true world motion
/// M_world = T_world_object,1 T_world_object,0^-1 and projected into camera 1, with noise.
/// Points landing behind camera 1 or outside its image are dropped; self-occlusion in frame 1
/// is not modelled. Throws std::invalid_argument on stride < 1 or an invalid camera.
std::vector<ObjectCorrespondence> syntheticObjectCorrespondences(
    const CameraModel& camera, const RenderedView& view0, int object_id, const SE3& T_world_cam0,
    const SE3& T_world_cam1, const SE3& M_world, int stride, const ObjectNoise& noise,
    std::mt19937_64* rng);

/// A window problem for one object of a scene: frames first..first+frames-1 (frames >= 2),
/// camera poses from ground truth, the object's points from the noise-free render of the first
/// frame (every `stride`-th pixel) with depth noise, and their true projections in the later
/// frames with pixel noise and outliers. Points leaving the image or going behind the camera
/// are not observed there. Throws std::invalid_argument on bad arguments or a missing object.
ObjectWindowProblem syntheticObjectWindow(const SyntheticScene& scene, const Joint& joint,
                                          int object_id, int first, int frames, int stride,
                                          const ObjectNoise& noise, std::mt19937_64* rng);

/// The true world motion of an object between two frames of a scene, T_world_object,b *
/// T_world_object,a^-1. Throws std::invalid_argument if the scene has no such object.
SE3 syntheticObjectMotion(const SyntheticScene& scene, int object_id, int frame_a, int frame_b);

/// The scene's object with this id. Throws std::invalid_argument if there is none.
SyntheticObject syntheticObject(const SyntheticScene& scene, int object_id);

}  // namespace radslam
