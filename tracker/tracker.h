// The tracker core: dense monocular / RGB-D / stereo SLAM front end around dense BA with exact
// marginal covariances (NeRF-SLAM's tracking with DROID-SLAM's GRU replaced by DIS flow).
// No LCM here: tracker/tracker_node.* wires it to the bus. DESIGN.md section 3.
//
/// Per frame: undistort + resize to the working resolution, dense flow from the last keyframe
/// (warm-started from the pose predicted by constant velocity), motion-only alignment gives the
/// frame's pose and covariance. When the parallax to the last keyframe exceeds
/// keyframe_flow_px, the rotation alone exceeds keyframe_rotation_px (BA grid px) or too few
/// cells are tracked (isNewKeyframe), the frame becomes a keyframe: edges to its predecessor and
/// to overlapping window keyframes (and loop edges to older overlapping keyframes outside the
/// window), then flow_ba_rounds alternations of (flow warm-started from BA's prediction, BA),
/// then exact marginals; new and changed keyframes are returned.
///
/// Frames keep their pose relative to their reference keyframe and are aligned again against its
/// final depths when it leaves the window; finish() re-emits every frame's pose with the final
/// keyframe poses.
///
/// Monocular initialisation: keyframe 0 gets a constant inverse depth (init_inv_depth, scene
/// units); frames are aligned against it from frame 1 on; the first BA runs with the second
/// keyframe. A weak prior pulls each inverse depth towards init_inv_depth (sigma =
/// mono_prior_rel_sigma x init_inv_depth) so that pixels without parallax (pure rotation) stay
/// determined, and a level prior holds each keyframe's mean inverse depth, the scale
/// (mono_level_rel_sigma). Gauge (mono_gauge): the first window keyframe's pose, the scale by
/// those priors. "first_pose_and_scale" also holds keyframe 0's distance to keyframe 1 and keeps
/// keyframe 1's rotation free, which pure-rotation starts need (DROID's first_two_poses would
/// freeze keyframe 1 at its rough motion-only pose); it falls back to the priors alone while the
/// baseline is degenerate.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "common/types.h"
#include "tracker/dense_ba.h"
#include "tracker/depth_upsampling.h"
#include "tracker/frontend.h"
#include "tracker/frontend_flow.h"
#include "tracker/keyframe_graph.h"

namespace radslam {

enum class TrackerMode { kMono, kRgbd, kStereo };

/// "mono", "rgbd", "stereo"; throws std::invalid_argument otherwise.
TrackerMode parseTrackerMode(const std::string& name);
const char* trackerModeName(TrackerMode mode);

/// Every tracker parameter (YAML section "tracker"; loadTrackerParams in tracker_node.h).
struct TrackerParams {
  std::string mode = "mono";  // mono | rgbd | stereo (the command line's --mode overrides)
  int opencv_threads = 1;     // OpenCV worker threads (1: one process per core)

  // Front end.
  // Working image area, px (0 = input size): the size keeps the input's aspect ratio (a
  // multiple of grid_cell each way), so wide images (KITTI) keep as many BA grid rows as
  // their area allows. 384 x 288 for 4:3 input.
  int working_pixels = 110592;
  int grid_cell = 8;  // working px per BA grid px
  // Rolling shutter: s from the first input row's exposure to the last's; negative: the
  // camera's own (CameraModel::readout_s), 0: global shutter. Frames are resampled as seen at
  // their middle row (tracker/frontend.h ImagePreparer, tracker/rotation_alignment.h).
  double rolling_shutter_readout_s = -1;
  // RGB-D: the depth image is exposed at its stamp minus this, relative to the colour image's
  // middle row at its own stamp (s; TUM fr1/rpy: 0.015, docs/mapper.md "Sensor clocks"). The
  // depth is turned by the camera's rotation between the two (its angular velocity over the
  // frame's depth_time_offset_s minus this), so that it is seen from the colour image's pose.
  double depth_delay_s = 0;
  std::string flow_preset = "fast";  // DIS preset: ultrafast | fast | medium
  int flow_finest_scale = 1;         // DIS finest pyramid level (2 biased the flow at 384 px width)
  int flow_variational_iterations = 0;
  int flow_patch_size = 8;
  int flow_patch_stride = 4;
  bool flow_spatial_propagation = true;
  // Warm starts (tracker/frontend_flow.h WarmStart) of a frame's flow to its keyframe:
  // "coarse" (DIS starts from the motion model's prediction at its coarsest level), "warp"
  // (the frame is warped by the prediction and DIS measures the residual) or "auto": warp when
  // motion segmentation judges that flow, coarse otherwise. Keyframe pairs start coarse in the
  // first flow/BA round and are warped by BA's prediction after.
  std::string frame_flow_start = "auto";
  double flow_warp_smoothing_px = 12;  // working px, Gaussian sigma of the warp
  bool frame_backward_flow = false;    // forward-backward check on per-frame flow (one more flow)
  double conf_sigma0_px = 0.05;        // grid px (see tracker/frontend_flow.h)
  double conf_fb_gain = 1.0;
  double conf_fb_max_px = 0.75;     // grid px
  double conf_photo_scale = 100.0;  // grey levels
  double conf_photo_max = 40.0;     // grey levels
  double conf_grad_gain = 0.2;      // (grey/px)^2 grid px^2
  double conf_grad_floor = 1.0;     // (grey/px)^2

