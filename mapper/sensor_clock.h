// When an RGB-D dataset's images were taken, on its ground truth's clock (radslam-bench-sync).
// Motion capture and camera run on different clocks, and a Kinect stamps colour and depth with
// delays of their own, so the pose at an image's stamp is not the pose it was taken from. Each
// trial offset is judged by the images themselves: the ground-truth motion read at the shifted
// stamps must carry one frame's depth and colour onto a later frame's.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "common/camera.h"
#include "common/trajectory.h"

namespace radslam {

/// One RGB-D frame, at the check's pinhole camera.
struct ClockFrame {
  double t_colour = 0, t_depth = 0;  // s, the images' own stamps
  cv::Mat grey;                      // CV_32FC1, 0-255
  cv::Mat depth;                     // CV_32FC1, m, 0 = none
};

/// How well the ground truth read at stamp + offset_s explains the images.
struct ClockFit {
  double offset_s = 0;
  // Frame i's depth moved by the motion between the depth poses of frames i and i + gap,
  // against frame i + gap's depth: the mean relative difference, each capped at 5 % (beyond it
  // a pixel sees another surface), and the share within 2 %.
  double depth_error = 0;
  double depth_agree = 0;
  // Frame i's textured pixels (gradient above 20 grey levels per 2 px), with the depth turned
  // from its best offset to the colour pose, moved by the motion between the colour poses:
  // median grey-level difference to frame i + gap.
  float colour_median_diff = 0;
};

struct ClockScan {
  std::vector<ClockFit> fits;  // one per trial offset
  size_t best_depth = 0;       // index of the least depth error
  size_t best_colour = 0;      // index of the least colour difference
};

/// Judges every offset in `offsets_s` on the pairs (i, i + gap) of `frames`. Pairs whose
/// ground truth is missing at a shifted stamp do not count. Throws std::invalid_argument when
/// there are no offsets or no pair.
ClockScan scanSensorClocks(const std::vector<ClockFrame>& frames, const Trajectory& ground_truth,
                           const CameraModel& camera, int gap,
                           const std::vector<double>& offsets_s);

}  // namespace radslam
