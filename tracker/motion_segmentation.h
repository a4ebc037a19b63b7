// Geometric motion segmentation for sequences without instance masks (DESIGN.md section 5):
// pixels whose measured flow disagrees with the flow the static scene predicts, clustered into
// objects whose ids persist from frame to frame.
//
/// For a keyframe a and a frame b: the measured flow a -> b, and the flow a's depths would make
/// if everything were static and the camera moved to b's estimated pose. Where they differ by
/// more than min_residual_px, plus relative_residual of the predicted flow, plus what the depth's
/// uncertainty explains (depth_sigmas times the flow change of a one-sigma depth error), the
/// pixel moved by itself; pixels of unknown depth
/// (sky, beyond the sensor's range) cannot be judged. With depth (RGB-D, stereo), pixels whose
/// depth in b disagrees with the static prediction move too (depthDisagreement): flow alone misses
/// motion along the viewing ray. Evidence below the thresholds but above weak_fraction of them,
/// and the flow test of pixels the static scene carries out of b (their flow may have found
/// nothing to match), count only where they connect to evidence above the thresholds
/// (hysteresis). The moving pixels are carried along the measured flow into b,
/// closed, split into connected components, and components smaller than min_object_pixels are
/// dropped. A component keeps the id of the previous frame's component it overlaps most
/// (intersection over union at least min_overlap), or gets a new one.
#pragma once

#include <optional>

#include <opencv2/core.hpp>

#include "common/binary_io.h"
#include "common/lie.h"
#include "common/types.h"
#include "tracker/joints.h"

namespace radslam {

struct MotionSegmentationParams {
  double min_residual_px = 2.0;  // working px between measured and predicted flow
  double depth_sigmas = 3.0;     // depth uncertainty allowed for, in standard deviations
  /// Fraction of the predicted flow allowed for: long flows (near ground under forward motion,
  /// many frames from the keyframe) fail by more.
  double relative_residual = 0.25;
  int min_object_pixels = 400;     // working px of b; smaller components are noise
  int close_px = 3;                // working px, radius of the closing that fills splat holes
  double min_overlap = 0.3;        // IoU with a previous component to keep its id
  int first_id = 200;              // instance ids handed out from here on (0 = static)
  double depth_test_sigmas = 4.0;  // |depth disagreement| (z-score) that makes a pixel move
  /// With a photometric test (photometricPreference): a pixel moves by its flow only where the
  /// static prediction matches b worse than the measured flow by more than this (grey levels).
  double photometric_margin = 4.0;
  /// Weak evidence (every threshold above times this) makes a pixel move only where it connects
  /// to strong evidence; 1 = only the flow test of pixels the static scene carries out of view.
  double weak_fraction = 0.7;
  /// With carry errors (landingGreyError): a flow lands off its pixel when it lands more than
  /// carry_grey_error grey levels from it. Where more than carry_max_failed_fraction of a
  /// connected region's moving pixels do (those moving by their flow alone), its flow failed
  /// (a pole passing close), and carried it would scatter the pixels over the background,
  /// which closing fills into a blob several times the pole's size: they are not carried.
  double carry_grey_error = 8.0;
  double carry_max_failed_fraction = 0.25;
};

class MotionSegmenter {
 public:
  /// Throws std::invalid_argument on out-of-range parameters.
  explicit MotionSegmenter(const MotionSegmentationParams& params = {});

  /// measured, predicted: CV_32FC2 flows a -> b (working px, a's size); predicted NaN where a has
  /// no depth. depth_flow (CV_32FC1, a's size, optional): working px the predicted flow moves by
  /// for a one-sigma error of a's depth (+inf: unknown depth). Returns b's instance mask
  /// (CV_16UC1, a's size, 0 = static): one id per moving object, stable across calls.
  /// depth_test (CV_32FC1, a's size, optional, NaN: not judged): depthDisagreement below;
  /// pixels beyond depth_test_sigmas move too. photo_test (CV_32FC1, a's size, optional, NaN:
  /// not judged): photometricPreference below; a pixel whose flow disagrees moves only when
  /// the static prediction is photometrically worse by photometric_margin (a flow that failed,
  /// at occlusions, thin structures or long flows on the ground, matches b no better).
  /// carry_error (CV_32FC1, a's size, optional, NaN: not judged): landingGreyError below of the
  /// measured flow (see carry_grey_error). occluding (CV_32FC1, b's size, optional):
  /// depthDisagreement's occluding_b; b's pixels beyond depth_test_sigmas move, where they are,
  /// without a flow to carry them.
  cv::Mat segment(const cv::Mat& measured, const cv::Mat& predicted, const cv::Mat& depth_flow = {},
                  const cv::Mat& depth_test = {}, const cv::Mat& photo_test = {},
                  const cv::Mat& carry_error = {}, const cv::Mat& occluding = {});

  /// Forgets the previous frame's components (ids are not reused).
  void reset() { previous_.release(); }

  /// The state carried from frame to frame (tracker checkpoints); load() replaces it, its mask
  /// must be empty or of `size` (the flows').
  void save(BinaryWriter* out) const;
  void load(BinaryReader* in, cv::Size size);

