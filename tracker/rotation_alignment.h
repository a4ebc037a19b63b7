// The rotation between two consecutive frames by direct alignment of their coarse images, for
// the rolling-shutter correction (tracker/frontend.h ImagePreparer): the correction needs the
// camera's angular velocity during the frame, before the frame's flow is measured.
//
// The motion model's angular velocity is that of the previous frame interval. Hand-held motion
// changes it by a quarter from one interval to the next (TUM fr1/rpy at 30 Hz: 14.6 of
// 56 deg/s, medians), so the rotation to the previous frame is measured on the images
// themselves: consecutive frames overlap almost entirely and differ by little more than the
// rotation.
//
// Model: pixel x of image a is seen at Pi(R_b_a Pi^-1(x)) in image b (a homography; exact for a
// pure rotation or a distant scene) with a brightness offset beta:
//   b(Pi(R_b_a Pi^-1(x))) = a(x) + beta.
// Inverse compositional Gauss-Newton (Baker and Matthews) on a coarse-to-fine pyramid with a
// Huber kernel: the step delta solves a(Pi(Exp(delta) Pi^-1(x))) + beta = b(Pi(R_b_a Pi^-1(x)))
// and updates R_b_a <- R_b_a Exp(-delta).
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "common/lie.h"
#include "common/types.h"

namespace radslam {

/// An image and its coarser versions, finest first: each level halves the previous one with
/// cv::INTER_AREA (the pixel-centre convention of scaleCamera).
struct ImagePyramid {
  std::vector<cv::Mat> levels;  // CV_8UC1
  std::vector<CameraModel> cameras;
};

/// Levels `first`..`last` (0 = `grey` itself, each one half of the one before) of a grey image
/// and their pinhole cameras. Throws std::invalid_argument when grey is not CV_8UC1 of the
/// camera's size, or the range is empty or too deep for the image.
ImagePyramid coarsePyramid(const cv::Mat& grey, const CameraModel& camera, int first, int last);

struct RotationAlignmentOptions {
  int max_iterations = 12;        // per level
  double min_gradient = 4.0;      // grey levels per px: flatter pixels carry no rotation
  double huber_scale = 10.0;      // grey levels
  double min_inlier_share = 0.3;  // of the usable pixels, inside b and within the kernel scale
  double converged_rad = 1e-4;    // step norm
};

struct RotationAlignment {
  bool ok = false;
  SO3 R_b_a;
  double brightness_offset = 0;  // beta, grey levels
  double rms = 0;                // grey levels, over the inliers of the finest level
  int pixels = 0;                // pixels used at the finest level
};

/// The rotation that carries image a's pixels to image b's, from R_b_a_init. Both pyramids must
/// have the same levels and cameras. ok is false (and R_b_a the initial guess) when too few
/// pixels of a land in b or agree with it.
RotationAlignment alignRotation(const ImagePyramid& a, const ImagePyramid& b, const SO3& R_b_a_init,
                                const RotationAlignmentOptions& options);

/// d Pi(Exp(delta) Pi^-1(u, v)) / d delta at delta = 0 (px per rad): the pixel motion of a small
/// rotation of the camera's rays.
Eigen::Matrix<double, 2, 3> rotationWarpJacobian(const CameraModel& camera, double u, double v);

}  // namespace radslam