  // Per-cell Lucas-Kanade refinement of the flow targets (tracker/frontend_refine.h).
  int refine_iterations = 4;             // 0 = off
  double refine_max_shift_px = 3.0;      // working px from the DIS target; further: weight 0
  bool refine_brightness_offset = true;  // per-cell offset (auto-exposure)
  // Start check (RefineOptions::start_check_px, working px; 0 = off): a cell refined again
  // from this far along its flow must end within the tolerance of the first run, or it is
  // left out. RGB-D and stereo: on the flows of frames to their keyframe and the left-right
  // flow; stereo also on the keyframe pairs, where it halves the synthetic streets' ATE (RGB-D's
  // pairs do better with the affine step, rgbd_pair_affine_iterations). Monocular: off, the
  // synthetic room's monocular run lost its way with it (docs/tracker.md, step 2).
  double mono_start_check_px = 0;
  double metric_start_check_px = 1.0;
  double stereo_pair_start_check_px = 1.0;
  double refine_start_check_tolerance_px = 0.3;
  int refine_start_check_iterations = 8;
  // RGB-D: affine Lucas-Kanade iterations after the translation on the keyframe pairs BA
  // re-measures (RefineOptions::affine_iterations; 0 = none). The sensor prior fixes the scale,
  // so a flow measured short becomes a trajectory too short.
  int rgbd_pair_affine_iterations = 4;

  // Keyframes and window.
  double keyframe_flow_px = 2.5;  // grid px, mean parallax to the last keyframe
  // Monocular: the same bound, lower. Driving forward at 10 Hz the mean parallax of the cells
  // still tracked stays below 2 px for tens of metres, and with no metric baseline to make a
  // keyframe (keyframe_baseline_ratio) the monocular scale collapsed (synthetic street: 23 m
  // ATE at 2.5, 0.31 m at 1.5; docs/tracker.md).
  double mono_keyframe_flow_px = 1.5;
  double keyframe_rotation_px = 7.0;  // grid px, mean flow of the rotation alone
  double keyframe_min_valid = 0.4;    // fraction of tracked pixels below which a keyframe is made
  // RGB-D and stereo: translation / median keyframe depth that makes a keyframe.
  double keyframe_baseline_ratio = 0.1;
  int window_size = 8;            // keyframes in dense BA
  int max_edge_partners = 3;      // earlier keyframes a new keyframe gets edges with
  double min_edge_overlap = 0.5;  // fraction of pixels predicted inside the other image
  int flow_ba_rounds = 2;         // (flow, BA) alternations per new keyframe
  // Loop edges: a new keyframe also gets an edge pair with keyframes outside the window that
  // it overlaps by more than loop_min_overlap (fixed pose, depths held by their marginals),
  // when at least loop_min_valid of the pixels are tracked both ways. Bounds drift when the
  // camera returns to a view it has seen.
  double loop_min_overlap = 0.7;  // fraction of grid pixels; > 1 disables loop edges
  double loop_min_valid = 0.5;    // fraction of grid pixels
  // Loop partners tried per keyframe (KeyframeGraph::loopPartners: the oldest, then the most
  // overlapping): monocular / RGB-D and stereo. A second one took fr1/rpy monocular from 1.12
  // to 1.04 deg; RGB-D, which drifts less, did not gain (docs/tracker.md, step 6).
  int loop_max_edges = 2;
  int metric_loop_max_edges = 1;
  int loop_max_kept_images = 200;  // keyframes outside the window that keep their grey image
  // Edges between a keyframe leaving the window and the window stay, with the departed
  // keyframe fixed (KeyframeGraph): a longer memory of scale and rotation at the cost of BA
  // time for its depths. Monocular KITTI 07, mean Sim3 ATE over six start frames: 0.50 m
  // without, 0.27 m with.
  bool keep_departed_edges = true;
  int ba_iterations = 4;  // Levenberg-Marquardt iterations per BA call
  // BA stops early when an accepted step lowers the cost by less than this fraction: later
  // steps move the estimate less than the flow noise (fr1/rpy mono 31 -> 33 frames/s, same
  // accuracy; docs/tracker.md).
  double ba_function_tolerance = 1e-2;
  int final_ba_iterations = 8;  // in finish()
  // Global BA in finish(): every keyframe that kept its image (loop_max_kept_images) gets flow
  // edges with its global_max_partners most overlapping others (overlap > global_min_overlap,
  // tracked both ways >= loop_min_valid), warm-started by the final estimate; one BA over all.
  // 0 iterations = off, the default: on the synthetic street (stereo, 20 Hz) it cut the ATE
  // from 0.11 to 0.02 m, but on TUM fr1/rpy it raised the keyframes' orientation error from
  // 1.49 to 1.85 deg (RGB-D), with any partner count.
  int global_ba_iterations = 0;
  double global_min_overlap = 0.5;
  int global_max_partners = 4;

