// Pinhole projection and unprojection with Jacobians, camera rescaling, and
// undistortion of images into a pinhole camera.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "common/lie.h"
#include "common/types.h"

namespace radslam {

/// Pixel coordinates of a point in the camera frame (x right, y down, z forward):
/// u = fx x / z + cx, v = fy y / z + cy. Pixel (0, 0) is the centre of the
/// top-left pixel. Only fx, fy, cx, cy are used: undistort images first.
/// Requires z > 0 (the caller checks; z = 0 gives inf). H_point = d(u, v) / dp.
Eigen::Vector2d project(const CameraModel& cam, const Vec3& p_cam,
                        Eigen::Matrix<double, 2, 3>* H_point = nullptr);

/// The point at z-depth `depth` (m, along the optical axis, not along the ray)
/// seen at pixel px: the inverse of project.
Vec3 unproject(const CameraModel& cam, const Eigen::Vector2d& px, double depth);

/// The same camera for an image resized to new_width x new_height, with the
/// pixel-centre convention of cv::resize: cx' = (cx + 0.5) sx - 0.5. The
/// distortion coefficients act on normalised coordinates and are kept.
/// Throws std::invalid_argument on non-positive sizes.
CameraModel scaleCamera(const CameraModel& cam, int new_width, int new_height);

/// K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]].
cv::Matx33d cameraMatrix(const CameraModel& cam);

/// Throws std::invalid_argument naming what is wrong: size or focal length
/// not positive, principal point not finite, wrong number of distortion
/// coefficients for the model (Pinhole none or all zero; RadTan 0, 4 or 5;
/// Equidistant 4).
void validateCamera(const CameraModel& cam);

/// Depth (CV_32FC1, m, 0 = invalid) measured at another time than the colour image, brought to
/// the colour image's time: R_colour_depth is the camera's rotation over the gap (the camera at
/// colour time from the camera at depth time); the translation over the few ms is neglected.
/// Each pixel takes the depth of the pixel the rotation carries it from (nearest, so that
/// depth edges stay sharp), with its z in the colour camera; 0 where that pixel is outside or
/// invalid. `camera`: the pinhole of `depth`.
cv::Mat rotateDepth(const cv::Mat& depth, const CameraModel& camera, const Mat3& R_colour_depth);

/// Maps images of a (possibly distorted) camera to a pinhole camera of the
/// requested size. The maps are built once; apply() is one cv::remap.
/// RadTan: new K from cv::getOptimalNewCameraMatrix with alpha = 0 (every
/// output pixel sees the scene, no black borders). Equidistant: the largest
/// axis-aligned rectangle inside the undistorted image border. Pinhole: the
/// scaled K, and apply() is a plain resize.
class Undistorter {
 public:
  /// Throws std::invalid_argument on an invalid camera or target size.
  Undistorter(const CameraModel& source, int target_width, int target_height);

  /// Undistorts and resamples `image` (any depth/channels cv::remap takes).
  /// Use cv::INTER_NEAREST for depth, instance and class images. Throws
  /// std::invalid_argument if the image size is not the source camera's.
  cv::Mat apply(const cv::Mat& image, int interpolation = cv::INTER_LINEAR) const;

  /// The source pixel (CV_32FC1 maps of x and y) of every target pixel and of `pad` more
  /// pixels beyond each border of the target: entry (pad + v, pad + u) is target pixel (u, v).
  /// Throws std::invalid_argument when pad < 0.
  void sourcePixels(int pad, cv::Mat* map_x, cv::Mat* map_y) const;

  // Rolling shutter (source readout_s > 0): source row y is exposed (y / (H - 1) - 0.5)
  // readout_s after the middle row. A camera turning meanwhile sees each row from another
  // orientation; rotation only (over a readout a camera turns by degrees but moves by
  // millimetres).

  /// The source pixel (CV_32FC2) of every target pixel, as the camera saw the pixel's ray
  /// when the middle row was exposed, turning at omega_cam (rad/s, camera frame): the ray r
  /// of the middle row's camera is Exp(-omega_cam dt) r in the camera of a row exposed dt
  /// later. Solved every `step` target pixels (at the centres of step x step blocks) and
  /// interpolated. Empty for a global shutter or no rotation.
  cv::Mat rollingShutterMap(const Vec3& omega_cam, int step) const;
  /// Resamples `image` through a map of rollingShutterMap (apply() when it is empty).
  cv::Mat apply(const cv::Mat& image, int interpolation, const cv::Mat& source_map) const;
  /// When each target pixel was exposed: s after the middle row (CV_32FC1, the source row of
  /// its pixel); empty for a global shutter. A view rendered with each pixel's ray turned by
  /// Exp(omega dt) is what the rolling shutter saw.
  cv::Mat exposureTimes() const;

  const CameraModel& source() const { return source_; }
  /// The pinhole camera of the output images.
  const CameraModel& target() const { return target_; }

 private:
  void makeDistortedMaps(int target_width, int target_height);
  // Source pixel at a target position (bilinear in the padded map, clamped to it).
  cv::Vec2f paddedSource(double u, double v) const;

  CameraModel source_;
  CameraModel target_;
  bool pure_resize_ = false;
  cv::Mat map_x_, map_y_;           // CV_32FC1 source pixel per target pixel (nearest)
  cv::Mat map_fixed_, map_interp_;  // fixed-point version (linear, cubic: faster)
  // Rolling shutter: source pixels of the target and a margin of source_pad_ px (CV_32FC2).
  int source_pad_ = 0;
  cv::Mat padded_source_;
};

}  // namespace radslam
