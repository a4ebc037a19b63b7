// What the renderer leaves in the run folder at the end: renders of the final map at the
// keyframes' poses (PNG colour, EXR depth + sigma) and a fly-through video along the trajectory.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "common/lie.h"
#include "common/types.h"
#include "renderer/field_replica.h"

namespace radslam {

struct ViewPose {
  int64_t utime = 0;  // us, sensor time
  SE3 T_world_cam;
  CameraModel camera;
};

/// The camera scaled to `width` pixels (same field of view); unchanged when width <= 0.
CameraModel scaledCamera(const CameraModel& camera, int width);

/// Writes DIR/<timestamp>.png (colour) and DIR/<timestamp>.exr (channels "depth" and
/// "sigma", m) for each view, creating DIR. Returns the number of views written; throws
/// std::runtime_error naming the file when one cannot be written. threads: per render (0 = the
/// replica's own). progress (if set) is called after each view.
int writeFinalRenders(const FieldReplica& replica, const std::vector<ViewPose>& views,
                      const std::string& dir, int threads = 0,
                      const std::function<void()>& progress = {});

/// Renders the views in order into an MJPG .avi at fps. Returns the number of frames written;
/// throws std::runtime_error naming the file when the writer cannot open it. No views: no file.
int writeFlyThrough(const FieldReplica& replica, const std::vector<ViewPose>& views,
                    const std::string& path, double fps, int threads = 0,
                    const std::function<void()>& progress = {});

}  // namespace radslam
