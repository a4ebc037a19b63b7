// Two-view initialisation of monocular tracking: the relative pose of the second keyframe and
// the first keyframe's inverse depths from their grid correspondences, by the essential matrix
// (OpenCV's five-point RANSAC) and triangulation.
//
/// Why: before the second keyframe the first one has no depth, so frames are aligned against a
/// constant depth. That is right for rotation (fr1/rpy) but under fast forward motion the
/// constant-depth model explains the ground's flow as rotation (KITTI 07 from frame 40: 7.5 deg
/// after one frame), and BA started there converges to a wrong two-view solution it never
/// leaves. The essential matrix has no such bias; with too little parallax (rotation) it is
/// degenerate and the constant-depth start is kept.
#pragma once

#include <string>

#include <opencv2/core.hpp>

#include "common/camera.h"
#include "common/lie.h"

namespace radslam {

struct TwoViewOptions {
  double ransac_threshold_px = 0.25;  // grid px, Sampson distance of an inlier
  double ransac_confidence = 0.999;
  double min_inlier_fraction = 0.5;  // of the weighted correspondences
  /// Median angle between the two rays of the inliers below which the motion counts as
  /// rotation (translation and depth not observable): deg.
  double min_parallax_deg = 1.0;
  /// The map's scale: the first keyframe's median inverse depth (1/scene unit).
  double median_inv_depth = 1.0;
};

struct TwoViewResult {
  bool ok = false;
  std::string why;  // when !ok
  /// Not ok only because the median parallax is below min_parallax_deg: a translation shows
  /// (a rotation alone does not explain the flow) but is short for triangulation. T_b_a and
  /// inv_depth_a are set then too (a noisier estimate, still better than none).
  bool small_parallax = false;
  SE3 T_b_a;  // maps points of camera a to camera b; |t| in scene units
  /// CV_32FC1 grid of a: inverse depth (1/scene unit) of the inliers, NaN elsewhere.
  cv::Mat inv_depth_a;
  int correspondences = 0;
  int inliers = 0;
  double median_parallax_deg = 0;
};

/// Relative pose of b and inverse depths of a from grid correspondences a -> b (target CV_32FC2:
/// location in b's grid of each grid pixel of a; weight kFlowWeightType, a pixel counts where
/// either diagonal entry is > 0) on the pinhole grid camera. The translation is scaled so that the
/// median inverse depth of the inliers is options.median_inv_depth.
TwoViewResult initializeTwoView(const CameraModel& grid, const cv::Mat& target,
                                const cv::Mat& weight, const TwoViewOptions& options = {});

}  // namespace radslam
