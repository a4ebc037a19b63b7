// Tracker::Impl, shared by tracker/tracker.cc (tracking) and tracker/tracker_checkpoint.cc
// (its state on disk). Not part of the tracker's interface.
#pragma once

#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "tracker/frontend_refine.h"
#include "tracker/mono_init.h"
#include "tracker/motion_only.h"
#include "tracker/motion_segmentation.h"
#include "tracker/object_tracker.h"
#include "tracker/rotation_alignment.h"
#include "tracker/tracker.h"

namespace radslam {

/// A frame's pose, kept relative to its reference keyframe so that it follows BA.
struct FrameRecord {
  Header header;
  int64_t frame_index = 0;
  int ref_kf = 0;
  SE3 T_kf_frame;               // identity for keyframes
  Mat6 cov_rel = Mat6::Zero();  // covariance of the frame pose given the keyframe's
  TrackingState state = TrackingState::kTracking;
  bool is_keyframe = false;
};

/// Covariance of T_world_frame = T_world_kf T_kf_frame from the keyframe's covariance and the
/// relative one (independent): a right perturbation of T_world_kf moves the frame by
/// Ad(T_frame_kf) delta.
/// A frame aligned again later (Tracker::Impl::pending_frames): its record and its grid
/// correspondences to its keyframe.
struct PendingFrame {
  size_t record = 0;  // index into Tracker::Impl::frames
  cv::Mat target, weight;
  MotionOnlyDepth measured;  // RGB-D: the frame's measured grid depth
};

inline Mat6 composeCovariance(const Mat6& cov_kf, const SE3& T_kf_frame, const Mat6& cov_rel) {
  const Mat6 Ad = T_kf_frame.inverse().adjoint();
  return Ad * cov_kf * Ad.transpose() + cov_rel;
}

struct Tracker::Impl {
  Impl(const TrackerParams& p, TrackerMode mode);

  // Per-frame steps.
  /// The image preparer for the first frame's camera (working size from working_pixels).
  std::unique_ptr<ImagePreparer> makePreparer(const CameraModel& camera) const;
  /// What the first frame sets up once its images passed: the preparer, the object tracker
  /// and the motion segmenter (when on).
  void setUpCamera(std::unique_ptr<ImagePreparer> first_preparer);
  void initialise(const Frame& frame, const PreparedImage& image, TrackerOutput* out);
  void track(const Frame& frame, const PreparedImage& image, TrackerOutput* out);
  /// The flows of the frame against its reference keyframe (the last keyframe).
  struct TrackedFlow {
    cv::Mat forward, backward;  // keyframe -> frame, frame -> keyframe (may be empty)
    Correspondences correspondences;
  };
  /// two_view: the second monocular keyframe's two-view geometry against the first (nullptr:
  /// none); when ok it gives the keyframe's pose and the first keyframe's inverse depths.
  void makeKeyframe(const Frame& frame, const PreparedImage& image, SE3 T_world_frame,
                    const TrackedFlow* tracked, bool restart, TrackerOutput* out,
                    const TwoViewResult* two_view = nullptr);

  KeyframeData newKeyframeData(const Frame& frame, const PreparedImage& image,
                               const SE3& T_world_cam);
  SE3 predictPose(int64_t utime) const;
  /// The camera's angular velocity (rad/s, camera frame) by the motion model; zero without one.
  Vec3 angularVelocity() const;
  /// The frame at working resolution; with a rolling shutter, as seen at its middle row.
  PreparedImage prepareFrame(const ImagePreparer& preparer, const Frame& frame);
  /// The frame's prepared depth seen from the colour image's pose: turned by the rotation at
  /// angular velocity omega (rad/s, camera frame) between the two exposures (the frame's
  /// depth_time_offset_s minus depth_delay_s); working: the prepared images' camera.
  PreparedImage turnDepth(PreparedImage image, const Frame& frame, const CameraModel& working,
                          const Vec3& omega) const;
  SE3 framePose(const FrameRecord& r) const {
    return graph.keyframe(r.ref_kf).ba.T_world_cam * r.T_kf_frame;
  }
  Mat6 frameCovariance(const FrameRecord& r) const {
    return composeCovariance(graph.keyframe(r.ref_kf).covariance, r.T_kf_frame, r.cov_rel);
  }
  PoseStamped poseMessage(const FrameRecord& r) const;

  /// Grid correspondences a -> b from the flows (confidence from both), refined per cell.
  /// Pixels of moving objects (working-size masks, may be empty) are left out. `refine`:
  /// options other than refine_options (keyframe pairs).
  Correspondences correspond(const cv::Mat& grey_a, const cv::Mat& gradients_a,
                             const cv::Mat& structure_a, const cv::Mat& grey_b,
                             const cv::Mat& flow_ab, const cv::Mat& flow_ba,
                             const cv::Mat& moving_a, const cv::Mat& moving_b,
                             const RefineOptions* refine = nullptr) const;

