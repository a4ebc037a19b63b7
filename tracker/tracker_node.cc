#include "tracker/tracker_node.h"

#include <malloc.h>
#include <unistd.h>
#include <algorithm>
#include <chrono>
#include <iostream>
#include <stdexcept>
#include <thread>

#include "common/cli.h"
#include "common/control.h"
#include "common/params.h"
#include "tracker/object_tracker.h"

namespace radslam {
namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

constexpr int kKeyframeGapMs = 50;             // between keyframes of one burst (~40 MB/s at most)
constexpr int kRepublishGapMs = 200;           // between re-published keyframes (~10 MB/s)
constexpr double kRewindRequestPeriodS = 1.0;  // CONTROL REWIND repeated until frames come

// Warn about the first few of a kind, then every 100th, so a bad stream cannot flood the log.
bool shouldWarn(int64_t count) { return count <= 5 || count % 100 == 0; }

void check(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("tracker parameter " + what);
}

}  // namespace

TrackerMode parseTrackerMode(const std::string& name) {
  if (name == "mono") return TrackerMode::kMono;
  if (name == "rgbd") return TrackerMode::kRgbd;
  if (name == "stereo") return TrackerMode::kStereo;
  throw std::invalid_argument("tracker mode '" + name + "' is unknown (mono, rgbd, stereo)");
}

const char* trackerModeName(TrackerMode mode) {
  switch (mode) {
    case TrackerMode::kMono:
      return "mono";
    case TrackerMode::kRgbd:
      return "rgbd";
    case TrackerMode::kStereo:
      return "stereo";
  }
  return "?";
}

