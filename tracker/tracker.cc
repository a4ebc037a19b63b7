#include "tracker/tracker.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include <opencv2/core/utility.hpp>

#include "tracker/frontend_depth.h"
#include "tracker/tracker_internal.h"

namespace radslam {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace

Tracker::Impl::Impl(const TrackerParams& params, TrackerMode m)
    : p(params),
      mode(m),
      flow_options([&] {
        FlowOptions f;
        f.preset = params.flow_preset;
        f.finest_scale = params.flow_finest_scale;
        f.variational_iterations = params.flow_variational_iterations;
        f.patch_size = params.flow_patch_size;
        f.patch_stride = params.flow_patch_stride;
        f.spatial_propagation = params.flow_spatial_propagation;
        f.warp_smoothing_px = params.flow_warp_smoothing_px;
        f.sigma0_px = params.conf_sigma0_px;
        f.fb_gain = params.conf_fb_gain;
        f.fb_max_px = params.conf_fb_max_px;
        f.photo_scale = params.conf_photo_scale;
        f.photo_max = params.conf_photo_max;
        f.grad_gain = params.conf_grad_gain;
        f.grad_floor = params.conf_grad_floor;
        return f;
      }()),
      flow(flow_options),
      graph(params.window_size,
            params.loop_min_overlap <= 1 || params.global_ba_iterations > 0
                ? params.loop_max_kept_images
                : 0,
            params.keep_departed_edges),
      aligner([&] {
        MotionOnlyOptions m;
        m.max_iterations = params.motion_iterations;
        m.robust_kernel = parseRobustKernel(params.robust_kernel);
        m.robust_scale = params.robust_scale;
        m.min_depth_ratio = params.min_depth_ratio;
        m.depth_residual_max_jump = params.depth_residual_max_jump;
        return m;
      }()) {
  upsampling.sigma_range = p.upsample_sigma_range;
  keyframe_policy.flow_px =
      mode == TrackerMode::kMono ? p.mono_keyframe_flow_px : p.keyframe_flow_px;
  keyframe_policy.rotation_px = p.keyframe_rotation_px;
  keyframe_policy.min_valid_fraction = p.keyframe_min_valid;
  refine_options.iterations = p.refine_iterations;
  refine_options.max_shift_px = p.refine_max_shift_px;
  refine_options.brightness_offset = p.refine_brightness_offset;
  refine_options.start_check_px =
      mode == TrackerMode::kMono ? p.mono_start_check_px : p.metric_start_check_px;
  refine_options.start_check_tolerance_px = p.refine_start_check_tolerance_px;
  refine_options.start_check_iterations = p.refine_start_check_iterations;
  // Motion segmentation judges the residual a warped flow leaves; camera tracking does better
  // with the coarse start (fr1/rpy mono orientation 2.38 -> 2.33 deg) and needs no warp.
  const bool warp =
      p.frame_flow_start == "warp" || (p.frame_flow_start == "auto" && p.motion_segmentation);
  frame_warm_start = warp ? WarmStart::kWarp : WarmStart::kCoarse;
  tolerance.rotation_rad = p.resend_rotation_deg * M_PI / 180.0;
  tolerance.translation_rel = p.resend_translation_rel;
  tolerance.inv_depth_rel = p.resend_inv_depth_rel;
  tolerance.min_keyframes_between = p.resend_min_keyframes;
  ba_options.max_iterations = p.ba_iterations;
  ba_options.function_tolerance = p.ba_function_tolerance;
  ba_options.depth_residual_max_jump = p.depth_residual_max_jump;
  ba_options.robust_kernel = parseRobustKernel(p.robust_kernel);
  ba_options.robust_scale = p.robust_scale;
  ba_options.min_depth_ratio = p.min_depth_ratio;
  ba_options.min_inv_depth =
      mode == TrackerMode::kRgbd ? p.rgbd_ba_min_inv_depth : p.ba_min_inv_depth;
  ba.setOptions(ba_options);
}

Tracker::Tracker(TrackerParams params) : params_(std::move(params)) {
  validateTrackerParams(params_);
  mode_ = parseTrackerMode(params_.mode);
  if (params_.opencv_threads > 0) cv::setNumThreads(params_.opencv_threads);
  impl_ = std::make_unique<Impl>(params_, mode_);
}

Tracker::~Tracker() = default;

const GridGeometry* Tracker::geometry() const {
  return impl_->preparer ? &impl_->preparer->geometry() : nullptr;
}

const KeyframeGraph& Tracker::graph() const { return impl_->graph; }

std::unique_ptr<ImagePreparer> Tracker::Impl::makePreparer(const CameraModel& camera) const {
  const int width =
      p.working_pixels <= 0
          ? 0
          : static_cast<int>(std::lround(
                std::sqrt(p.working_pixels * static_cast<double>(camera.width) / camera.height)));
  const double readout_s =
      p.rolling_shutter_readout_s < 0 ? camera.readout_s : p.rolling_shutter_readout_s;
  return std::make_unique<ImagePreparer>(camera, width, p.grid_cell, readout_s);
}

void Tracker::Impl::setUpCamera(std::unique_ptr<ImagePreparer> first_preparer) {
  preparer = std::move(first_preparer);
  if (!p.dynamic_objects) return;
  ObjectTrackerParams object_params;
  object_params.classes = parseDynamicClasses(p.dynamic_classes);
  object_params.stride = p.object_stride;
  object_params.mask_dilation_px = p.object_mask_dilation_px;
  object_params.flow_warp_smoothing_px = p.object_flow_smoothing_px;
  object_params.window_frames = p.object_window_frames;
  if (p.motion_segmentation) {
    // Objects found by motion segmentation: a class of their own with a free joint.
    object_params.classes.push_back(DynamicClass{p.motion_class_id, JointType::kFree, -1});
    MotionSegmentationParams segmentation;
    segmentation.min_residual_px = p.motion_residual_px;
    segmentation.photometric_margin = p.motion_photometric_margin;
    segmentation.min_object_pixels = p.motion_min_pixels;
    segmentation.weak_fraction = p.motion_weak_fraction;
    segmentation.carry_grey_error = p.motion_carry_grey_error;
    segmenter = std::make_unique<MotionSegmenter>(segmentation);
  }
  objects =
      std::make_unique<ObjectTracker>(object_params, preparer->geometry().working, flow_options);
}

TrackerOutput Tracker::process(const Frame& frame) {
  const auto t0 = Clock::now();
  Impl& s = *impl_;
  const std::string where = "frame " + std::to_string(frame.frame_index) + ": ";
  // Everything that can reject the frame happens before any state changes.
  validateFrame(frame);
  if (mode_ == TrackerMode::kRgbd && frame.depth.empty()) {
    throw std::invalid_argument(where + "RGB-D mode needs a depth image");
  }
  if (mode_ == TrackerMode::kStereo && frame.right.empty()) {
    throw std::invalid_argument(where + "stereo mode needs a right image");
  }
  std::unique_ptr<ImagePreparer> first_preparer;
  if (!s.preparer) {
    first_preparer = s.makePreparer(frame.camera);
  } else if (!s.preparer->matches(frame.camera)) {
    const CameraModel& c = s.preparer->input();
    throw std::invalid_argument(where + "camera differs from the first frame's (" +
                                std::to_string(c.width) + "x" + std::to_string(c.height) +
                                " fx=" + std::to_string(c.fx) + "); one tracker, one camera");
  }
  const PreparedImage image = s.prepareFrame(first_preparer ? *first_preparer : *s.preparer, frame);
  if (first_preparer) s.setUpCamera(std::move(first_preparer));
  if (mode_ == TrackerMode::kStereo && s.baseline_m == 0) s.baseline_m = frame.baseline_m;
  s.moving = s.objects ? s.objects->movingMask(image.instance, image.class_id) : cv::Mat();

  TrackerOutput out;
  s.stats.ba_ms = 0;
  s.stats.flow_ms = 0;
  s.stats.keyframe_ba_deg = 0;
  s.segmented_instance.release();
  s.segmented_class.release();
  s.frame_depth.release();
  if (s.graph.empty()) {
    s.initialise(frame, image, &out);
  } else {
    s.track(frame, image, &out);
  }
  out.has_pose = true;
  const bool segmented = image.class_id.empty() && !s.segmented_class.empty();
  out.moving_mask = segmented ? cv::Mat(s.segmented_instance > 0) : s.moving;
  if (s.objects && (!image.class_id.empty() || segmented)) {
    PreparedImage masked = image;
    if (segmented) {
      masked.instance = s.segmented_instance;
      masked.class_id = s.segmented_class;
    }
    out.has_objects = true;
    out.objects = s.trackObjects(frame, masked, out.pose.T_world_cam);
  }
  ++s.stats.frames;
  s.stats.keyframes = s.graph.size();
  s.stats.window_size = static_cast<int>(s.graph.windowIds().size());
  s.stats.edges = static_cast<int>(s.graph.edges().size());
  s.stats.frame_ms = msSince(t0);
  out.stats = s.stats;
  return out;
}

std::vector<Keyframe> Tracker::republishKeyframes(const std::vector<int>& ids) {
  Impl& s = *impl_;
  std::vector<Keyframe> out;
  for (int id = 0; id < s.graph.size(); ++id) {
    if (!ids.empty() && std::find(ids.begin(), ids.end(), id) == ids.end()) continue;
    const KeyframeData& k = s.graph.keyframe(id);
    if (!k.color.empty() && !k.grey.empty()) out.push_back(s.keyframeMessage(id));
  }
  return out;
}

TrackerOutput Tracker::finish() {
  Impl& s = *impl_;
  TrackerOutput out;
  s.stats.ba_ms = 0;
  s.stats.flow_ms = 0;
  if (!s.graph.empty()) {
    if (params_.final_ba_iterations > 0 && s.runBa(params_.final_ba_iterations)) {
      s.updateMarginals();
    }
    if (params_.global_ba_iterations > 0) s.globalBa(&out);
    s.realignFrames(nullptr);
    s.emitChangedKeyframes(&out, true);
  }
  for (const FrameRecord& r : s.frames) {
    PoseStamped pose = s.poseMessage(r);
    if (pose.state == TrackingState::kInitializing && s.ba_ran)
      pose.state = TrackingState::kTracking;
    out.refreshed_poses.push_back(pose);
  }
  out.stats = s.stats;
  return out;
}

// ---------------------------------------------------------------------------------------------
// Frames

PoseStamped Tracker::Impl::poseMessage(const FrameRecord& r) const {
  PoseStamped pose;
  pose.header = r.header;
  pose.frame_index = r.frame_index;
  pose.state = r.state;
  pose.is_keyframe = r.is_keyframe;
  pose.T_world_cam = framePose(r);
  pose.covariance = frameCovariance(r);
  return pose;
}

SE3 Tracker::Impl::predictPose(int64_t utime) const {
  // Constant velocity from the last two frames' current estimates (they follow BA), scaled to
  // the time since the last frame; no velocity after a lost frame.
  const FrameRecord& last = frames.back();
  const SE3 T_last = framePose(last);
  if (frames.size() < 2 || last.state == TrackingState::kLost) return T_last;
  const FrameRecord& before = frames[frames.size() - 2];
  const double dt_prev = static_cast<double>(last.header.utime - before.header.utime);
  const double dt_now = static_cast<double>(utime - last.header.utime);
  double ratio = dt_prev > 0 && dt_now > 0 ? dt_now / dt_prev : 1.0;
  ratio = std::clamp(ratio, 0.0, 3.0);
  const Vec6 xi = (framePose(before).inverse() * T_last).log();
  return T_last * SE3::exp(ratio * xi);
}

PreparedImage Tracker::Impl::prepareFrame(const ImagePreparer& preparer, const Frame& frame) {
  Vec3 omega = angularVelocity();
  const CameraModel& working = preparer.geometry().working;
  if (preparer.readout() <= 0)
    return turnDepth(preparer.prepare(frame, false), frame, working, omega);
  // A first grey image turned by the motion model's angular velocity; the rotation from the
  // previous frame's image to it measures this frame interval's, which turns the image kept.
  const double dt_s = 1e-6 * static_cast<double>(frame.header.utime - previous_frame_utime);
  if (!previous_frame_pyramid.levels.empty() && dt_s > 0 && dt_s < kMaxRotationGapS) {
    const ImagePyramid first = coarsePyramid(preparer.prepareGrey(frame, omega), working,
                                             kRotationLevels[0], kRotationLevels[1]);
    const RotationAlignment rotation =
        alignRotation(previous_frame_pyramid, first, SO3::exp(-dt_s * omega), rotation_options);
    // R_b_a = R_world_b^T R_world_a = Exp(-omega dt).
    if (rotation.ok) omega = -rotation.R_b_a.log() / dt_s;
    if (rotation.ok && first_frame && graph.size() == 1) undistortFirstKeyframe(omega);
  }
  first_frame.reset();
  PreparedImage image = turnDepth(preparer.prepare(frame, false, omega), frame, working, omega);
  previous_frame_pyramid =
      coarsePyramid(image.grey, working, kRotationLevels[0], kRotationLevels[1]);
  previous_frame_utime = frame.header.utime;
  return image;
}

PreparedImage Tracker::Impl::turnDepth(PreparedImage image, const Frame& frame,
                                       const CameraModel& working, const Vec3& omega) const {
  // The depth image's exposure after the colour image's (s): R_colour_depth = Exp(dt omega).
  const double dt_s = frame.depth_time_offset_s - p.depth_delay_s;
  if (mode == TrackerMode::kRgbd && !image.depth.empty() && dt_s != 0 && !omega.isZero())
    image.depth = rotateDepth(image.depth, working, SO3::exp(dt_s * omega).matrix());
  return image;
}

Vec3 Tracker::Impl::angularVelocity() const {
  if (frames.size() < 2 || frames.back().state == TrackingState::kLost) return Vec3::Zero();
  const FrameRecord& last = frames.back();
  const FrameRecord& before = frames[frames.size() - 2];
  const double dt_s = 1e-6 * static_cast<double>(last.header.utime - before.header.utime);
  if (!(dt_s > 0)) return Vec3::Zero();
  return (framePose(before).so3().inverse() * framePose(last).so3()).log() / dt_s;
}

KeyframeData Tracker::Impl::newKeyframeData(const Frame& frame, const PreparedImage& image,
                                            const SE3& T_world_cam) {
  const GridGeometry& g = preparer->geometry();
  KeyframeData kf;
  kf.frame_index = frame.frame_index;
  kf.header = frame.header;
  kf.color = preparer->prepareColor(frame.color, image);
  kf.grey = image.grey;
  kf.gradients = imageGradients(image.grey);
  kf.structure = cellStructureTensor(kf.gradients, g.cell, moving);
  kf.right_grey = image.right_grey;
  kf.moving = moving;
  if (mode == TrackerMode::kRgbd || (segmenter && mode != TrackerMode::kMono))
    kf.depth = frameDepth(image);
  kf.ba.T_world_cam = T_world_cam;
  if (mode == TrackerMode::kRgbd) {
    sensorInverseDepth(image, &kf.sensor_inv_depth, &kf.sensor_inv_depth_var);
    setMeasuredDepth(&kf);
  }
  return kf;
}

void Tracker::Impl::sensorInverseDepth(const PreparedImage& image, cv::Mat* inv_depth,
                                       cv::Mat* inv_depth_var) const {
  const cv::Mat z = sensorDepthToGrid(image.depth, preparer->geometry().cell,
                                      p.depth_min_cell_fraction, p.depth_min_m, p.depth_max_m);
  depthPrior(z, p.depth_sigma_a, p.depth_sigma_b, p.depth_sigma_z0, inv_depth, inv_depth_var);
}

void Tracker::Impl::initialise(const Frame& frame, const PreparedImage& image, TrackerOutput* out) {
  makeKeyframe(frame, image, SE3(), nullptr, false, out);
  if (preparer->readout() > 0) first_frame = frame;
}

void Tracker::Impl::undistortFirstKeyframe(const Vec3& omega) {
  // What makeKeyframe made of the first frame, from its images turned by omega; its pose and
  // (monocular) constant inverse depth stay.
  KeyframeData& k = graph.keyframe(0);
  KeyframeData fresh = newKeyframeData(*first_frame,
                                       turnDepth(preparer->prepare(*first_frame, false, omega),
                                                 *first_frame, preparer->geometry().working, omega),
                                       k.ba.T_world_cam);
  k.color = fresh.color;
  k.grey = fresh.grey;
  k.gradients = fresh.gradients;
  // The keyframe keeps its own moving mask (fresh's is the current frame's).
  k.structure = cellStructureTensor(k.gradients, preparer->geometry().cell, k.moving);
  k.right_grey = fresh.right_grey;
  k.depth = fresh.depth;
  k.sensor_inv_depth = fresh.sensor_inv_depth;
  k.sensor_inv_depth_var = fresh.sensor_inv_depth_var;
  k.ba.measured_inv_depth = fresh.ba.measured_inv_depth;
  k.ba.measured_inv_depth_var = fresh.ba.measured_inv_depth_var;
  if (mode == TrackerMode::kRgbd) {
    k.sensor_inv_depth.copyTo(k.ba.inv_depth);
    fillInverseDepth(&k.ba.inv_depth, cv::Mat(), 1.0 / p.depth_max_m);
  }
  if (mode == TrackerMode::kStereo) initStereoDepth(0, p.init_inv_depth);
}

void Tracker::Impl::track(const Frame& frame, const PreparedImage& image, TrackerOutput* out) {
  const GridGeometry& g = preparer->geometry();
  const KeyframeData& ref = graph.last();
  frame_measured = MotionOnlyDepth();
  if (mode == TrackerMode::kRgbd && p.depth_residual_sigma_scale > 0) {
    cv::Mat inv_depth, inv_depth_var;
    sensorInverseDepth(image, &inv_depth, &inv_depth_var);
    frame_measured = measuredDepth(inv_depth, inv_depth_var, moving);
  }
  const SE3 T_pred = predictPose(frame.header.utime);

  const auto t_flow = Clock::now();
  const cv::Mat predicted = reprojectKeyframe(g.grid, ref.ba, T_pred, p.min_depth_ratio);
  const cv::Mat init = predictedFlow(predicted, g);
  // Without the dataset's masks motion segmentation judges this flow (against its keyframe's
  // own segmented objects too), so there it must show the objects move.
  const bool segmenting = segmenter && image.class_id.empty();
  const bool painting = !segmenting && !(ref.moving.empty() && moving.empty());
  // The frame has no depth to predict the backward flow: the negated forward prediction is
  // close wherever the flow is smooth. Only the backward flow and the painting use it.
  const cv::Mat init_back =
      (p.frame_backward_flow || painting) && !init.empty() ? cv::Mat(-init) : cv::Mat();
  const auto [dis_ref, dis_frame] =
      painting ? paintOutMoving(ref.grey, ref.moving, image.grey, moving, init, init_back)
               : std::make_pair(ref.grey, image.grey);
  const cv::Mat forward = flow.compute(dis_ref, dis_frame, init, frame_warm_start);
  cv::Mat backward;
  if (p.frame_backward_flow) backward = flow.compute(dis_frame, dis_ref, init_back);
  TrackedFlow tracked;
  tracked.forward = forward;
  tracked.backward = backward;
  tracked.correspondences = correspond(ref.grey, ref.gradients, ref.structure, image.grey, forward,
                                       backward, ref.moving, moving);
  const Correspondences& c = tracked.correspondences;
  stats.flow_ms += msSince(t_flow);
  stats.valid_fraction = c.valid_fraction;

  MotionOnlyResult aligned = aligner.align(
      g.grid, {ref.ba}, {MotionOnlyEdge{0, c.target, c.weight}}, T_pred, frame_measured);
  cv::Scalar mean, stddev;
  cv::meanStdDev(image.grey, mean, stddev);
  const bool lost =
      !aligned.ok || c.valid_fraction < p.lost_min_valid || stddev[0] < p.lost_min_contrast;

  if (lost) {
    ++lost_streak;
    ++stats.lost_frames;
    if (lost_streak >= p.lost_reinit_frames) {
      // Tracking has not come back: start a new window at the predicted pose.
      lost_streak = 0;
      makeKeyframe(frame, image, T_pred, nullptr, true, out);
      return;
    }
    FrameRecord r;
    r.header = frame.header;
    r.frame_index = frame.frame_index;
    r.ref_kf = ref.id;
    r.T_kf_frame = ref.ba.T_world_cam.inverse() * T_pred;
    r.state = TrackingState::kLost;
    frames.push_back(r);
    out->pose = poseMessage(r);
    out->pose.covariance = Mat6::Identity() * 1e6;  // no information
    return;
  }
  lost_streak = 0;
  if (segmenting) segmentMotion(ref, frame.frame_index, image, &tracked, &aligned);

  const Mat3 R_frame_kf = (aligned.T_world_frame.inverse() * ref.ba.T_world_cam).rotation();
  // The keyframe policy counts what the flow found, also the cells that the refinement's start
  // check keeps out of the estimate (without them fr1/rpy RGB-D made 40 keyframes, not 29).
  const FlowMotion motion = measureFlowMotion(c.target, c.weight, g.grid, R_frame_kf, c.leaning);
  stats.mean_flow_px = motion.mean_flow_px;
  stats.mean_parallax_px = motion.mean_parallax_px;
  stats.alignment_deg = (T_pred.inverse() * aligned.T_world_frame).so3().log().norm() * 180 / M_PI;
  KeyframePolicy policy = keyframe_policy;
  if (mode == TrackerMode::kMono && graph.windowIds().size() == 1) {
    // The second monocular keyframe starts the map: its BA needs a baseline, and the poses
    // before it come from constant depths, so wait for more flow than later keyframes.
    policy.flow_px = p.mono_init_flow_px;
  }
  // With metric depth the baseline relative to the scene depth decides as well: forward motion
  // makes little flow near the focus of expansion, and measured flow fails first where it is
  // largest (the near ground), so the mean flow alone keeps the keyframe until tracking breaks
  // (synthetic street at 12 m/s, 30 Hz: RGB-D ATE 16.9 m without it, 1.3 m with it). In
  // monocular mode the parallax measures the same in scene units (KITTI 07 lost accuracy with
  // both: 0.38 -> 0.46 m).
  const double baseline_ratio =
      (aligned.T_world_frame.translation() - ref.ba.T_world_cam.translation()).norm() *
      medianPositive(ref.ba.inv_depth, p.init_inv_depth);
  if (isNewKeyframe(motion, policy) ||
      (mode != TrackerMode::kMono && baseline_ratio > p.keyframe_baseline_ratio)) {
    if (mode != TrackerMode::kMono || graph.windowIds().size() != 1) {
      makeKeyframe(frame, image, aligned.T_world_frame, &tracked, false, out);
      return;
    }
    // The second monocular keyframe: two-view geometry where the translation shows, so that BA
    // does not start from the constant-depth alignment. A translation still short for
    // triangulation waits for more baseline while the first keyframe is tracked (started from
    // constant depths, forward motion while turning became rotation: KITTI 07 from frames 20
    // and 30, 11-12 m ATE), and is taken as it is when the view leaves the keyframe first.
    TwoViewOptions options;
    options.median_inv_depth = p.init_inv_depth;
    options.min_parallax_deg = p.mono_init_min_parallax_deg;
    const TwoViewResult two_view = initializeTwoView(g.grid, tracked.correspondences.target,
                                                     tracked.correspondences.weight, options);
    if (!two_view.small_parallax || motion.valid_fraction < policy.min_valid_fraction) {
      makeKeyframe(frame, image, aligned.T_world_frame, &tracked, false, out, &two_view);
      return;
    }
  }
  FrameRecord r;
  r.header = frame.header;
  r.frame_index = frame.frame_index;
  r.ref_kf = ref.id;
  r.T_kf_frame = ref.ba.T_world_cam.inverse() * aligned.T_world_frame;
  r.cov_rel = aligned.covariance;
  r.state = trackingState();
  frames.push_back(r);
  pending_frames.push_back(PendingFrame{frames.size() - 1, c.target, c.weight, frame_measured});
  out->pose = poseMessage(r);
}

void Tracker::Impl::segmentMotion(const KeyframeData& ref, int64_t frame_index,
                                  const PreparedImage& image, TrackedFlow* tracked,
                                  MotionOnlyResult* aligned) {
  const GridGeometry& g = preparer->geometry();
  constexpr float kInf = std::numeric_limits<float>::infinity();
  // Motion is judged against a keyframe at least motion_min_keyframe_age frames old: against
  // one made a frame ago a moving object has barely moved (the car at 30 Hz went undetected
  // on every frame after a new keyframe). Then the flow from it is measured too.
  const KeyframeData* judge = &ref;
  for (int id : graph.windowIds()) {
    const KeyframeData& k = graph.keyframe(id);
    if (frame_index - k.frame_index >= p.motion_min_keyframe_age) judge = &k;  // newest such
  }
  cv::Mat forward = tracked->forward, backward = tracked->backward;
  if (judge != &ref) {
    const cv::Mat init = predictedFlow(
        reprojectKeyframe(g.grid, judge->ba, aligned->T_world_frame, p.min_depth_ratio), g);
    forward = flow.compute(judge->grey, image.grey, init, frame_warm_start);
    backward = cv::Mat();
  }
  const KeyframeData& a = *judge;
  // Only flow the front end trusts is judged: occlusions and mismatches disagree with the
  // static prediction too. The confidence without masks: the keyframe's own mask must not hide
  // an object that still moves.
  const Correspondences unmasked =
      flowToCorrespondences(a.grey, image.grey, forward, backward, a.structure, g, flow_options);
  const cv::Mat& var = a.inv_depth_var.empty() ? a.ba.prior_inv_depth_var : a.inv_depth_var;
  cv::Mat sigma;
  cv::sqrt(cv::max(var, 0.0), sigma);
  DenseBaKeyframe shifted = a.ba;
  shifted.inv_depth = cv::Mat();  // (a new buffer: the copy shares the keyframe's)
  cv::add(a.ba.inv_depth, sigma, shifted.inv_depth);
  // The depth test's noise model; stereo: sigma_z = a + z^2 sigma_disparity / (fx baseline).
  const cv::Mat& depth = frameDepth(image);
  const bool stereo = mode == TrackerMode::kStereo;
  const double depth_sigma_b =
      stereo ? p.stereo_disparity_sigma_px / (g.working.fx * baseline_m) : p.depth_sigma_b;
  const double depth_sigma_z0 = stereo ? 0.0 : p.depth_sigma_z0;
  // The ground, looked for once and only when something moves: its pixels within the fit's
  // range (the ground test) and the band the objects leave out. DIS smooths an object's flow
  // across its lower edge onto the road; what lies on the ground is the objects' static parent,
  // not theirs (within 4 cm of the plane; 8 cm took more of a door that ends 5 mm above the
  // floor).
  constexpr double kObjectGroundRangeM = 40, kObjectGroundThresholdM = 0.04;
  cv::Mat ground, ground_band;
  bool ground_searched = false;
  const auto find_ground = [&] {
    if (ground_searched || depth.empty()) return;
    ground_searched = true;
    const GroundParams params;
    const std::optional<Plane> plane = fitGroundPlane(depth, g.working, params);
    if (!plane) return;
    ground = planePixels(depth, g.working, *plane, params.max_range_m, params.inlier_threshold_m);
    ground_band =
        planePixels(depth, g.working, *plane, kObjectGroundRangeM, kObjectGroundThresholdM);
  };
  const auto ground_moves = [&](const cv::Mat& instance) {
    if (p.motion_ground_max_moving >= 1 || depth.empty() || cv::countNonZero(instance) == 0)
      return false;
    find_ground();
    const int ground_count = ground.empty() ? 0 : cv::countNonZero(ground);
    return ground_count > 0 &&
           cv::countNonZero(ground & (instance > 0)) > p.motion_ground_max_moving * ground_count;
  };
  bool on_ground = false;
  MotionOnlyResult first_pose;
  // Rounds: an object the first alignment followed biases its pose, so the residuals are taken
  // again at the pose re-aligned without the object.
  for (int round = 0; round < p.motion_rounds; ++round) {
    const cv::Mat targets =
        reprojectKeyframe(g.grid, a.ba, aligned->T_world_frame, p.min_depth_ratio);
    const SE3 T_frame_a = aligned->T_world_frame.inverse() * a.ba.T_world_cam;
    // The flow change a one-sigma inverse-depth error of the keyframe makes (working px);
    // infinite (not judged) without depth or without a trusted flow.
    const cv::Mat targets_shifted =
        reprojectKeyframe(g.grid, shifted, aligned->T_world_frame, p.min_depth_ratio);
    cv::Mat depth_flow_grid(g.gridSize(), CV_32FC1);
    cv::Mat trusted_grid(g.gridSize(), CV_8UC1);
    for (int v = 0; v < depth_flow_grid.rows; ++v) {
      for (int u = 0; u < depth_flow_grid.cols; ++u) {
        const cv::Vec2f a = targets.at<cv::Vec2f>(v, u), b = targets_shifted.at<cv::Vec2f>(v, u);
        const cv::Vec3f w = unmasked.weight.at<cv::Vec3f>(v, u);
        const float change = g.cell * std::hypot(b[0] - a[0], b[1] - a[1]);
        depth_flow_grid.at<float>(v, u) =
            std::isfinite(change) && std::isfinite(sigma.at<float>(v, u)) ? change : kInf;
        trusted_grid.at<uint8_t>(v, u) = w[0] > 0 || w[2] > 0;
      }
    }
    cv::Mat depth_flow, trusted;
    cv::resize(depth_flow_grid, depth_flow, g.workingSize(), 0, 0, cv::INTER_NEAREST);
    cv::resize(trusted_grid, trusted, g.workingSize(), 0, 0, cv::INTER_NEAREST);
    // Where the keyframe measured its depth the prediction is made from it, so that depth's
    // noise bounds the prediction's error there as well as BA's marginal does. It also judges
    // pixels BA leaves to the weak prior (stereo: those that moved when the keyframe was made,
    // whose marginal is unknown; the truck alongside went unseen on every other keyframe).
    const cv::Mat noise_flow =
        a.depth.empty() ? cv::Mat()
                        : flowFromDepthNoise(a.depth, T_frame_a, g.working, p.depth_sigma_a,
                                             depth_sigma_b, depth_sigma_z0);
    for (int y = 0; y < depth_flow.rows; ++y) {
      float* d = depth_flow.ptr<float>(y);
      const float* n = noise_flow.empty() ? nullptr : noise_flow.ptr<float>(y);
      const uint8_t* t = trusted.ptr<uint8_t>(y);
      for (int x = 0; x < depth_flow.cols; ++x) {
        if (!t[x])
          d[x] = kInf;
        else if (n && std::isfinite(n[x]))
          d[x] = std::min(d[x], n[x]);
      }
    }
    cv::Mat occluding;
    const cv::Mat depth_test =
        a.depth.empty() || depth.empty()
            ? cv::Mat()
            : depthDisagreement(a.depth, depth, a.grey, image.grey, depth_flow, T_frame_a,
                                g.working, p.depth_sigma_a, depth_sigma_b, depth_sigma_z0,
                                p.motion_occlusion_test ? &occluding : nullptr);
    // Most of the image disagreeing means the pose is wrong, not that the scene moves.
    const auto too_much = [&](const cv::Mat& instance) {
      return cv::countNonZero(instance) > p.motion_max_fraction * instance.total();
    };
    // The prediction at full resolution where the keyframe has measured depth.
    const cv::Mat grid_predicted = predictedFlow(targets, g);
    const cv::Mat predicted =
        a.depth.empty() ? grid_predicted
                        : staticFlowFromDepth(a.depth, T_frame_a, g.working, grid_predicted);
    const cv::Mat photo_test = p.motion_photometric_margin > 0
                                   ? photometricPreference(a.grey, image.grey, forward, predicted)
                                   : cv::Mat();
    // No grey difference exceeds 255 levels: the test is off there.
    const cv::Mat carry_error =
        p.motion_carry_grey_error < 255 ? landingGreyError(a.grey, image.grey, forward) : cv::Mat();
    const MotionSegmenter before = *segmenter;
    cv::Mat instance = segmenter->segment(forward, predicted, depth_flow, depth_test, photo_test,
                                          carry_error, occluding);
    if (!depth_test.empty() && too_much(instance)) {
      // A pose that followed a large object makes the static scene disagree in depth nearly
      // everywhere (synthetic truck: 14.6 m ATE); then flow alone judges this round.
      *segmenter = before;
      instance = segmenter->segment(forward, predicted, depth_flow, {}, photo_test, carry_error);
    }
    if (ground_moves(instance)) {
      *segmenter = before;
      if (on_ground) {
        // Aligned on the ground, the ground moves still: keep the first pose.
        *aligned = first_pose;
        return;
      }
      // The ground is the static parent of what moves on it: when much of it disagrees, the
      // pose followed an object (a truck alongside, driving with the camera). Align on the
      // ground alone and judge this round again.
      const Correspondences c =
          correspond(ref.grey, ref.gradients, ref.structure, image.grey, tracked->forward,
                     tracked->backward, ref.moving, ground == 0);
      const MotionOnlyResult grounded =
          aligner.align(g.grid, {ref.ba}, {MotionOnlyEdge{0, c.target, c.weight}},
                        aligned->T_world_frame, frame_measured);
      if (!grounded.ok) return;
      first_pose = *aligned;
      *aligned = grounded;
      on_ground = true;
      ++stats.ground_realignments;
      --round;
      continue;
    }
    if (too_much(instance)) return;
    const cv::Mat any = instance > 0;
    if (cv::countNonZero(any) == 0) {
      segmented_instance.release();
      segmented_class.release();
      moving.release();
    } else {
      // The ground band leaves the objects' points and the published mask; camera tracking
      // keeps it out too, since its flow is the object's.
      find_ground();
      if (!ground_band.empty()) instance.setTo(0, ground_band);
      segmented_instance = instance;
      segmented_class = cv::Mat(instance.size(), CV_16UC1, cv::Scalar(0));
      segmented_class.setTo(cv::Scalar(p.motion_class_id), instance > 0);
      moving = any;
    }
    tracked->correspondences = correspond(ref.grey, ref.gradients, ref.structure, image.grey,
                                          tracked->forward, tracked->backward, ref.moving, moving);
    const Correspondences& c = tracked->correspondences;
    const MotionOnlyResult again =
        aligner.align(g.grid, {ref.ba}, {MotionOnlyEdge{0, c.target, c.weight}},
                      aligned->T_world_frame, frame_measured);
    if (again.ok) *aligned = again;
    stats.valid_fraction = c.valid_fraction;
    if (moving.empty()) return;
  }
}

void Tracker::Impl::realignFrames(const std::vector<int>* leaving) {
  const GridGeometry& g = preparer->geometry();
  std::vector<PendingFrame> kept;
  for (PendingFrame& f : pending_frames) {
    FrameRecord& r = frames[f.record];
    if (leaving && std::find(leaving->begin(), leaving->end(), r.ref_kf) == leaving->end()) {
      kept.push_back(std::move(f));
      continue;
    }
    const KeyframeData& ref = graph.keyframe(r.ref_kf);
    const MotionOnlyResult aligned = aligner.align(
        g.grid, {ref.ba}, {MotionOnlyEdge{0, f.target, f.weight}}, framePose(r), f.measured);
    if (aligned.ok) {
      r.T_kf_frame = ref.ba.T_world_cam.inverse() * aligned.T_world_frame;
      r.cov_rel = aligned.covariance;
    }
    if (!leaving) kept.push_back(std::move(f));
  }
  pending_frames = std::move(kept);
}

ObjectList Tracker::Impl::trackObjects(const Frame& frame, const PreparedImage& image,
                                       const SE3& T_world_cam) {
  ObjectFrame f;
  f.header = frame.header;
  f.frame_index = frame.frame_index;
  f.grey = image.grey;
  f.instance = image.instance;
  f.class_id = image.class_id;
  f.T_world_cam = T_world_cam;
  // Stereo: per-frame depth only where something moves.
  if (mode == TrackerMode::kRgbd || !moving.empty()) f.depth = frameDepth(image);
  return objects->track(f);
}

const cv::Mat& Tracker::Impl::frameDepth(const PreparedImage& image) {
  if (mode == TrackerMode::kRgbd) return image.depth;
  if (mode == TrackerMode::kStereo && frame_depth.empty()) {
    const auto t_flow = Clock::now();
    const double fx = preparer->geometry().working.fx;
    frame_depth = p.stereo_matcher == "sgbm"
                      ? semiGlobalStereoDepth(image.grey, image.right_grey, fx, baseline_m,
                                              p.stereo_min_depth_m)
                      : flowStereoDepth(flow.compute(image.grey, image.right_grey), fx, baseline_m);
    stats.flow_ms += msSince(t_flow);
  }
  return frame_depth;
}

// ---------------------------------------------------------------------------------------------
// Keyframes

void Tracker::Impl::makeKeyframe(const Frame& frame, const PreparedImage& image, SE3 T_world_frame,
                                 const TrackedFlow* tracked, bool restart, TrackerOutput* out,
                                 const TwoViewResult* two_view) {
  const GridGeometry& g = preparer->geometry();
  const bool first = graph.empty();
  if (two_view) {
    stats.two_view_init = two_view->ok || two_view->small_parallax;
    if (stats.two_view_init) {
      KeyframeData& prev = graph.last();
      T_world_frame = prev.ba.T_world_cam * two_view->T_b_a.inverse();
      fillInverseDepth(&prev.ba.inv_depth, two_view->inv_depth_a, p.init_inv_depth);
    }
  }
  KeyframeData kf = newKeyframeData(frame, image, T_world_frame);

  // Initial inverse depth: sensor (RGB-D) > previous keyframe carried along the flow > median.
  cv::Mat carried;
  double fallback = p.init_inv_depth;
  if (!first) {
    const KeyframeData& prev = graph.last();
    fallback = medianPositive(prev.ba.inv_depth, p.init_inv_depth);
    if (tracked) {
      const Correspondences& c = tracked->correspondences;
      carried = splatInverseDepth(prev.ba.inv_depth, c.target, c.weight,
                                  T_world_frame.inverse() * prev.ba.T_world_cam, g.grid);
    }
  }
  // RGB-D: pixels without sensor depth are mostly beyond its range (sky, far walls); as near
  // surfaces they would hold translation back.
  if (mode == TrackerMode::kRgbd) fallback = 1.0 / p.depth_max_m;
  kf.ba.inv_depth =
      cv::Mat(g.gridSize(), CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  if (mode == TrackerMode::kRgbd) kf.sensor_inv_depth.copyTo(kf.ba.inv_depth);
  if (!carried.empty()) {
    fillInverseDepth(&kf.ba.inv_depth, carried, fallback);
  } else {
    fillInverseDepth(&kf.ba.inv_depth, cv::Mat(), fallback);
  }

  const int id = graph.add(std::move(kf)).id;
  // Keyframes leaving the window keep their estimate from now on: send its final state.
  std::vector<int> leaving = graph.leaving();
  if (restart) {
    const std::vector<int> window = graph.windowIds();
    leaving.assign(window.begin(), window.end() - 1);
  }
  realignFrames(&leaving);
  for (int old : leaving) {
    if (graph.changed(old, tolerance)) out->keyframes.push_back(keyframeMessage(old));
  }
  if (restart) graph.restartWindowAtLast();
  graph.slideWindow();

  if (mode == TrackerMode::kStereo) initStereoDepth(id, fallback);

  std::vector<int> partners;
  if (!first && !restart) {
    partners =
        graph.edgePartners(id, g.grid, p.min_edge_overlap, p.max_edge_partners, p.min_depth_ratio);
  }
  const bool can_ba = graph.windowIds().size() >= 2 || mode == TrackerMode::kStereo;
  if (!partners.empty() && p.loop_min_overlap <= 1) {
    const auto t_loop = Clock::now();
    const int max_loops = mode == TrackerMode::kMono ? p.loop_max_edges : p.metric_loop_max_edges;
    for (int anchor :
         graph.loopPartners(id, g.grid, p.loop_min_overlap, max_loops, p.min_depth_ratio)) {
      if (measureLoop(id, anchor)) ++stats.loop_edges;
    }
    stats.flow_ms += msSince(t_loop);
  }
  for (int round = 0; round < p.flow_ba_rounds; ++round) {
    const auto t_flow = Clock::now();
    // The first round's flows start coarse from the motion-only pose (robust to its errors);
    // later rounds warp by BA's prediction, which measures the near ground and other fast
    // varying flow without DIS's shrinking bias.
    const WarmStart warm_start = round == 0 ? WarmStart::kCoarse : WarmStart::kWarp;
    for (int m : partners) {
      if (round == 0 && tracked && !tracked->backward.empty() && m == partners.front()) {
        // The frame's own flows against its reference keyframe are this pair's first measure.
        const KeyframeData& k = graph.keyframe(id);
        const KeyframeData& ref = graph.keyframe(m);
        const Correspondences back =
            correspond(k.grey, k.gradients, k.structure, ref.grey, tracked->backward,
                       tracked->forward, k.moving, ref.moving);
        graph.setEdge(GraphEdge{m, id, tracked->correspondences.target,
                                tracked->correspondences.weight, std::nullopt});
        graph.setEdge(GraphEdge{id, m, back.target, back.weight, std::nullopt});
      } else {
        measurePair(id, m, warm_start);
      }
    }
    if (mode == TrackerMode::kStereo && round > 0) measureStereo(id, warm_start);
    stats.flow_ms += msSince(t_flow);
    if (can_ba) runBa(p.ba_iterations);
  }
  stats.keyframe_ba_deg =
      (T_world_frame.inverse() * graph.keyframe(id).ba.T_world_cam).so3().log().norm() * 180 / M_PI;
  if (can_ba && ba_ran) updateMarginals();
  if (ba_ran && !first_ba_done) {
    first_ba_done = true;
    realignFrames(nullptr);
  }
  if (!ba_ran || graph.keyframe(id).inv_depth_var.empty()) {
    // No BA yet (monocular keyframe 0, RGB-D keyframe 0): the prior is all that is known.
    setPriors();
    KeyframeData& k = graph.keyframe(id);
    k.inv_depth_var = k.ba.prior_inv_depth_var.clone();
  }

  FrameRecord r;
  r.header = frame.header;
  r.frame_index = frame.frame_index;
  r.ref_kf = id;
  r.is_keyframe = true;
  r.state = trackingState();
  frames.push_back(r);
  emitChangedKeyframes(out);
  out->pose = poseMessage(r);
}

Correspondences Tracker::Impl::correspond(const cv::Mat& grey_a, const cv::Mat& gradients_a,
                                          const cv::Mat& structure_a, const cv::Mat& grey_b,
                                          const cv::Mat& flow_ab, const cv::Mat& flow_ba,
                                          const cv::Mat& moving_a, const cv::Mat& moving_b,
                                          const RefineOptions* refine) const {
  const GridGeometry& g = preparer->geometry();
  Correspondences c = flowToCorrespondences(grey_a, grey_b, flow_ab, flow_ba, structure_a, g,
                                            flow_options, moving_a, moving_b);
  if (p.refine_iterations > 0) {
    const RefineOptions& options = refine ? *refine : refine_options;
    refineTargets(grey_a, gradients_a, grey_b, g.cell, options, &c.target, &c.weight, moving_a,
                  options.start_check_px > 0 ? &c.leaning : nullptr);
  }
  return c;
}

std::pair<Correspondences, Correspondences> Tracker::Impl::measureBothWays(int a, int b,
                                                                           WarmStart warm_start) {
  const GridGeometry& g = preparer->geometry();
  const KeyframeData& ka = graph.keyframe(a);
  const KeyframeData& kb = graph.keyframe(b);
  const cv::Mat init_ab =
      predictedFlow(reprojectKeyframe(g.grid, ka.ba, kb.ba.T_world_cam, p.min_depth_ratio), g);
  const cv::Mat init_ba =
      predictedFlow(reprojectKeyframe(g.grid, kb.ba, ka.ba.T_world_cam, p.min_depth_ratio), g);
  const auto [dis_a, dis_b] =
      paintOutMoving(ka.grey, ka.moving, kb.grey, kb.moving, init_ab, init_ba);
  const cv::Mat f_ab = flow.compute(dis_a, dis_b, init_ab, warm_start);
  const cv::Mat f_ba = flow.compute(dis_b, dis_a, init_ba, warm_start);
  // A keyframe outside the window keeps only its grey image and structure tensor.
  auto gradients = [](const KeyframeData& k) {
    return k.gradients.empty() ? imageGradients(k.grey) : k.gradients;
  };
  // The affine fit on the pairs that BA re-measures from its own prediction (the last word on
  // every edge of a new keyframe); the first, coarse round only seeds that prediction.
  RefineOptions pair_refine = refine_options;
  if (mode == TrackerMode::kRgbd && warm_start == WarmStart::kWarp)
    pair_refine.affine_iterations = p.rgbd_pair_affine_iterations;
  pair_refine.start_check_px = mode == TrackerMode::kStereo ? p.stereo_pair_start_check_px : 0;
  return {correspond(ka.grey, gradients(ka), ka.structure, kb.grey, f_ab, f_ba, ka.moving,
                     kb.moving, &pair_refine),
          correspond(kb.grey, gradients(kb), kb.structure, ka.grey, f_ba, f_ab, kb.moving,
                     ka.moving, &pair_refine)};
}

void Tracker::Impl::measurePair(int a, int b, WarmStart warm_start) {
  const auto [c_ab, c_ba] = measureBothWays(a, b, warm_start);
  graph.setEdge(GraphEdge{a, b, c_ab.target, c_ab.weight, std::nullopt});
  graph.setEdge(GraphEdge{b, a, c_ba.target, c_ba.weight, std::nullopt});
}

bool Tracker::Impl::measureLoop(int id, int a) {
  const auto [c_ak, c_ka] = measureBothWays(a, id, WarmStart::kCoarse);
  if (c_ak.valid_fraction < p.loop_min_valid || c_ka.valid_fraction < p.loop_min_valid) {
    return false;
  }
  graph.setEdge(GraphEdge{a, id, c_ak.target, c_ak.weight, std::nullopt, a});
  graph.setEdge(GraphEdge{id, a, c_ka.target, c_ka.weight, std::nullopt, a});
  return true;
}

void Tracker::Impl::measureStereo(int id, WarmStart warm_start) {
  const GridGeometry& g = preparer->geometry();
  const KeyframeData& k = graph.keyframe(id);
  if (k.right_grey.empty() || !(baseline_m > 0)) return;
  // Right camera at +baseline along the left camera's x: T_left_right = [I | (b, 0, 0)].
  const SE3 T_left_right(SO3(), Vec3(baseline_m, 0, 0));
  cv::Mat init;  // a new window's first keyframe has no metric depth yet: DIS starts from zero
  if (graph.windowIds().size() > 1 || !k.inv_depth_var.empty()) {
    init = predictedFlow(
        reprojectKeyframe(g.grid, k.ba, k.ba.T_world_cam * T_left_right, p.min_depth_ratio), g);
  }
  const cv::Mat f_lr = flow.compute(k.grey, k.right_grey, init, warm_start);
  const cv::Mat f_rl =
      flow.compute(k.right_grey, k.grey, init.empty() ? cv::Mat() : cv::Mat(-init), warm_start);
  // The right image's objects are where the left one's are, give or take the disparity.
  const Correspondences c =
      correspond(k.grey, k.gradients, k.structure, k.right_grey, f_lr, f_rl, k.moving, k.moving);
  graph.setEdge(GraphEdge{id, -1, c.target, c.weight, T_left_right});
  // Kept with the keyframe for global BA (the window's edge goes when the keyframe leaves).
  KeyframeData& kept = graph.keyframe(id);
  kept.stereo_target = c.target;
  kept.stereo_weight = c.weight;
}

void Tracker::Impl::initStereoDepth(int id, double fallback) {
  // Metric inverse depth from the disparity where it is measured.
  measureStereo(id, WarmStart::kCoarse);
  KeyframeData& k = graph.keyframe(id);
  const GraphEdge* stereo = nullptr;
  for (const GraphEdge& e : graph.edges()) {
    if (e.i == id && e.T_i_other) stereo = &e;
  }
  if (stereo) {
    cv::Mat d = stereoInverseDepth(stereo->target, stereo->weight, preparer->geometry().grid.fx,
                                   baseline_m);
    fillInverseDepth(&d, k.ba.inv_depth, fallback);
    k.ba.inv_depth = d;
  }
}

void Tracker::Impl::setPrior(const KeyframeData& k, DenseBaKeyframe* out) const {
  // A weak prior keeps pixels without parallax determined; in RGB-D the sensor prior replaces
  // it where the sensor measured. Monocular "fixed": towards init_inv_depth, which also holds
  // the map's scale (no data constrain it); otherwise towards the keyframe's median. With
  // metric depth it is much weaker: pulling far points towards the median depth biases the
  // scale the stereo edges set.
  const double median = mode == TrackerMode::kMono && p.mono_prior_mean == "fixed"
                            ? p.init_inv_depth
                            : medianPositive(k.ba.inv_depth, p.init_inv_depth);
  const double weak_sigma =
      (mode == TrackerMode::kMono ? p.mono_prior_rel_sigma : p.metric_prior_rel_sigma) * median;
  out->prior_inv_depth = cv::Mat(k.ba.inv_depth.size(), CV_32FC1, cv::Scalar(median));
  out->prior_inv_depth_var =
      cv::Mat(k.ba.inv_depth.size(), CV_32FC1, cv::Scalar(weak_sigma * weak_sigma));
  // Monocular: the keyframe's mean is held with precision N / level_sigma^2, of which the N
  // pixels' own prior gives N / weak_sigma^2.
  out->prior_level_var = 0;
  if (mode == TrackerMode::kMono && p.mono_level_rel_sigma < p.mono_prior_rel_sigma) {
    const double level_sigma = p.mono_level_rel_sigma * median;
    const double pixels = static_cast<double>(k.ba.inv_depth.total());
    out->prior_level_var =
        1.0 / (pixels * (1.0 / (level_sigma * level_sigma) - 1.0 / (weak_sigma * weak_sigma)));
  }
  if (!k.sensor_inv_depth.empty()) {
    for (int v = 0; v < k.sensor_inv_depth.rows; ++v) {
      for (int u = 0; u < k.sensor_inv_depth.cols; ++u) {
        const float var = k.sensor_inv_depth_var.at<float>(v, u);
        if (var > 0 && std::isfinite(k.sensor_inv_depth.at<float>(v, u))) {
          out->prior_inv_depth.at<float>(v, u) = k.sensor_inv_depth.at<float>(v, u);
          out->prior_inv_depth_var.at<float>(v, u) = var;
        }
      }
    }
  }
}

MotionOnlyDepth Tracker::Impl::measuredDepth(const cv::Mat& sensor_inv_depth,
                                             const cv::Mat& sensor_inv_depth_var,
                                             const cv::Mat& moving_mask) const {
  MotionOnlyDepth out;
  if (mode != TrackerMode::kRgbd || p.depth_residual_sigma_scale <= 0 || sensor_inv_depth.empty()) {
    return out;
  }
  const double scale2 = p.depth_residual_sigma_scale * p.depth_residual_sigma_scale;
  out.inv_depth = sensor_inv_depth.clone();
  out.inv_depth_var = sensor_inv_depth_var * scale2;
  if (moving_mask.empty()) return out;
  // Cells a moving object touches measure the object, not the static scene.
  const int cell = preparer->geometry().cell;
  for (int v = 0; v < out.inv_depth.rows; ++v) {
    for (int u = 0; u < out.inv_depth.cols; ++u) {
      if (cv::countNonZero(moving_mask(cv::Rect(u * cell, v * cell, cell, cell))) > 0) {
        out.inv_depth_var.at<float>(v, u) = 0;
      }
    }
  }
  return out;
}

void Tracker::Impl::setMeasuredDepth(KeyframeData* k) const {
  const MotionOnlyDepth m = measuredDepth(k->sensor_inv_depth, k->sensor_inv_depth_var, k->moving);
  k->ba.measured_inv_depth = m.inv_depth;
  k->ba.measured_inv_depth_var = m.inv_depth_var;
}

void Tracker::Impl::setPriors() {
  for (int id : graph.windowIds()) {
    KeyframeData& k = graph.keyframe(id);
    setPrior(k, &k.ba);
  }
}

DenseBaGauge Tracker::Impl::gauge(const DenseBaProblem& problem) const {
  if (mode != TrackerMode::kMono || p.mono_gauge == "first_pose") return DenseBaGauge::kFirstPose;
  if (p.mono_gauge == "first_two_poses") {
    return problem.keyframes.size() >= 2 ? DenseBaGauge::kFirstTwoPoses : DenseBaGauge::kFirstPose;
  }
  if (problem.keyframes.size() >= 2) {
    // Fixing a degenerate baseline (pure rotation) would fix noise; the prior keeps the
    // scale then.
    const double baseline = (problem.keyframes[1].T_world_cam.translation() -
                             problem.keyframes[0].T_world_cam.translation())
                                .norm();
    const double depth = 1.0 / medianPositive(problem.keyframes[0].inv_depth, 1.0);
    if (baseline > 1e-4 * depth) return DenseBaGauge::kFirstPoseAndScale;
  }
  return DenseBaGauge::kFirstPose;
}

void Tracker::Impl::globalBa(TrackerOutput* out) {
  const auto t0 = Clock::now();
  const GridGeometry& g = preparer->geometry();
  std::vector<GraphEdge> edges;
  for (const auto& [a, b] :
       graph.globalPairs(g.grid, p.global_min_overlap, p.global_max_partners, p.min_depth_ratio)) {
    const auto [c_ab, c_ba] = measureBothWays(a, b, WarmStart::kWarp);
    if (c_ab.valid_fraction < p.loop_min_valid || c_ba.valid_fraction < p.loop_min_valid) continue;
    edges.push_back(GraphEdge{a, b, c_ab.target, c_ab.weight, std::nullopt});
    edges.push_back(GraphEdge{b, a, c_ba.target, c_ba.weight, std::nullopt});
  }
  stats.flow_ms += msSince(t0);
  if (edges.empty()) return;
  if (mode == TrackerMode::kStereo) {
    const SE3 T_left_right(SO3(), Vec3(baseline_m, 0, 0));
    std::vector<int> joined;
    for (const GraphEdge& e : edges) joined.push_back(e.i);
    std::sort(joined.begin(), joined.end());
    joined.erase(std::unique(joined.begin(), joined.end()), joined.end());
    for (int id : joined) {
      const KeyframeData& k = graph.keyframe(id);
      if (!k.stereo_target.empty()) {
        edges.push_back(GraphEdge{id, -1, k.stereo_target, k.stereo_weight, T_left_right});
      }
    }
  }
  std::vector<int> ids;
  DenseBaProblem problem = graph.buildProblem(g.grid, edges, &ids);
  for (size_t n = 0; n < ids.size(); ++n) setPrior(graph.keyframe(ids[n]), &problem.keyframes[n]);
  DenseBaOptions options = ba_options;
  options.max_iterations = p.global_ba_iterations;
  options.gauge = gauge(problem);
  ba.setOptions(options);
  const DenseBaSummary summary = ba.optimize(&problem);
  stats.ba_ms += summary.total_ms;
  if (!summary.ok) return;
  graph.writeBack(problem, ids);
  const auto t_marginals = Clock::now();
  graph.setMarginals(ba.computeMarginals(problem), ids);
  stats.ba_ms += msSince(t_marginals);
  for (int id : ids) {
    KeyframeData& k = graph.keyframe(id);
    if (k.in_window) continue;
    // A departed keyframe stays an anchor (tracking may go on), now at the global estimate.
    graph.anchor(id);
    if (!k.color.empty() && graph.changed(id, tolerance)) {
      out->keyframes.push_back(keyframeMessage(id));
    }
  }
  stats.global_ba_edges = static_cast<int>(edges.size());
}

bool Tracker::Impl::runBa(int iterations) {
  const std::vector<int> window = graph.windowIds();
  bool has_stereo = false;
  for (const GraphEdge& e : graph.edges()) has_stereo |= e.T_i_other.has_value();
  if (window.size() < 2 && !has_stereo) return false;
  const GridGeometry& g = preparer->geometry();
  setPriors();
  std::vector<int> ids;
  DenseBaProblem problem = graph.buildProblem(g.grid, &ids);
  DenseBaOptions options = ba_options;
  options.max_iterations = iterations;
  options.gauge = gauge(problem);
  ba.setOptions(options);
  const DenseBaSummary summary = ba.optimize(&problem);
  stats.ba_ms += summary.total_ms;
  stats.ba_cost = summary.final_cost;
  stats.ba_iterations = summary.iterations;
  if (!summary.ok) return false;
  graph.writeBack(problem, ids);
  ba_ran = true;
  return true;
}

void Tracker::Impl::updateMarginals() {
  const auto t0 = Clock::now();
  std::vector<int> ids;
  const DenseBaProblem problem = graph.buildProblem(preparer->geometry().grid, &ids);
  const DenseBaMarginals marginals = ba.computeMarginals(problem);
  graph.setMarginals(marginals, ids);
  stats.ba_ms += msSince(t0);
}

Keyframe Tracker::Impl::keyframeMessage(int id) {
  const GridGeometry& g = preparer->geometry();
  KeyframeData& k = graph.keyframe(id);
  Keyframe msg;
  msg.header = k.header;
  msg.keyframe_id = id;
  msg.version = graph.markSent(id);
  msg.frame_index = k.frame_index;
  msg.T_world_cam = k.ba.T_world_cam;
  msg.covariance = k.covariance;
  msg.camera = g.working;
  msg.color = k.color;
  msg.dynamic_mask = k.moving;
  cv::Mat var = k.inv_depth_var;
  if (var.empty()) {
    var = cv::Mat(k.ba.inv_depth.size(), CV_32FC1,
                  cv::Scalar(std::numeric_limits<float>::infinity()));
  }
  UpsampledDepth up = upsampleDepth(k.ba.inv_depth, var, k.grey, g.cell, upsampling);
  if (mode == TrackerMode::kRgbd && !k.depth.empty() && !k.sensor_inv_depth.empty()) {
    // The sensor's pixels within its range, with their own noise, moved by BA's correction.
    cv::Mat z(k.depth.size(), CV_32FC1, cv::Scalar(0)), sensor_inv, sensor_var;
    k.depth.copyTo(z, (k.depth >= p.depth_min_m) & (k.depth <= p.depth_max_m));
    depthPrior(z, p.depth_sigma_a, p.depth_sigma_b, p.depth_sigma_z0, &sensor_inv, &sensor_var);
    // BA's correction where the sensor measured the cell (NaN, with zero variance, elsewhere).
    const cv::Mat correction_grid = k.ba.inv_depth - k.sensor_inv_depth;
    addSensorDetail(
        sensor_inv, sensor_var,
        upsampleDepth(correction_grid, k.sensor_inv_depth_var, k.grey, g.cell, upsampling)
            .inv_depth,
        &up);
  }
  msg.inv_depth = up.inv_depth;
  msg.inv_depth_var = up.inv_depth_var;
  msg.depth = up.depth;
  msg.depth_var = up.depth_var;
  return msg;
}

void Tracker::Impl::emitChangedKeyframes(TrackerOutput* out, bool now) {
  for (int id : graph.toSend(tolerance, now)) out->keyframes.push_back(keyframeMessage(id));
}

}  // namespace radslam
