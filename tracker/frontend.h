// The tracker's image front end: input frames undistorted and resampled to the working
// resolution, the BA grid that goes with it, and the keyframe decision. Dense flow and its
// confidence are in tracker/frontend_flow.h. DESIGN.md section 3.
//
/// Resolutions. The working image is W x H (W, H multiples of the grid cell c, default 8); the
/// BA grid is (W / c) x (H / c). Grid pixel (u, v) is the c x c block of working pixels
/// [c u, c u + c) x [c v, c v + c): its centre is working pixel (c u + (c - 1) / 2, ...), e.g.
/// 8 u + 3.5. This is cv::resize's pixel-centre convention (INTER_AREA averages exactly those
/// blocks, INTER_LINEAR upsampling interpolates between those centres) and scaleCamera's, so
/// the grid camera is scaleCamera(working camera, W / c, H / c).
#pragma once

#include <memory>
#include <optional>
#include <string>

#include <opencv2/core.hpp>

#include "common/camera.h"
#include "common/types.h"

namespace radslam {

/// Working-resolution and BA-grid cameras (pinhole, undistorted).
struct GridGeometry {
  int cell = 8;         // working pixels per grid pixel, each direction
  CameraModel working;  // W x H, W and H multiples of cell
  CameraModel grid;     // (W / cell) x (H / cell)
  cv::Size workingSize() const { return {working.width, working.height}; }
  cv::Size gridSize() const { return {grid.width, grid.height}; }
};

/// The geometry for a pinhole working camera whose size is a multiple of cell. Throws
/// std::invalid_argument otherwise.
GridGeometry makeGridGeometry(const CameraModel& working, int cell);

/// Working size for an input of input_width x input_height: width working_width (never more
/// than the input width) rounded down to a multiple of cell, height keeping the aspect ratio,
/// rounded to the nearest multiple of cell (at least 2 cells each way). working_width <= 0
/// keeps the input width. Throws std::invalid_argument when the input is smaller than 2 cells.
cv::Size workingSize(int input_width, int input_height, int working_width, int cell);

/// A frame at working resolution.
struct PreparedImage {
  cv::Mat grey;        // CV_8UC1 working size
  cv::Mat color;       // CV_8UC3 (or CV_8UC1 for grey input) working size; only when requested
  cv::Mat right_grey;  // CV_8UC1 working size; stereo input only
  cv::Mat depth;       // CV_32FC1 m, 0 = invalid, working size (nearest neighbour); RGB-D only
  cv::Mat instance;    // CV_16UC1 working size (nearest neighbour); when the frame has one
  cv::Mat class_id;    // CV_16UC1 working size (nearest neighbour); when the frame has one
  // Rolling shutter only: the source pixel of every working pixel (CV_32FC2, in the input
  // reduced by the preparer's prescale), which prepareColor() reuses for the same frame.
  cv::Mat source_map;
};

/// Undistorts and resamples frames of one camera to the working resolution. Large downscales
/// first halve the image with INTER_AREA (so a 1226-wide KITTI image does not alias), then one
/// remap (or, for an undistorted camera, one INTER_AREA resize) reaches the working size.
class ImagePreparer {
 public:
  /// Throws std::invalid_argument on an invalid camera or a working size it cannot make, or
  /// a readout outside [0, 1) s.
  ///
  /// readout_s > 0 (usually input.readout_s): the camera has a rolling shutter that exposes the
  /// input's rows one after another, the last row readout_s after the first. A camera that turns
  /// meanwhile sees each row from another orientation, which bends and shears a global-shutter view
  /// by up to degrees (TUM fr1/rpy turns at 58 deg/s median). prepare() then resamples every pixel
  /// as the camera saw it when the middle row was exposed: rotation only (over a readout the camera
  /// turns by up to degrees but moves by millimetres).
  ImagePreparer(const CameraModel& input, int working_width, int cell, double readout_s = 0);