void validateTrackerParams(const TrackerParams& p) {
  parseTrackerMode(p.mode);
  check(p.opencv_threads >= 0, "opencv_threads must be >= 0");
  check(p.working_pixels >= 0, "working_pixels must be >= 0 (0 = input size)");
  check(std::abs(p.depth_delay_s) < 1, "depth_delay_s must be within 1 s");
  check(p.rolling_shutter_readout_s < 1,
        "rolling_shutter_readout_s must be below 1 s (negative: the camera's own)");
  check(p.grid_cell >= 2 && p.grid_cell <= 32, "grid_cell must be in [2, 32]");
  check(p.flow_preset == "ultrafast" || p.flow_preset == "fast" || p.flow_preset == "medium",
        "flow_preset must be ultrafast, fast or medium");
  check(p.frame_flow_start == "auto" || p.frame_flow_start == "warp" ||
            p.frame_flow_start == "coarse",
        "frame_flow_start must be auto, warp or coarse");
  check(p.flow_finest_scale >= 0 && p.flow_finest_scale <= 6,
        "flow_finest_scale must be in [0, 6]");
  check(p.flow_variational_iterations >= 0, "flow_variational_iterations must be >= 0");
  check(p.flow_patch_size >= 4 && p.flow_patch_stride >= 1 &&
            p.flow_patch_stride <= p.flow_patch_size,
        "flow_patch_size >= 4 and 1 <= flow_patch_stride <= flow_patch_size");
  check(p.conf_sigma0_px > 0, "conf_sigma0_px must be > 0");
  check(p.conf_grad_floor > 0, "conf_grad_floor must be > 0");
  check(p.conf_fb_gain >= 0 && p.conf_grad_gain >= 0, "conf_fb_gain, conf_grad_gain must be >= 0");
  check(p.conf_fb_max_px > 0 && p.conf_photo_max > 0 && p.conf_photo_scale > 0,
        "conf_fb_max_px, conf_photo_max, conf_photo_scale must be > 0");
  check(p.refine_iterations >= 0 && p.refine_max_shift_px > 0,
        "refine_iterations >= 0, refine_max_shift_px > 0");
  check(p.rgbd_pair_affine_iterations >= 0, "rgbd_pair_affine_iterations >= 0");
  check(p.mono_start_check_px >= 0 && p.metric_start_check_px >= 0 &&
            p.stereo_pair_start_check_px >= 0 && p.refine_start_check_tolerance_px > 0 &&
            p.refine_start_check_iterations >= 1,
        "mono_start_check_px, metric_start_check_px and stereo_pair_start_check_px >= 0, "
        "refine_start_check_tolerance_px > 0, refine_start_check_iterations >= 1");
  check(p.keyframe_flow_px > 0, "keyframe_flow_px must be > 0");
  check(p.mono_keyframe_flow_px > 0, "mono_keyframe_flow_px must be > 0");
  check(p.keyframe_rotation_px > 0, "keyframe_rotation_px must be > 0");
  check(p.keyframe_min_valid >= 0 && p.keyframe_min_valid < 1, "keyframe_min_valid in [0, 1)");
  check(p.keyframe_baseline_ratio > 0, "keyframe_baseline_ratio must be > 0");
  check(p.window_size >= 2, "window_size must be >= 2");
  check(p.max_edge_partners >= 1, "max_edge_partners must be >= 1");
  check(p.min_edge_overlap >= 0 && p.min_edge_overlap <= 1, "min_edge_overlap in [0, 1]");
  check(p.flow_ba_rounds >= 1, "flow_ba_rounds must be >= 1");
  check(p.loop_min_overlap >= 0, "loop_min_overlap must be >= 0 (> 1 disables loop edges)");
  check(p.loop_min_valid >= 0 && p.loop_min_valid <= 1, "loop_min_valid in [0, 1]");
  check(p.loop_max_edges >= 1 && p.metric_loop_max_edges >= 1,
        "loop_max_edges and metric_loop_max_edges must be >= 1");
  check(p.loop_max_kept_images >= 0, "loop_max_kept_images must be >= 0");
  check(p.ba_iterations >= 1 && p.final_ba_iterations >= 0,
        "ba_iterations >= 1, final_ba_iterations >= 0");
  check(p.ba_function_tolerance >= 0, "ba_function_tolerance >= 0");
  check(p.global_ba_iterations >= 0 && p.global_max_partners >= 0 && p.global_min_overlap >= 0,
        "global_ba_iterations, global_max_partners and global_min_overlap must be >= 0");
  check(p.robust_kernel == "huber" || p.robust_kernel == "cauchy",
        "robust_kernel must be huber or cauchy");
  check(p.robust_scale >= 0, "robust_scale must be >= 0 (0 = none)");
  check(p.min_depth_ratio > 0 && p.min_depth_ratio < 1, "min_depth_ratio in (0, 1)");
  check(p.ba_min_inv_depth > 0 && p.rgbd_ba_min_inv_depth > 0,
        "ba_min_inv_depth and rgbd_ba_min_inv_depth must be > 0");
  check(p.mono_gauge == "first_pose" || p.mono_gauge == "first_pose_and_scale" ||
            p.mono_gauge == "first_two_poses",
        "mono_gauge must be first_pose, first_pose_and_scale or first_two_poses");
  check(p.mono_prior_mean == "fixed" || p.mono_prior_mean == "median",
        "mono_prior_mean must be fixed or median");
  check(p.init_inv_depth > 0, "init_inv_depth must be > 0");
  check(p.mono_init_flow_px > 0, "mono_init_flow_px must be > 0");
  check(p.mono_init_min_parallax_deg >= 0, "mono_init_min_parallax_deg must be >= 0");
  check(p.mono_prior_rel_sigma > 0, "mono_prior_rel_sigma must be > 0");
  check(p.mono_level_rel_sigma > 0, "mono_level_rel_sigma must be > 0");
  check(p.metric_prior_rel_sigma > 0, "metric_prior_rel_sigma must be > 0");
  check(p.depth_sigma_a > 0 && p.depth_sigma_b >= 0, "depth_sigma_a > 0, depth_sigma_b >= 0");
  check(p.depth_residual_sigma_scale >= 0, "depth_residual_sigma_scale must be >= 0");
  check(p.depth_residual_max_jump > 0, "depth_residual_max_jump must be > 0");
  check(p.depth_min_m > 0 && p.depth_max_m > p.depth_min_m, "0 < depth_min_m < depth_max_m");
  check(p.depth_min_cell_fraction > 0 && p.depth_min_cell_fraction <= 1,
        "depth_min_cell_fraction in (0, 1]");
  check(p.motion_iterations >= 1, "motion_iterations must be >= 1");
  check(p.lost_min_valid >= 0 && p.lost_min_valid < 1, "lost_min_valid in [0, 1)");
  check(p.lost_min_contrast >= 0, "lost_min_contrast must be >= 0");
  check(p.lost_reinit_frames >= 1, "lost_reinit_frames must be >= 1");
  check(p.upsample_sigma_range > 0, "upsample_sigma_range must be > 0");
  check(p.resend_rotation_deg >= 0 && p.resend_translation_rel >= 0 && p.resend_inv_depth_rel >= 0,
        "resend tolerances must be >= 0");
  check(p.resend_min_keyframes >= 1, "resend_min_keyframes must be >= 1");
  check(p.object_stride >= 1, "object_stride must be >= 1");
  check(p.object_mask_dilation_px >= 0, "object_mask_dilation_px must be >= 0");
  check(p.motion_residual_px > 0 && p.motion_min_pixels >= 1 && p.motion_class_id >= 1 &&
            p.motion_class_id <= 65535,
        "motion_residual_px > 0, motion_min_pixels >= 1, motion_class_id in [1, 65535]");
  check(p.motion_rounds >= 1 && p.motion_max_fraction > 0 && p.motion_max_fraction <= 1,
        "motion_rounds >= 1, motion_max_fraction in (0, 1]");
  check(p.stereo_disparity_sigma_px > 0, "stereo_disparity_sigma_px > 0");
  check(p.stereo_matcher == "flow" || p.stereo_matcher == "sgbm",
        "stereo_matcher must be flow or sgbm, not '" + p.stereo_matcher + "'");
  check(p.stereo_min_depth_m > 0, "stereo_min_depth_m must be > 0");
  check(p.motion_photometric_margin >= 0, "motion_photometric_margin must be >= 0");
  check(p.motion_weak_fraction > 0 && p.motion_weak_fraction <= 1,
        "motion_weak_fraction in (0, 1]");
  check(p.motion_carry_grey_error >= 0, "motion_carry_grey_error must be >= 0");
  check(p.motion_min_keyframe_age >= 0, "motion_min_keyframe_age must be >= 0");
  check(p.motion_ground_max_moving > 0 && p.motion_ground_max_moving <= 1,
        "motion_ground_max_moving must be in (0, 1]");
  check(p.object_flow_smoothing_px >= 0, "object_flow_smoothing_px must be >= 0");
  check(p.object_window_frames >= 1, "object_window_frames must be >= 1");
  parseDynamicClasses(p.dynamic_classes);  // throws naming the bad item
}