  // Dense BA.
  // Robust kernel of BA and per-frame alignment (tracker/dense_ba_kernel.h): "cauchy"
  // (redescending: on the synthetic street, RGB-D ATE 48 m -> 1.1 m against Huber) or "huber";
  // scale on the whitened residual norm.
  std::string robust_kernel = "cauchy";
  double robust_scale = 2.4477;
  double min_depth_ratio = 0.2;
  // Far limit of BA's points: inverse depths stay at or above this (1/m; monocular 1/scene
  // unit). A point farther away is held at 1 / ba_min_inv_depth, and under forward motion the
  // parallax it should then show bends the rotation: at 1e-3 the synthetic streets' clouds
  // (1.5 km up) were held at 1 km and the camera pitched up 0.12 deg over 36 m (docs/tracker.md).
  double ba_min_inv_depth = 1e-5;
  // RGB-D keeps the nearer limit: there the parallax it adds lengthens the path and cancels part
  // of the flow's shortfall; at 1e-5 the orientation error halves but the ATE grows by 15-35 %
  // (docs/tracker.md).
  double rgbd_ba_min_inv_depth = 1e-3;
  std::string mono_gauge = "first_pose";  // first_pose | first_pose_and_scale | first_two_poses
  std::string mono_prior_mean = "fixed";  // fixed (init_inv_depth) | median (of the keyframe)
  double init_inv_depth = 1.0;            // monocular keyframe 0, 1/scene unit
  double mono_init_flow_px = 7.5;         // grid px of mean flow before the second keyframe
  // The second keyframe's pose and the first one's depths come from the essential matrix
  // (tracker/mono_init.h) when the median ray angle of its inliers reaches this (deg); below,
  // from the constant-depth alignment (rotation).
  double mono_init_min_parallax_deg = 1.0;
  // Monocular weak inverse-depth prior on each pixel, relative to its mean (init_inv_depth):
  // it keeps pixels without parallax determined and flattens the scene.
  double mono_prior_rel_sigma = 2.0;
  // Monocular scale: each keyframe's mean inverse depth is held as hard as a per-pixel prior
  // of this relative sigma would hold it (the pixels' own prior holds part, a level prior the
  // rest: DenseBaKeyframe::prior_level_var; none when not below mono_prior_rel_sigma).
  double mono_level_rel_sigma = 1.0;
  // RGB-D and stereo: the same prior, towards the keyframe's median. At 1.0 it pulled the far
  // half of the synthetic street forward and made the stereo scale 15 % too large.
  double metric_prior_rel_sigma = 10.0;

  // RGB-D: sensor depth on the grid (median of the valid pixels of each cell) as an inverse-depth
  // prior with sigma_z = depth_sigma_a + depth_sigma_b (z - depth_sigma_z0)^2 (m), Khoshelham &
  // Elberink's Kinect model.
  double depth_sigma_a = 0.0012;  // m
  double depth_sigma_b = 0.0019;  // 1/m
  double depth_sigma_z0 = 0.4;    // m
  double depth_min_m = 0.1;
  double depth_max_m = 20.0;
  double depth_min_cell_fraction = 0.5;  // valid pixels a cell needs
  // RGB-D: every BA edge, and each frame's alignment, also compares its points' inverse depth in
  // the target keyframe (the frame) with the sensor's depth where they land
  // (DenseBaKeyframe::measured_inv_depth, MotionOnlyDepth), with the sensor's sigma times this
  // (0: off).
  double depth_residual_sigma_scale = 1.0;
  // Points whose nine nearest grid cells' inverse depths spread by more than this fraction of the
  // largest skip it (DenseBaOptions::depth_residual_max_jump).
  double depth_residual_max_jump = 0.1;

