// Evaluation of a mapped field against a dataset (radslam-bench-mapper): image and depth
// errors, ground-truth poses at frame times, the sensor-noise variance of oracle keyframes, and
// keyframes from a tracker run folder brought into the ground-truth frame.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/camera.h"
#include "common/lie.h"
#include "common/trajectory.h"

namespace radslam {

/// PSNR (dB, peak 1) of a render (CV_32FC3 RGB in [0, 1]) against a CV_8UC3 BGR image of the
/// same size. Throws std::invalid_argument on a type or size mismatch.
double psnr(const cv::Mat& reference_bgr8, const cv::Mat& rendered_rgb);

struct DepthError {
  double sum_abs = 0;  // m, over `pixels`
  int64_t pixels = 0;  // reference valid and rendered depth known
  int64_t valid = 0;   // reference valid (> 0, finite)
  // The same by reference depth: bin b holds [b, b + 1) m, the last one everything beyond.
  static constexpr int kBins = 4;
  double bin_abs[kBins] = {};
  double bin_signed[kBins] = {};  // sum of rendered - reference (m)
  int64_t bin_pixels[kBins] = {};
  double l1() const { return pixels > 0 ? sum_abs / pixels : 0; }
  double coverage() const { return valid > 0 ? double(pixels) / valid : 0; }
  DepthError& operator+=(const DepthError& o);
};
/// Mean |rendered - reference| (m) over pixels whose reference depth is valid and whose
/// rendered depth is known (> 0). Both CV_32FC1 of one size, else std::invalid_argument.
DepthError depthError(const cv::Mat& rendered, const cv::Mat& reference);

/// The pose of `trajectory` (sorted by time) at time t: linear in position and spherical in
/// rotation between the two stamps around t; nullopt outside it or across a gap > max_gap_s.
std::optional<SE3> poseAt(const Trajectory& trajectory, double t, double max_gap_s = 0.05);

/// Structured-light sensor noise (Nguyen, Izadi, Lovell 2012) plus depth discontinuities,
/// where a pixel may see either side: sigma = 0.0012 + 0.0019 (z - 0.4)^2 + half the depth
/// range of the 3x3 neighbourhood (m). Returns the variance (m^2); invalid depth -> infinity.
/// Pixels within `foreground_edge_px` (Chebyshev distance) of a pixel more than 10 % deeper get
/// infinity too: a Kinect's foreground depth spills a few pixels over the background beside
/// it, so there the measurement claims a surface that other views see through.
cv::Mat sensorDepthVariance(const cv::Mat& depth, int foreground_edge_px = 0);

/// A tracker run folder: trajectory.txt (every frame), keyframes.txt and
/// keyframes/<%.6f stamp>.exr with channels "depth" and "sigma" (m, the tracker's scale).
struct TrackerKeyframe {
  double t = 0;  // s
  SE3 T_world_cam;
  cv::Mat depth;  // m, 0 = unknown
  cv::Mat sigma;  // m
  cv::Mat color;  // BGR, the image the mapper trains on; empty when the folder has none
};
struct TrackerRun {
  Trajectory trajectory;
  std::vector<TrackerKeyframe> keyframes;
};
/// Reads a run folder (common/keyframe_files.h). Throws std::runtime_error naming the file
/// that is missing or wrong (depth and sigma of different sizes, a colour image of another
/// size, no keyframes).
TrackerRun readTrackerRun(const std::string& dir);

/// The similarity T_gt_est bringing a monocular tracker run into the ground-truth frame.
/// Rotation from the orientations (well conditioned even when the camera barely translates),
/// scale `scale` when > 0 (e.g. a depth ratio) else from Umeyama on the positions, and the
/// translation that matches the centroids. Needs 3 matched poses (std::invalid_argument).
/// With camera_offset, the rotation is fitted together with a constant rotation on the camera
/// side (alignRotationsWithCameraOffset), returned there: the estimate's camera at a ground-truth
/// pose T_gt is then T_gt * camera_offset^-1.
Sim3 alignToGroundTruth(const Trajectory& estimate, const Trajectory& ground_truth,
                        double scale = 0, double max_gap_s = 0.05, SO3* camera_offset = nullptr);

}  // namespace radslam