void keepImageAllocationsMapped() {
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
}

TrackerParams loadTrackerParams(const std::string& yaml_path,
                                const std::vector<std::string>& overrides, std::string* dump,
                                std::string* source) {
  TrackerParams p;
  ParamReader r(yaml_path, "tracker");
  for (const std::string& o : overrides) r.addOverride(o);
  r.get("mode", &p.mode);
  r.get("opencv_threads", &p.opencv_threads);
  r.get("working_pixels", &p.working_pixels);
  r.get("grid_cell", &p.grid_cell);
  r.get("rolling_shutter_readout_s", &p.rolling_shutter_readout_s);
  r.get("depth_delay_s", &p.depth_delay_s);
  r.get("flow_preset", &p.flow_preset);
  r.get("flow_finest_scale", &p.flow_finest_scale);
  r.get("flow_variational_iterations", &p.flow_variational_iterations);
  r.get("flow_patch_size", &p.flow_patch_size);
  r.get("flow_patch_stride", &p.flow_patch_stride);
  r.get("flow_spatial_propagation", &p.flow_spatial_propagation);
  r.get("frame_flow_start", &p.frame_flow_start);
  r.get("flow_warp_smoothing_px", &p.flow_warp_smoothing_px);
  r.get("frame_backward_flow", &p.frame_backward_flow);
  r.get("conf_sigma0_px", &p.conf_sigma0_px);
  r.get("conf_fb_gain", &p.conf_fb_gain);
  r.get("conf_fb_max_px", &p.conf_fb_max_px);
  r.get("conf_photo_scale", &p.conf_photo_scale);
  r.get("conf_photo_max", &p.conf_photo_max);
  r.get("conf_grad_gain", &p.conf_grad_gain);
  r.get("conf_grad_floor", &p.conf_grad_floor);
  r.get("refine_iterations", &p.refine_iterations);
  r.get("refine_max_shift_px", &p.refine_max_shift_px);
  r.get("refine_brightness_offset", &p.refine_brightness_offset);
  r.get("mono_start_check_px", &p.mono_start_check_px);
  r.get("metric_start_check_px", &p.metric_start_check_px);
  r.get("stereo_pair_start_check_px", &p.stereo_pair_start_check_px);
  r.get("refine_start_check_tolerance_px", &p.refine_start_check_tolerance_px);
  r.get("refine_start_check_iterations", &p.refine_start_check_iterations);
  r.get("rgbd_pair_affine_iterations", &p.rgbd_pair_affine_iterations);
  r.get("keyframe_flow_px", &p.keyframe_flow_px);
  r.get("mono_keyframe_flow_px", &p.mono_keyframe_flow_px);
  r.get("keyframe_rotation_px", &p.keyframe_rotation_px);
  r.get("keyframe_min_valid", &p.keyframe_min_valid);
  r.get("keyframe_baseline_ratio", &p.keyframe_baseline_ratio);
  r.get("window_size", &p.window_size);
  r.get("max_edge_partners", &p.max_edge_partners);
  r.get("min_edge_overlap", &p.min_edge_overlap);
  r.get("flow_ba_rounds", &p.flow_ba_rounds);
  r.get("loop_min_overlap", &p.loop_min_overlap);
  r.get("loop_min_valid", &p.loop_min_valid);
  r.get("loop_max_edges", &p.loop_max_edges);
  r.get("metric_loop_max_edges", &p.metric_loop_max_edges);
  r.get("loop_max_kept_images", &p.loop_max_kept_images);
  r.get("keep_departed_edges", &p.keep_departed_edges);
  r.get("ba_iterations", &p.ba_iterations);
  r.get("ba_function_tolerance", &p.ba_function_tolerance);
  r.get("final_ba_iterations", &p.final_ba_iterations);
  r.get("global_ba_iterations", &p.global_ba_iterations);
  r.get("global_min_overlap", &p.global_min_overlap);
  r.get("global_max_partners", &p.global_max_partners);
  r.get("robust_kernel", &p.robust_kernel);
  r.get("robust_scale", &p.robust_scale);
  r.get("min_depth_ratio", &p.min_depth_ratio);
  r.get("ba_min_inv_depth", &p.ba_min_inv_depth);
  r.get("rgbd_ba_min_inv_depth", &p.rgbd_ba_min_inv_depth);
  r.get("mono_gauge", &p.mono_gauge);
  r.get("mono_prior_mean", &p.mono_prior_mean);
  r.get("init_inv_depth", &p.init_inv_depth);
  r.get("mono_init_flow_px", &p.mono_init_flow_px);
  r.get("mono_init_min_parallax_deg", &p.mono_init_min_parallax_deg);
  r.get("mono_prior_rel_sigma", &p.mono_prior_rel_sigma);
  r.get("mono_level_rel_sigma", &p.mono_level_rel_sigma);
  r.get("metric_prior_rel_sigma", &p.metric_prior_rel_sigma);
  r.get("depth_sigma_a", &p.depth_sigma_a);
  r.get("depth_residual_sigma_scale", &p.depth_residual_sigma_scale);
  r.get("depth_residual_max_jump", &p.depth_residual_max_jump);
  r.get("depth_sigma_b", &p.depth_sigma_b);
  r.get("depth_sigma_z0", &p.depth_sigma_z0);
  r.get("depth_min_m", &p.depth_min_m);
  r.get("depth_max_m", &p.depth_max_m);
  r.get("depth_min_cell_fraction", &p.depth_min_cell_fraction);
  r.get("motion_iterations", &p.motion_iterations);
  r.get("lost_min_valid", &p.lost_min_valid);
  r.get("lost_min_contrast", &p.lost_min_contrast);
  r.get("lost_reinit_frames", &p.lost_reinit_frames);
  r.get("upsample_sigma_range", &p.upsample_sigma_range);
  r.get("resend_rotation_deg", &p.resend_rotation_deg);
  r.get("resend_translation_rel", &p.resend_translation_rel);
  r.get("resend_inv_depth_rel", &p.resend_inv_depth_rel);
  r.get("resend_min_keyframes", &p.resend_min_keyframes);
  r.get("dynamic_objects", &p.dynamic_objects);
  r.get("dynamic_classes", &p.dynamic_classes);
  r.get("object_stride", &p.object_stride);
  r.get("object_mask_dilation_px", &p.object_mask_dilation_px);
  r.get("motion_segmentation", &p.motion_segmentation);
  r.get("motion_residual_px", &p.motion_residual_px);
  r.get("motion_photometric_margin", &p.motion_photometric_margin);
  r.get("motion_weak_fraction", &p.motion_weak_fraction);
  r.get("motion_carry_grey_error", &p.motion_carry_grey_error);
  r.get("motion_min_keyframe_age", &p.motion_min_keyframe_age);
  r.get("motion_occlusion_test", &p.motion_occlusion_test);
  r.get("motion_min_pixels", &p.motion_min_pixels);
  r.get("motion_class_id", &p.motion_class_id);
  r.get("motion_rounds", &p.motion_rounds);
  r.get("stereo_disparity_sigma_px", &p.stereo_disparity_sigma_px);
  r.get("stereo_matcher", &p.stereo_matcher);
  r.get("stereo_min_depth_m", &p.stereo_min_depth_m);
  r.get("motion_max_fraction", &p.motion_max_fraction);
  r.get("motion_ground_max_moving", &p.motion_ground_max_moving);
  r.get("object_flow_smoothing_px", &p.object_flow_smoothing_px);
  r.get("object_window_frames", &p.object_window_frames);
  r.finish();
  try {
    validateTrackerParams(p);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(r.source() + ": " + e.what());
  }
  if (dump) *dump = r.dump();
  if (source) *source = r.source();
  return p;
}