  // Per-frame alignment.
  int motion_iterations = 10;
  double lost_min_valid = 0.15;  // fraction of valid correspondences below which a frame is lost
  // Grey-level standard deviation below which a frame is lost without measuring flow (covered
  // lens, blank or saturated image: without the backward flow check nothing else rejects it).
  double lost_min_contrast = 2.0;
  int lost_reinit_frames = 5;  // consecutive lost frames before re-initialising

  // Moving objects (tracker/object_tracker.h): pixels of moving objects stay out of camera
  // tracking and of the keyframes' static map (Keyframe::dynamic_mask), and each object gets a
  // pose and a twist under its joint where depth is available (RGB-D, stereo). Class table
  // "ID:JOINT[:PARENT],...": the default is the synthetic generator's (car and truck planar on
  // the road, door revolute in the wall). Frames without class masks are not affected.
  bool dynamic_objects = true;
  std::string dynamic_classes = "10:planar:1,11:revolute:2,12:planar:1";
  // Frames without class masks (tracker/motion_segmentation.h): pixels whose flow to the
  // keyframe differs from the static scene's by more than motion_residual_px (working px) form
  // moving objects of motion_class_id (free joint) when at least motion_min_pixels large.
  bool motion_segmentation = false;
  double motion_residual_px = 2.0;
  // A pixel moves by its flow only where the static prediction matches the frame worse than the
  // measured flow by this many grey levels (5 x 5 mean; tracker/motion_segmentation.h
  // photometricPreference); 0 = the flow residual alone.
  double motion_photometric_margin = 4.0;
  // Evidence above this fraction of the thresholds moves a pixel where it connects to evidence
  // above them (tracker/motion_segmentation.h): the slow side of a door near its hinge.
  double motion_weak_fraction = 0.7;
  // A flow lands off its pixel more than this many grey levels from it (tracker/
  // motion_segmentation.h landingGreyError). A moving region where a quarter of the pixels
  // moving by their flow alone do is not carried into the frame (255 = always carried): the
  // failed flow of a pole passing close scatters it into a blob.
  double motion_carry_grey_error = 8.0;
  // Motion is judged against the newest window keyframe at least this many frames old (the
  // last keyframe when none is; 0 = always the last): one made a frame ago has seen little of
  // the motion (the car was missed on every frame after a new keyframe). Older ones make longer
  // flows, which fail more: at 2 the car's IoU rises from 0.40 to 0.49 and the large truck's
  // falls from 0.85 to 0.79; at 3 the truck's falls to 0.71 (docs/tracker.md).
  int motion_min_keyframe_age = 2;
  // With depth: pixels of the frame nearer than every static point of the judging keyframe
  // that lands on them move where they are (depthDisagreement's occluding_b).
  bool motion_occlusion_test = true;
  int motion_min_pixels = 400;
  int motion_class_id = 250;
  int motion_rounds = 2;                   // segment, re-align without the objects, segment again
  double stereo_disparity_sigma_px = 0.5;  // working px: stereo depth noise for segmentation
  // Stereo: the per-frame depth of segmentation and objects, from "flow" (the left -> right
  // dense flow) or "sgbm" (semi-global matching, down to stereo_min_depth_m): better with a
  // wide rig, slower (docs/tracker.md, Moving objects).
  std::string stereo_matcher = "flow";
  double stereo_min_depth_m = 0.5;
  double motion_max_fraction = 0.5;  // of the image: more moving means the pose is wrong
  // More than this fraction of the ground plane (tracker/motion_segmentation.h fitGroundPlane)
  // moving means the pose followed an object (a truck alongside driving with the camera): the
  // frame is aligned on the ground alone and judged again; 1 = never.
  double motion_ground_max_moving = 0.3;
  int object_stride = 2;                // working px between an object's sample points
  int object_mask_dilation_px = 3;      // working px the moving mask grows by (silhouette edges)
  double object_flow_smoothing_px = 4;  // working px (ObjectTrackerParams::flow_warp_smoothing_px)
  // Frames of each object's dynamic BA window (ObjectTrackerParams::window_frames); 1 = off.
  int object_window_frames = 5;

