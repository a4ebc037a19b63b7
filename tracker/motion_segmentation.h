// Geometric motion segmentation for sequences without instance masks (DESIGN.md section 5):
// pixels whose measured flow disagrees with the flow the static scene predicts, clustered into
// objects whose ids persist from frame to frame.
//
/// For a keyframe a and a frame b: the measured flow a -> b, and the flow a's depths would make
/// if everything were static and the camera moved to b's estimated pose. Where they differ by
/// more than min_residual_px, plus relative_residual of the predicted flow, plus what the depth's
/// uncertainty explains (depth_sigmas times the flow change of a one-sigma depth error), the
/// pixel moved by itself; pixels of unknown depth
/// (sky, beyond the sensor's range) cannot be judged. Those pixels are carried along the
/// measured flow into b, closed, split into connected components, and components smaller than
/// min_object_pixels are dropped. A component keeps the id of the previous frame's component it
/// overlaps most (intersection over union at least min_overlap), or gets a new one.
#pragma once

#include <opencv2/core.hpp>

namespace radslam {

struct MotionSegmentationParams {
  double min_residual_px = 2.0;  // working px between measured and predicted flow
  double depth_sigmas = 3.0;     // depth uncertainty allowed for, in standard deviations
  /// Fraction of the predicted flow allowed for: long flows (near ground under forward motion,
  /// many frames from the keyframe) fail by more.
  double relative_residual = 0.25;
  int min_object_pixels = 400;  // working px of b; smaller components are noise
  int close_px = 3;             // working px, radius of the closing that fills splat holes
  double min_overlap = 0.3;     // IoU with a previous component to keep its id
  int first_id = 200;           // instance ids handed out from here on (0 = static)
};

class MotionSegmenter {
 public:
  /// Throws std::invalid_argument on out-of-range parameters.
  explicit MotionSegmenter(const MotionSegmentationParams& params = {});

  /// measured, predicted: CV_32FC2 flows a -> b (working px, a's size); predicted NaN where a has
  /// no depth. depth_flow (CV_32FC1, a's size, optional): working px the predicted flow moves by
  /// for a one-sigma error of a's depth (+inf: unknown depth). Returns b's instance mask
  /// (CV_16UC1, a's size, 0 = static): one id per moving object, stable across calls.
  cv::Mat segment(const cv::Mat& measured, const cv::Mat& predicted,
                  const cv::Mat& depth_flow = {});

  /// Forgets the previous frame's components (ids are not reused).
  void reset() { previous_.release(); }

 private:
  MotionSegmentationParams params_;
  cv::Mat previous_;  // last instance mask
  int next_id_;
};

}  // namespace radslam