TrackerNode::TrackerNode(Bus* bus, TrackerParams params, TrackerNodeOptions options)
    : bus_(bus),
      params_(std::move(params)),
      options_(options),
      tracker_(std::make_unique<Tracker>(params_)),
      reporter_("tracker") {
  if (options_.max_queue < 1) throw std::invalid_argument("tracker queue must hold >= 1 frame");
  bus_->subscribe<Frame>(channel::kCamera, [this](const Frame& f) { onFrame(f); });
  bus_->subscribe<Control>(channel::kControl, [this](const Control& c) { onControl(c); });
  last_checkpoint_ = Clock::now();
}

void TrackerNode::resume(const std::string& checkpoint) {
  tracker_->loadCheckpoint(checkpoint);
  last_index_ = tracker_->lastFrameIndex();
  rewind_from_ = last_index_ + 1;
  rewind_token_ = std::to_string(::getpid()) + "-" +
                  std::to_string(std::chrono::system_clock::now().time_since_epoch().count());
  last_rewind_request_ = Clock::now() - std::chrono::hours(1);
  std::cerr << "radslam-tracker: resumed from " << checkpoint << " at frame " << last_index_ << " ("
            << tracker_->graph().size() << " keyframes)\n";
}

void TrackerNode::saveCheckpoint() {
  const auto t0 = Clock::now();
  try {
    tracker_->saveCheckpoint(options_.checkpoint_path);
  } catch (const std::runtime_error& e) {
    reporter_.setError(e.what());
    std::cerr << "radslam-tracker: warning: " << e.what() << "\n";
  }
  last_checkpoint_ = Clock::now();
  const double ms = 1e3 * secondsSince(t0);
  reporter_.setValue("checkpoint_ms", ms);
  std::cerr << "radslam-tracker: checkpoint at frame " << last_index_ << " written in "
            << static_cast<int>(ms) << " ms\n";
}