  // Keyframe output (KEYFRAME messages at working resolution).
  double upsample_sigma_range = 12.0;  // grey levels
  double resend_rotation_deg = 0.1;
  double resend_translation_rel = 2e-3;  // of the median depth
  double resend_inv_depth_rel = 1e-2;
  int resend_min_keyframes = 3;  // new keyframes between two re-sends of one keyframe
};

/// Throws std::invalid_argument naming the first parameter out of range (implemented beside
/// the YAML loader in tracker/tracker_node.cc).
void validateTrackerParams(const TrackerParams& params);

/// Figures for STATUS and the benchmark.
struct TrackerStats {
  int frames = 0;               // frames processed (with a pose)
  int keyframes = 0;            // created so far
  int window_size = 0;          // keyframes in the BA window
  int edges = 0;                // flow edges in the window
  double ba_cost = 0;           // final cost of the last BA call
  int ba_iterations = 0;        // of the last BA call
  double ba_ms = 0;             // BA time of this frame (all rounds), ms
  double flow_ms = 0;           // flow + confidence time of this frame, ms
  double frame_ms = 0;          // whole process() call, ms
  double valid_fraction = 0;    // tracked pixels of this frame
  double mean_flow_px = 0;      // to the last keyframe, grid px
  double mean_parallax_px = 0;  // of it, not explained by the rotation, grid px
  int lost_frames = 0;          // frames reported LOST so far
  int loop_edges = 0;           // loop edge pairs made so far
  int global_ba_edges = 0;      // flow edges of the global BA in finish()
  int ground_realignments = 0;  // frames re-aligned on the ground (it moved) so far
  double alignment_deg = 0;     // rotation the alignment moved the frame from its prediction
  double keyframe_ba_deg = 0;   // rotation BA moved a new keyframe from its aligned pose
  bool two_view_init = false;   // the second monocular keyframe came from two-view geometry
};

struct TrackerOutput {
  bool has_pose = false;
  PoseStamped pose;
  /// New keyframes, and window keyframes BA moved since they were last sent (higher version).
  std::vector<Keyframe> keyframes;
  /// finish() only: every frame's pose recomputed from its reference keyframe's final pose.
  std::vector<PoseStamped> refreshed_poses;
  /// The frame's moving-object mask (CV_8UC1 working size, 255 = moving; empty: none), from its
  /// class masks or from motion segmentation.
  cv::Mat moving_mask;
  /// The frame's moving objects (when it has class masks or segmented ones, dynamic_objects on).
  bool has_objects = false;
  ObjectList objects;
  TrackerStats stats;
};

class Tracker {
 public:
  /// Throws std::invalid_argument on invalid parameters.
  explicit Tracker(TrackerParams params);
  ~Tracker();
  Tracker(const Tracker&) = delete;
  Tracker& operator=(const Tracker&) = delete;

  /// Processes the next frame (in order). Throws std::invalid_argument, naming what is wrong,
  /// for a frame with bad content (empty or mismatched images, bad intrinsics, NaN, a camera
  /// different from the first frame's, missing depth in RGB-D or right image in stereo mode);
  /// the tracker's state is then unchanged and the caller skips the frame.
  TrackerOutput process(const Frame& frame);

  /// Final BA over the window, final keyframes (those changed since last sent) and every
  /// frame's refreshed pose. Further process() calls continue tracking.
  TrackerOutput finish();

  /// Every keyframe that still has its images (the window and the kept ones that left it, see
  /// loop_max_kept_images) at its current estimate, each with a new version: what a mapper
  /// that restarted asks for (CONTROL REPUBLISH).
  /// `ids` empty = all of them.
  std::vector<Keyframe> republishKeyframes(const std::vector<int>& ids = {});

  /// Checkpoint: everything process() carries from frame to frame (keyframes with their images,
  /// depths, marginals and edges, every frame's pose, objects, publication versions), so that
  /// a tracker loaded from it continues exactly as this one would. Throws std::runtime_error
  /// naming the file (written to PATH.tmp and renamed: a crash leaves the last checkpoint).
  void saveCheckpoint(const std::string& path) const;
  /// Replaces the state by a checkpoint's. The checkpoint must come from a tracker with the
  /// same mode, working size, grid, window and object options; throws std::runtime_error naming
  /// the file and what is wrong (the state is then unchanged).
  void loadCheckpoint(const std::string& path);
  /// Frame index of the last frame processed (-1: none).
  int64_t lastFrameIndex() const;

  const TrackerParams& params() const { return params_; }
  TrackerMode mode() const { return mode_; }
  /// Null before the first frame.
  const GridGeometry* geometry() const;
  const KeyframeGraph& graph() const;

 private:
  struct Impl;
  TrackerParams params_;
  TrackerMode mode_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace radslam
