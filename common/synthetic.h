// radslam's built-in synthetic dataset: a CPU ray caster rendering procedurally textured rooms
// and streets along smooth camera paths, with moving objects on mechanical joints, and the
// writer of the synthetic dataset folder.
//
/// Scenes: "room" (static room with furniture, 30 Hz), "street" (static street, 10 Hz), and the
/// dynamic "car" (street + a car, planar joint), "door" (room + a door, revolute joint), "multi"
/// (street + two cars + a gate), "large" (street + a truck filling much of the image).
///
/// World frame: z up, ground plane z = 0. Camera axes: x right, y down, z forward.
/// Depth is the z coordinate in the camera frame (not the ray length), 0 where nothing is hit
/// (sky). Instance ids: 0 sky, 1.. static surface groups (road/floor 1, ...), >= 100 moving
/// objects (instance id = object id). Class ids: 0 sky, then the scene's classes() table.
///
/// Folder format written by generateSyntheticDataset (read by openDataset("synthetic:DIR")):
///   camera.yaml       cv::FileStorage: width height fx fy cx cy baseline_m depth_scale
///   times.txt         one time per frame, seconds
///   rgb/%06d.png      colour, BGR 8-bit            right/%06d.png  right stereo image
///   depth/%06d.png    uint16, metres = value * depth_scale (0.001); 0 = invalid or > 65.535 m
///   instance/%06d.png uint16 instance ids          class/%06d.png  uint16 class ids
///   groundtruth.txt   TUM "t tx ty tz qx qy qz qw", T_world_cam
///   objects.txt       "t object_id class_id tx ty tz qx qy qz qw", T_world_object per frame
///   classes.yaml      sequence "classes" of {id, name, dynamic, joint, parent}
///   generator.yaml    the SyntheticConfig used (provenance only)
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/dataset.h"
#include "common/lie.h"
#include "common/types.h"

namespace radslam {

namespace synth {
struct SceneData;
}

struct SyntheticConfig {
  std::string scene = "room";  // room, street, car, door, multi, large
  int frames = 300;
  int width = 640, height = 480;  // pixels; fx = fy = 0.8 * width, principal point at the centre
  uint64_t seed = 1;              // same seed -> byte-identical output
  bool stereo = true;             // render the right image
  double baseline_m = 0.1;        // right camera at +baseline along the left camera's x
  double image_noise_sigma = 0;   // Gaussian colour noise, grey levels (0 = none)
  double depth_noise_rel = 0;     // Kinect-like depth noise sigma = depth_noise_rel * z^2 (1/m)
  int threads = 1;                // render threads
  bool freeze_objects = false;    // moving objects stay at their last frame's pose (a reference)
  double fps = 0;                 // frame rate, Hz (0 = the scene's: 30 rooms, 10 streets)
  /// Rolling shutter: row y is exposed at the frame's time + (y / (height - 1) - 0.5) readout_s,
  /// with the camera and the objects where they are then (0: every row at the frame's time).
  double readout_s = 0;
};

/// A rendered view. Images are width x height.
struct RenderedView {
  cv::Mat color;     // CV_8UC3, BGR
  cv::Mat depth;     // CV_32FC1, metres along the optical axis, 0 = nothing hit (sky)
  cv::Mat instance;  // CV_16UC1
  cv::Mat class_id;  // CV_16UC1
};

/// A moving object and its joint to its static parent.
struct SyntheticObject {
  int32_t object_id = 0;  // >= 100; also its instance id in the masks
  int32_t class_id = 0;
  std::string name;  // class name
  JointType joint = JointType::kFree;
  /// z = the parent plane's normal (planar joint) or the hinge axis (revolute joint); the
  /// origin lies on the plane / on the axis.
  SE3 T_world_joint;
};

class SyntheticScene {
 public:
  /// Throws std::invalid_argument naming the bad field (unknown scene, size, frames...).
  static SyntheticScene make(const SyntheticConfig& config);
  static const std::vector<std::string>& sceneNames();

  const SyntheticConfig& config() const { return config_; }
  int numFrames() const { return config_.frames; }
  double fps() const;                 // Hz: 30 for rooms, 10 for streets
  double timestamp(int frame) const;  // s = frame / fps
  /// Time (s) at which the moving objects are posed for a frame: its own, or with
  /// freeze_objects the last frame's.
  double objectTime(int frame) const;
  CameraModel camera() const;  // pinhole, config size and readout
  double baseline() const { return config_.baseline_m; }

  /// T_world_cam of the (left) camera at a frame; frames past numFrames() continue the path.
  SE3 cameraPose(int frame) const;
  /// T_world_right = T_world_cam * [I | (baseline, 0, 0)].
  SE3 rightCameraPose(int frame) const;
  /// T_world_object of every moving object at a frame (empty for static scenes).
  std::vector<ObjectPoseSample> objectPoses(int frame) const;
  std::vector<SyntheticObject> objects() const;
  std::vector<SemanticClass> classes() const;

  /// Renders a noise-free view from any pose and pinhole camera (no distortion), with the
  /// moving objects where they are at `frame`. Throws std::invalid_argument on a bad camera.
  RenderedView render(const SE3& T_world_cam, const CameraModel& camera, int frame) const;

  /// The dataset frame: colour, right image (when stereo), depth, instance and class, with
  /// the configured sensor noise (deterministic from seed and frame) and rolling shutter.
  /// Header utime from timestamp(frame), sender "synthetic".
  Frame frame(int frame) const;

 private:
  SE3 leftToRight() const { return SE3(SO3(), Vec3(config_.baseline_m, 0, 0)); }  // T_left_right
  // The frame's view of the camera T_cam_sensor from the left one, with the rolling shutter.
  RenderedView renderFrame(int frame, const SE3& T_cam_sensor) const;

  SyntheticConfig config_;
  std::shared_ptr<const synth::SceneData> scene_;
};

/// Renders config.frames frames and writes the dataset folder `out_dir` (created if needed).
/// `progress`, when set, is called after each frame with (frames done, total).
/// Throws std::runtime_error naming the file or folder that cannot be written.
void generateSyntheticDataset(const SyntheticConfig& config, const std::string& out_dir,
                              const std::function<void(int, int)>& progress = {});

}  // namespace radslam