void TrackerNode::onFrame(const Frame& frame) {
  queue_.push_back(frame);
  while (static_cast<int>(queue_.size()) > options_.max_queue) {
    ++dropped_;
    if (shouldWarn(dropped_)) {
      std::cerr << "radslam-tracker: warning: " << bus_->fullChannel(channel::kCamera)
                << ": frames arrive faster than they are tracked; dropped frame "
                << queue_.front().frame_index << " (" << dropped_ << " dropped so far)\n";
    }
    queue_.pop_front();
  }
  reporter_.setQueueDepth(static_cast<int32_t>(queue_.size()));
}

void TrackerNode::onControl(const Control& control) {
  if (!control.target.empty() && control.target != "tracker") return;
  if (control.command == ControlCommand::kStop) requestStop();
  if (control.command == ControlCommand::kReset) reset_requested_ = true;
  // Only when addressed: a REPUBLISH for all processes means the field (mapper).
  if (control.command == ControlCommand::kRepublish && control.target == "tracker") {
    std::vector<int32_t> ids;
    if (!parseKeyframeRequest(control.argument, &ids)) {
      std::cerr << "radslam-tracker: warning: CONTROL REPUBLISH of '" << control.argument
                << "' ignored\n";
      return;
    }
    republish_ids_.insert(republish_ids_.end(), ids.begin(), ids.end());
    if (ids.empty()) republish_all_ = true;
    republish_requested_ = true;
  }
}