 private:
  MotionSegmentationParams params_;
  cv::Mat previous_;  // last instance mask
  int next_id_;
};

/// How well the flow a -> b (CV_32FC2 working px, a's size) carries each pixel of a: the grey
/// difference |b - a(x)| closest to zero within 1 px of its landing x + flow (grey levels).
/// CV_32FC1, a's size; NaN where that 3 x 3 neighbourhood is not inside b or the flow is unknown.
cv::Mat landingGreyError(const cv::Mat& grey_a, const cv::Mat& grey_b, const cv::Mat& flow);

/// Depth evidence (RGB-D sensor or stereo) of motion along the viewing ray, which flow misses: an
/// object ahead that drives with the camera stays put in the image while the static scene would
/// expand. For each pixel of a with depth, the point T_b_a p_a a static scene puts in b: its
/// depth against b's depth where it projects, in units of their standard deviation: sensor noise
/// sigma_z = a + b (z - z0)^2 (m) of both, plus b's depth change per pixel around that point (a
/// quarter of the range over 5 x 5 px: pose errors on slanted surfaces and at depth edges). The
/// projection, not the measured flow, picks b's pixel: flows that fail on repetitive facades
/// land on other depths of a slanted wall. The z-scores are averaged over a (2 radius + 1)^2
/// window and returned as the z-score of that mean (mean times the square root of the count).
/// CV_32FC1, a's size; NaN where not judged: no depth in a or near the projection, an untrusted
/// flow (depth_flow infinite, see MotionSegmenter::segment), a projection outside b, a point
/// that a's other static points hide in b (more than 3 sigma behind b's z-buffer of them: the
/// background behind a pole the camera passes), or a grey value of b within 1 px of the
/// projection no closer than max_grey_error to a's (a pose error moved a thin pole's projection
/// off it). depth_a, depth_b CV_32FC1 (m, 0 = invalid), grey_a, grey_b CV_8UC1, all of camera's
/// size. occluding_b (optional): the same z-score per pixel of b, positive where b's depth is
/// nearer than the nearest static point of a that lands there (something moved in front of
/// it); NaN where no point of a lands.
cv::Mat depthDisagreement(const cv::Mat& depth_a, const cv::Mat& depth_b, const cv::Mat& grey_a,
                          const cv::Mat& grey_b, const cv::Mat& depth_flow, const SE3& T_b_a,
                          const CameraModel& camera, double sigma_a, double sigma_b,
                          double sigma_z0, cv::Mat* occluding_b = nullptr,
                          double max_grey_error = 12, int radius = 2);

/// The flow a -> b (CV_32FC2 working px, a's size) the static scene makes where a's depth is
/// measured (depth_a CV_32FC1 m, 0 = unknown; RGB-D sensor or stereo): thin structures keep
/// their own depth, which the BA grid blends with what is behind them. `fallback` (the grid's
/// prediction, same type and size) where a has no depth or the point falls behind b.
cv::Mat staticFlowFromDepth(const cv::Mat& depth_a, const SE3& T_b_a, const CameraModel& camera,
                            const cv::Mat& fallback);

/// How far (working px) the static flow a -> b of each pixel of a moves when its depth is one
/// sigma nearer in inverse depth, sigma_z = sigma_a + sigma_b (z - sigma_z0)^2 (m): the error
/// the noise of depth_a (CV_32FC1 m, 0 = unknown) gives staticFlowFromDepth. CV_32FC1, a's size;
/// +inf where depth_a has no depth or the point falls behind b.
cv::Mat flowFromDepthNoise(const cv::Mat& depth_a, const SE3& T_b_a, const CameraModel& camera,
                           double sigma_a, double sigma_b, double sigma_z0);

/// How much worse the static prediction explains b than the measured flow does, per pixel of a
/// (grey levels): the mean over a (2 radius + 1)^2 window of |b(x + predicted) - a(x)| minus
/// |b(x + measured) - a(x)|, bilinear in b. Positive where the pixel moved by itself (its
/// measured flow finds it, the static prediction lands elsewhere); near zero or negative where
/// the measured flow is wrong or both agree. CV_32FC1, a's size; NaN where no pixel of the
/// window has both ends inside b. grey_a, grey_b CV_8UC1; flows CV_32FC2 a -> b (working px,
/// predicted NaN where a has no depth).
cv::Mat photometricPreference(const cv::Mat& grey_a, const cv::Mat& grey_b, const cv::Mat& measured,
                              const cv::Mat& predicted, int radius = 2);

struct GroundParams {
  double max_range_m = 12;  // points farther than this are noisier than the threshold
  double inlier_threshold_m = 0.08;
  double max_tilt_deg = 30;           // normal from the image's vertical axis
  double min_height_m = 0.3;          // the camera above the plane
  double min_inlier_fraction = 0.05;  // of the sampled lower-half points
  int stride_px = 6;                  // between the pixels RANSAC samples
};

/// The ground the camera stands on, the static parent of objects moving on it (a road, a
/// floor): the largest plane fitted by RANSAC to depth's lower half (every stride-th pixel
/// nearer than max_range_m) whose normal lies within max_tilt_deg of the image's vertical axis
/// and that lies at least min_height_m below the camera; the planes that fail the test are
/// removed and the fit repeated (a truck's rear, a facade). In the camera frame; none when no
/// plane passes. depth CV_32FC1 (m, 0 = invalid).
std::optional<Plane> fitGroundPlane(const cv::Mat& depth, const CameraModel& camera,
                                    const GroundParams& params = {});

/// The pixels of depth's lower half nearer than max_range_m whose point lies within
/// threshold_m of the plane (camera frame). CV_8UC1 255, depth's size.
cv::Mat planePixels(const cv::Mat& depth, const CameraModel& camera, const Plane& plane,
                    double max_range_m, double threshold_m);

}  // namespace radslam
