// What the mapper leaves in the run folder: checkpoint, point cloud and mesh (PLY), renders of
// every keyframe and of every 10th other frame, and the refined keyframe trajectory. No bus: the
// node calls it at the end.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "mapper/mapper.h"

namespace radslam {

struct MapperOutputOptions {
  bool checkpoint_images = true;
  int cloud_stride = 2;  // pixels
  float mesh_iso = 1.f;
  int mesh_max_faces = 4000000;  // a coarser lattice beyond (extractMeshWithin)
  int render_threads = 0;        // 0 = the mapper's render_threads
  // Called between the steps (and between renders): the node keeps its heartbeat going, so
  // that a supervisor tells a long end of run from a hung process.
  std::function<void()> progress;
};

/// A view to render besides the keyframes: a tracked frame at its pose.
struct FrameView {
  int64_t utime = 0;  // the frame's sensor time (names the files)
  int64_t frame_index = 0;
  SE3 T_world_cam;
  CameraModel camera;
  Vec6 exposure = Vec6::Zero();  // the colour as the frame sees it (applyExposure)
};

struct MapperOutputSummary {
  std::string checkpoint, cloud, mesh, trajectory;
  int renders = 0;        // keyframes
  int frame_renders = 0;  // other frames
  // Mean PSNR (dB) of the keyframe renders against the images the mapper trained on.
  double keyframe_psnr_db = 0;
  size_t cloud_points = 0, mesh_faces = 0;
  int mesh_stride = 1;  // fine voxels
  // Wall time of each step, s.
  double checkpoint_s = 0, mesh_s = 0, renders_s = 0;  // renders_s includes the cloud
};

/// A frame tracked relative to a keyframe, moved with that keyframe's refinement: its pose
/// relative to the keyframe as received, composed with the keyframe's pose as trained.
SE3 followRefinement(const KeyframeEntry& keyframe, const SE3& T_world_frame);

/// The frames to render besides the keyframes: of the tracked poses (latest per frame index)
/// that are neither flagged as keyframes nor the frame of a stored keyframe, in frame order,
/// the middle one of each run of stride (a scorer's held-out frames, whatever the keyframe
/// rate), tracked (not lost or initialising), each with the camera of the stored
/// keyframe nearest in frame index (keyframes carry the camera at training resolution) and
/// moved with that keyframe's refinement (its pose relative to the keyframe kept as tracked),
/// and with the exposure interpolated in time between the keyframes around it.
/// Empty when there are no keyframes. Sorted by frame index. At most max_views, evenly
/// spread (a long run would otherwise spend minutes rendering at its end).
std::vector<FrameView> nonKeyframeViews(const std::map<int64_t, PoseStamped>& poses,
                                        const KeyframeStore& keyframes, int stride = 10,
                                        size_t max_views = 100);

/// Writes into out_dir (created if needed): mapper.ckpt, map_points.ply, map_mesh.ply,
/// mapper_keyframes.txt (TUM, refined poses), renders/rgb/<stem>.png (colour) and
/// renders/depth/<stem>.exr (channels "depth" and "sigma", m) of every keyframe at its refined
/// pose, camera and exposure, and of every view in `frames`: each colour render predicts that
/// frame's image, so that it can be scored against the input. Throws std::runtime_error naming
/// the file that cannot be written.
MapperOutputSummary writeMapperOutputs(const Mapper& mapper, const std::string& out_dir,
                                       const MapperOutputOptions& options,
                                       const std::vector<FrameView>& frames = {});

}  // namespace radslam