void TrackerNode::handle(const Frame& frame) {
  const std::string camera = bus_->fullChannel(channel::kCamera);
  if (frame.frame_index <= last_index_) {
    ++rejected_;
    if (shouldWarn(rejected_)) {
      std::cerr << "radslam-tracker: warning: " << camera << ": skipped frame " << frame.frame_index
                << ": not after frame " << last_index_ << "\n";
    }
    return;
  }
  TrackerOutput output;
  try {
    BusyTimer::Scope busy(reporter_.busy());
    output = tracker_->process(frame);
  } catch (const std::invalid_argument& e) {
    ++rejected_;
    reporter_.setError(std::string(camera) + ": " + e.what());
    if (shouldWarn(rejected_)) {
      std::cerr << "radslam-tracker: warning: " << camera << ": skipped " << e.what() << "\n";
    }
  }
  last_index_ = frame.frame_index;
  rewind_from_ = -1;  // frames flow again
  if (output.has_pose) {
    ++processed_;
    publish(output);
  }
  // The acknowledgement (lock-step playback) follows the frame's POSE and KEYFRAMEs, also for
  // a skipped frame so that playback goes on.
  reporter_.itemHandled(frame.frame_index, frame.header.utime);
  reporter_.setQueueDepth(static_cast<int32_t>(queue_.size()));
  publishStatus(ProcessState::kRunning);
}

void TrackerNode::publish(const TrackerOutput& output) {
  last_stats_ = output.stats;
  try {
    if (output.has_pose) bus_->publish(channel::kPose, output.pose);
    if (output.has_objects) bus_->publish(channel::kObjects, output.objects);
    // The small refreshed poses before the keyframes: a keyframe burst can fill the receivers'
    // socket buffers, and what arrives behind it is lost.
    for (const PoseStamped& pose : output.refreshed_poses) bus_->publish(channel::kPose, pose);
  } catch (const std::invalid_argument& e) {
    reporter_.setError(e.what());
    std::cerr << "radslam-tracker: warning: cannot publish: " << e.what() << "\n";
  }
  publishKeyframes(output.keyframes);
}

void TrackerNode::publishKeyframes(const std::vector<Keyframe>& keyframes) {
  for (size_t k = 0; k < keyframes.size(); ++k) {
    // Pace bursts so that receivers keep up (a receive buffer overrun loses whole messages).
    if (k > 0) std::this_thread::sleep_for(std::chrono::milliseconds(kKeyframeGapMs));
    try {
      bus_->publish(channel::kKeyframe, keyframes[k]);
    } catch (const std::invalid_argument& e) {
      reporter_.setError(e.what());
      std::cerr << "radslam-tracker: warning: cannot publish keyframe " << keyframes[k].keyframe_id
                << ": " << e.what() << "\n";
    }
  }
}

void TrackerNode::publishStatus(ProcessState state) {
  reporter_.setState(state);
  const TrackerStats& s = last_stats_;
  reporter_.setValue("keyframes", s.keyframes);
  reporter_.setValue("window", s.window_size);
  reporter_.setValue("edges", s.edges);
  reporter_.setValue("ba_cost", s.ba_cost);
  reporter_.setValue("ba_ms", s.ba_ms);
  reporter_.setValue("flow_ms", s.flow_ms);
  reporter_.setValue("frame_ms", s.frame_ms);
  reporter_.setValue("valid_fraction", s.valid_fraction);
  reporter_.setValue("lost_frames", s.lost_frames);
  reporter_.setValue("dropped_frames", static_cast<double>(dropped_));
  reporter_.setValue("rejected_frames", static_cast<double>(rejected_));
  bus_->publish(channel::kStatus, reporter_.make());
}