  // Keyframe pairs, BA and output.
  /// Flow a -> b and b -> a warm-started from the current estimate, as correspondences.
  std::pair<Correspondences, Correspondences> measureBothWays(int a, int b, WarmStart warm_start);
  void measurePair(int a, int b, WarmStart warm_start);
  /// Loop edges between window keyframe id and anchor a; false (no edge) when too few pixels
  /// are tracked.
  bool measureLoop(int id, int a);
  void measureStereo(int id, WarmStart warm_start);
  /// Measures keyframe id's stereo edge and sets its inverse depth from the disparity where
  /// there is one, else from its current one, else fallback.
  void initStereoDepth(int id, double fallback);
  /// The inverse-depth prior of keyframe k (sensor depth where measured, else weak) into *out.
  void setPrior(const KeyframeData& k, DenseBaKeyframe* out) const;
  void setPriors();
  // RGB-D: the sensor's grid depth as the measurement of BA's and the alignment's depth
  // residual (empty when off), without the cells a moving object touches.
  MotionOnlyDepth measuredDepth(const cv::Mat& sensor_inv_depth,
                                const cv::Mat& sensor_inv_depth_var,
                                const cv::Mat& moving_mask) const;
  void setMeasuredDepth(KeyframeData* k) const;
  // RGB-D: the sensor's depth on the grid as inverse depth with the noise model's variance.
  void sensorInverseDepth(const PreparedImage& image, cv::Mat* inv_depth,
                          cv::Mat* inv_depth_var) const;
  DenseBaGauge gauge(const DenseBaProblem& problem) const;
  /// Global BA over every keyframe that kept its image (finish()): flow edges between each and
  /// its most overlapping others, warm-started by the final estimate, then one BA over all.
  void globalBa(TrackerOutput* out);
  bool runBa(int iterations);
  void updateMarginals();
  /// New keyframes and changed ones that are due (all changed ones when `now`).
  void emitChangedKeyframes(TrackerOutput* out, bool now = false);
  Keyframe keyframeMessage(int id);
  TrackingState trackingState() const {
    return mode == TrackerMode::kMono && !ba_ran ? TrackingState::kInitializing
                                                 : TrackingState::kTracking;
  }

  TrackerParams p;
  TrackerMode mode;
  FlowOptions flow_options;
  RefineOptions refine_options;
  WarmStart frame_warm_start = WarmStart::kCoarse;
  KeyframePolicy keyframe_policy;
  DepthUpsamplingOptions upsampling;
  ResendTolerance tolerance;
  DenseBaOptions ba_options;

  std::unique_ptr<ImagePreparer> preparer;
  DenseFlow flow;
  KeyframeGraph graph;
  DenseBundleAdjuster ba;
  MotionOnlyAligner aligner;
  std::vector<FrameRecord> frames;
  double baseline_m = 0;  // stereo
  bool ba_ran = false;
  bool first_ba_done = false;  // frames were aligned again after the first BA
  /// Frames are aligned against their keyframe's depths of the moment; BA refines those depths
  /// while the keyframe is in the window (monocular frames before the first BA even see
  /// constant depths). Their correspondences are kept and they are aligned again after the
  /// first BA, when their keyframe leaves the window (its estimate is final then) and in
  /// finish(): memory stays bounded by the window.
  std::vector<PendingFrame> pending_frames;
  /// Moving objects: null until the first frame (it needs the working camera) or when
  /// dynamic_objects is off. moving: the frame's mask (working size, 255 = moving object;
  /// empty: nothing moves).
  std::unique_ptr<ObjectTracker> objects;
  cv::Mat moving;
  /// Frames without class masks: moving objects from the flow (null when off), and this
  /// frame's instance and class masks from it (empty when nothing moves).
  std::unique_ptr<MotionSegmenter> segmenter;
  cv::Mat segmented_instance, segmented_class;
  cv::Mat frame_depth;             // stereo: the current frame's depth once frameDepth computed it
  MotionOnlyDepth frame_measured;  // RGB-D: the current frame's measuredDepth()
  /// The current frame's metric depth (CV_32FC1 working size, m, 0 = unknown): the sensor's
  /// (RGB-D) or from one more flow, left to right (stereo, computed once per frame); empty in
  /// monocular mode.
  const cv::Mat& frameDepth(const PreparedImage& image);
  /// Segments the frame's moving pixels from its flow to the reference keyframe; where some
  /// move, their correspondences are measured again without them and the frame re-aligned.
  void segmentMotion(const KeyframeData& ref, int64_t frame_index, const PreparedImage& image,
                     TrackedFlow* tracked, MotionOnlyResult* aligned);
  /// The frame's objects from its depth (sensor or stereo) and its final pose.
  ObjectList trackObjects(const Frame& frame, const PreparedImage& image, const SE3& T_world_cam);
  /// Aligns the pending frames again; with `leaving`, only those of these keyframes, which are
  /// then dropped.
  void realignFrames(const std::vector<int>* leaving);
  int lost_streak = 0;
  TrackerStats stats;

  // Rolling shutter: the previous frame's image at the levels that measure the rotation from
  // it (working / 4 and / 8: 96 x 72 and 48 x 36 px for 4:3 input), and its time.
  static constexpr int kRotationLevels[2] = {2, 3};
  static constexpr double kMaxRotationGapS = 0.2;  // a longer gap: the motion model alone
  RotationAlignmentOptions rotation_options;
  ImagePyramid previous_frame_pyramid;
  int64_t previous_frame_utime = 0;  // us
  /// The first frame, kept until the second measures the angular velocity that keyframe 0 was
  /// made without (rolling shutter only; not in checkpoints: a run resumed before its second
  /// frame keeps keyframe 0 as made).
  std::optional<Frame> first_frame;
  /// Makes keyframe 0's images again from first_frame, turned by omega (rad/s, camera frame).
  void undistortFirstKeyframe(const Vec3& omega);
};

}  // namespace radslam