  /// True when frames of `camera` can go through this preparer (same size and intrinsics).
  bool matches(const CameraModel& camera) const;
  const CameraModel& input() const { return input_; }
  double readout() const { return undistorter_->source().readout_s; }  // s, 0: global shutter
  const GridGeometry& geometry() const { return geometry_; }

  /// Grey (always), colour (when want_color), right grey, depth and the instance and class
  /// masks (each when the frame has it). Throws std::invalid_argument naming what is wrong with the
  /// frame's images (empty, size differs from the camera, unsupported type).
  /// omega_cam: the camera's angular velocity during the frame (rad/s, camera frame); it is
  /// used only with a rolling shutter.
  PreparedImage prepare(const Frame& frame, bool want_color,
                        const Vec3& omega_cam = Vec3::Zero()) const;
  /// The grey image alone, as prepare() makes it (no validation: for a frame prepare() takes).
  cv::Mat prepareGrey(const Frame& frame, const Vec3& omega_cam) const;
  /// Colour of a frame already validated by prepare() (done only for keyframes), resampled as
  /// that frame's `image` was.
  cv::Mat prepareColor(const cv::Mat& color, const PreparedImage& image) const;

  /// Rolling shutter: the source pixel (in the prescaled input) of every working pixel, as
  /// prepare() uses it for a camera turning at omega_cam; empty for a global shutter or no
  /// rotation.
  cv::Mat rollingShutterMap(const Vec3& omega_cam) const;

 private:
  cv::Mat resample(const cv::Mat& image, bool nearest, const cv::Mat& source_map) const;

  CameraModel input_;
  int prescale_ = 1;  // input is first reduced by this factor (power of 2)
  cv::Size prescaled_size_;
  bool distorted_ = false;
  std::unique_ptr<Undistorter> undistorter_;
  GridGeometry geometry_;
};

/// Throws std::invalid_argument naming what is wrong with a frame's content: empty colour,
/// unsupported image types, images whose size differs from the camera's, non-finite or
/// non-positive intrinsics, a right image without a positive baseline.
void validateFrame(const Frame& frame);

/// Mean displacement |target(p) - p| (grid pixels) over the pixels with a positive weight, and
/// the fraction of such pixels (DROID-SLAM's motion filter). The second form also splits the
/// displacement with the relative rotation R_b_a of the two views: the part a pure rotation
/// would cause, |Pi(R_b_a Pi^-1(p)) - p|, and the parallax left, |target(p) - Pi(R_b_a Pi^-1(p))|
/// (translation); only parallax conditions the depths and the baseline. Cells marked in
/// `leaning` (Correspondences::leaning) count as well: the flow found them.
struct FlowMotion {
  double mean_flow_px = 0;       // grid px
  double valid_fraction = 0;     // [0, 1]
  double mean_rotation_px = -1;  // grid px; -1 when not measured
  double mean_parallax_px = -1;  // grid px; -1 when not measured
};
FlowMotion measureFlowMotion(const cv::Mat& target, const cv::Mat& weight);
FlowMotion measureFlowMotion(const cv::Mat& target, const cv::Mat& weight, const CameraModel& grid,
                             const Mat3& R_b_a, const cv::Mat& leaning = {});

struct KeyframePolicy {
  double flow_px = 2.5;      // grid px: mean parallax (mean flow when the split is not measured)
  double rotation_px = 8.0;  // grid px: mean flow a pure rotation alone may cause
  double min_valid_fraction = 0.4;
};

/// A new keyframe when fewer than min_valid_fraction of the last keyframe's pixels are still
/// tracked, when the parallax exceeds flow_px or when the rotation alone moves pixels by more
/// than rotation_px. Only parallax conditions depths and baselines, so rotation makes keyframes
/// only as the view leaves the keyframe (DSO weighs rotational flow likewise lower); the
/// frames in between are aligned against the keyframe's depths. Without the split the mean
/// flow decides alone (DROID-SLAM's motion filter).
bool isNewKeyframe(const FlowMotion& motion, const KeyframePolicy& policy);

/// Grey conversion of an 8-bit image (BGR or already grey).
cv::Mat toGrey(const cv::Mat& image);

}  // namespace radslam