void TrackerNode::processQueued() {
  while (!queue_.empty()) {
    if (reset_requested_) {
      // CONTROL RESET: a fresh map from the next frame on.
      reset_requested_ = false;
      tracker_ = std::make_unique<Tracker>(params_);
      last_index_ = -1;
      std::cerr << "radslam-tracker: reset\n";
    }
    const Frame frame = std::move(queue_.front());
    queue_.pop_front();
    handle(frame);
    if (checkpointing() && secondsSince(last_checkpoint_) >= options_.checkpoint_period_s) {
      saveCheckpoint();
    }
    // Keep the queue current (and hear CONTROL) between frames.
    if (bus_->handle(0) < 0) break;
  }
}

void TrackerNode::finish() {
  TrackerOutput output;
  {
    BusyTimer::Scope busy(reporter_.busy());
    output = tracker_->finish();
  }
  publish(output);
  std::cerr << "radslam-tracker: finished: " << processed_ << " frames tracked, "
            << output.stats.keyframes << " keyframes, " << dropped_ << " dropped, " << rejected_
            << " skipped, " << output.stats.lost_frames << " lost; re-sent "
            << output.keyframes.size() << " keyframes and " << output.refreshed_poses.size()
            << " poses\n";
  publishStatus(ProcessState::kDone);
  // Once more after a moment: the first may be lost behind the final burst.
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  publishStatus(ProcessState::kDone);
}

int TrackerNode::run() {
  publishStatus(ProcessState::kIdle);
  auto last_status = Clock::now();
  auto last_frame = Clock::now();
  bool ended = false;
  while (!stopRequested() && !ended) {
    const int handled = bus_->handle(50);
    if (handled < 0) ended = true;  // e.g. the end of a file:// log
    if (!queue_.empty()) {
      processQueued();
      last_frame = Clock::now();
    }
    if (republish_requested_) {
      republish_requested_ = false;
      std::vector<Keyframe> keyframes =
          tracker_->republishKeyframes(republish_all_ ? std::vector<int>() : republish_ids_);
      republish_all_ = false;
      republish_ids_.clear();
      std::cerr << "radslam-tracker: re-publishing " << keyframes.size() << " keyframes\n";
      const bool any = !keyframes.empty();
      republish_queue_.insert(republish_queue_.end(), std::make_move_iterator(keyframes.begin()),
                              std::make_move_iterator(keyframes.end()));
      // Their new versions are on record: a tracker resumed later never sends one again. (A
      // request before the first keyframe changes nothing: no checkpoint of an empty tracker.)
      if (checkpointing() && any) saveCheckpoint();
    }
    if (rewind_from_ >= 0 && secondsSince(last_rewind_request_) >= kRewindRequestPeriodS) {
      Control rewind;
      rewind.command = ControlCommand::kRewind;
      rewind.target = "player";
      rewind.argument = rewindRequest(rewind_from_, rewind_token_);
      bus_->publish(channel::kControl, rewind);
      last_rewind_request_ = Clock::now();
    }
    if (!republish_queue_.empty() &&
        Clock::now() - last_republish_ >= std::chrono::milliseconds(kRepublishGapMs)) {
      publishKeyframes({republish_queue_.front()});
      republish_queue_.pop_front();
      last_republish_ = Clock::now();
    }
    if (secondsSince(last_status) >= options_.status_period_s) {
      publishStatus(last_index_ >= 0 ? ProcessState::kRunning : ProcessState::kIdle);
      last_status = Clock::now();
    }
    if (options_.idle_exit_s > 0 && processed_ > 0 &&
        secondsSince(last_frame) > options_.idle_exit_s) {
      break;
    }
  }
  // Drain: what LCM still holds goes through the queue (processQueued polls between frames).
  if (!ended) bus_->handle(0);
  processQueued();
  finish();
  return 0;
}

}  // namespace radslam
