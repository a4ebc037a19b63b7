// radslam-bench-dynamic: object motion error (VDO-SLAM / DynoSAM style) of the joint-constrained
// object tracker against free 6-DOF tracking and the dynamic window BA, on the synthetic dynamic
// scenes with sensor noise. Prints a table and one "RESULT" tab-separated line per object.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/camera.h"
#include "common/cli.h"
#include "common/evaluation.h"
#include "common/synthetic.h"
#include "tracker/joints.h"
#include "tracker/object_synthetic.h"
#include "tracker/object_tracking.h"
#include "tracker/object_window_ba.h"
#include "tracker/tracker.h"
#include "tracker/tracker_node.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-bench-dynamic [options]
  --scenes LIST      comma-separated synthetic scenes (default car,door,multi)
  --frames N         frames per scene (default 60)
  --width W          image width, height = 3/4 W (default 320)
  --stride S         use every S-th object pixel (default 2)
  --pixel-sigma PX   correspondence noise (default 1.0 px)
  --depth-noise R    depth sigma = R z^2 (default 0.002 1/m)
  --outliers F       fraction of wrong correspondences (default 0.05)
  --window N         frames per dynamic BA window (default 5)
  --seed N           noise seed (default 1; with --pipeline: the rendered sensor noise)
  --pipeline         instead: run the whole tracker (RGB-D and stereo) on the rendered sequences
                     with sensor noise: camera ATE with and without the handling of moving
                     objects and on the same scene with the objects frozen, and the error of the
                     tracker's object motions, joint-constrained vs free 6-DOF (default frames
                     150, width 640)
  --fps F            frame rate of the rendered sequences, Hz (default: the scene's, 30 for rooms
                     and 10 for streets)
  --modes LIST       with --pipeline: tracker modes to run (default rgbd,stereo)
  --baseline M       with --pipeline: stereo baseline of the rendered rig, m (default 0.1)
  --segmentation-only  with --pipeline: only the run with masks withheld (its ATE and IoU)
  --mask-dir DIR     with --pipeline: write each frame's true and segmented moving masks there
                     (DIR/<scene>-<mode>-<frame>.png: true in red, segmented in green,
                     the frame at half brightness in blue)
  --set KEY=VALUE    with --pipeline: override tracker parameters (comma-separated)
  --seeds N          with --pipeline: run the noise seeds seed..seed+N-1 and print medians
                     (default 1; the camera ATE of one scene varies by 2x from seed to seed)
)";

constexpr double kDeg = 180.0 / M_PI;
constexpr int kMinPoints = 30;

struct Stats {
  std::vector<double> t, r;  // m, rad
  void add(const MotionError& e) {
    t.push_back(e.translation);
    r.push_back(e.rotation);
  }
  static double mean(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return v.empty() ? NAN : s / v.size();
  }
  static double median(std::vector<double> v) {  // of the values that are not NaN
    v.erase(std::remove_if(v.begin(), v.end(), [](double x) { return std::isnan(x); }), v.end());
    return v.empty() ? NAN : radslam::median(std::move(v));
  }
};

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  std::string item;
  while (std::getline(in, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

struct Bench {
  SyntheticScene scene;
  ObjectNoise noise;
  int stride = 2, window = 5;
  std::mt19937_64 rng;
  std::vector<RenderedView> views;

  SE3 objectPose(int id, int f) const {
    for (const ObjectPoseSample& s : scene.objectPoses(f))
      if (s.object_id == id) return s.T_world_object;
    return SE3();
  }
  std::vector<ObjectCorrespondence> correspondences(int id, int a, int b) {
    return syntheticObjectCorrespondences(
        scene.camera(), views[a], id, scene.cameraPose(a), scene.cameraPose(b),
        syntheticObjectMotion(scene, id, a, b), stride, noise, &rng);
  }
  ObjectMotionEstimate track(const Joint& joint, const std::vector<ObjectCorrespondence>& c, int a,
                             int b) {
    ObjectTrackingParams params;
    params.pixel_sigma = noise.pixel_sigma;
    return trackObjectMotion(joint, scene.camera(), scene.cameraPose(a), scene.cameraPose(b), c,
                             1.0 / scene.fps(), params);
  }
};

// The joint frame as the system would estimate it: the road plane by RANSAC on the noisy road
// depth of the first frame the object is seen in; the hinge from the free-tracked motions of
// the object from the frame it is best seen in (`best`). *error = the joint's error (deg of axis, m
// of origin/axis).
Joint estimateJoint(Bench* b, const SyntheticObject& o, int first, int best, std::string* error) {
  const CameraModel cam = b->scene.camera();
  char buf[96];
  if (o.joint == JointType::kPlanar) {
    std::normal_distribution<double> gauss(0, 1);
    std::vector<Vec3> road;
    const RenderedView& v = b->views[first];
    const SE3 T_world_cam = b->scene.cameraPose(first);
    for (int y = 0; y < v.depth.rows; y += 2)
      for (int x = 0; x < v.depth.cols; x += 2) {
        const float z = v.depth.at<float>(y, x);
        if (v.instance.at<uint16_t>(y, x) != 1 || !(z > 0) || z > 40) continue;
        const double zn = z + b->noise.depth_sigma_rel * z * z * gauss(b->rng);
        road.push_back(T_world_cam * unproject(cam, Eigen::Vector2d(x, y), zn));
      }
    PlaneRansacParams params;
    params.inlier_threshold = 0.1;
    const PlaneFit fit = fitPlaneRansac(road, params);
    const SE3 T =
        planeJointFrame(fit.plane, b->objectPose(o.object_id, first).translation(), Vec3::UnitZ());
    const Vec3 n_gt = o.T_world_joint.rotation().col(2);
    std::snprintf(buf, sizeof(buf), "plane %.2f deg %.3f m",
                  std::acos(std::min(1.0, T.rotation().col(2).dot(n_gt))) * kDeg,
                  std::abs(n_gt.dot(T.translation() - o.T_world_joint.translation())));
    *error = buf;
    return Joint(JointType::kPlanar, T);
  }
  if (o.joint == JointType::kRevolute) {
    const Joint free(JointType::kFree, SE3());
    std::vector<SE3> motions;
    // From the best-seen frame to up to 20 frames either side: the widest swing angles.
    const int ref = best;
    for (int f = std::max(0, ref - 20); f < std::min(ref + 21, b->scene.numFrames()); ++f) {
      if (f == ref) continue;
      const auto c = b->correspondences(o.object_id, ref, f);
      if (static_cast<int>(c.size()) >= kMinPoints)
        motions.push_back(b->track(free, c, ref, f).motion_world);
    }
    const Hinge hinge = hingeFromMotions(motions, 0.05);
    const Vec3 a_gt = o.T_world_joint.rotation().col(2);
    const Vec3 d = hinge.point - o.T_world_joint.translation();
    std::snprintf(buf, sizeof(buf), "hinge %.2f deg %.3f m",
                  std::acos(std::min(1.0, std::abs(hinge.axis.dot(a_gt)))) * kDeg,
                  (d - d.dot(a_gt) * a_gt).norm());
    *error = buf;
    return Joint(JointType::kRevolute, hingeJointFrame(hinge));
  }
  *error = "-";
  return Joint(JointType::kFree, SE3());
}

void benchObject(Bench* b, const SyntheticObject& o) {
  const int n = b->scene.numFrames();
  std::vector<int> visible(n, 0);
  for (int f = 0; f < n; ++f) {
    const cv::Mat mask = b->views[f].instance == o.object_id;
    visible[f] = cv::countNonZero(mask) / (b->stride * b->stride);
  }
  int first = 0;
  while (first < n - 1 && visible[first] < 3 * kMinPoints) ++first;
  if (first >= n - 1) {
    std::printf("%-6s %-4d %-8s not visible\n", b->scene.config().scene.c_str(), o.object_id,
                o.name.c_str());
    return;
  }
  std::string joint_error;
  Joint joint;
  try {
    const int best =
        static_cast<int>(std::max_element(visible.begin(), visible.end()) - visible.begin());
    joint = estimateJoint(b, o, first, best, &joint_error);
  } catch (const std::invalid_argument& e) {
    std::printf("%-6s %-4d %-8s joint not estimated: %s\n", b->scene.config().scene.c_str(),
                o.object_id, o.name.c_str(), e.what());
    return;
  }
  const Joint free(JointType::kFree, SE3());
  Stats s_free, s_joint, s_window;
  double ms = 0;
  for (int i = 0; i + 1 < n; ++i) {
    if (visible[i] < kMinPoints) continue;
    const auto c = b->correspondences(o.object_id, i, i + 1);
    if (static_cast<int>(c.size()) < kMinPoints) continue;
    const SE3 M_gt = syntheticObjectMotion(b->scene, o.object_id, i, i + 1);
    const SE3 T_world_object = b->objectPose(o.object_id, i);
    s_free.add(objectMotionError(b->track(free, c, i, i + 1).motion_world, M_gt, T_world_object));
    const auto t0 = std::chrono::steady_clock::now();
    const ObjectMotionEstimate est = b->track(joint, c, i, i + 1);
    ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    s_joint.add(objectMotionError(est.motion_world, M_gt, T_world_object));
  }
  // Dynamic BA over consecutive windows sharing their end frames.
  ObjectWindowParams wp;
  wp.pixel_sigma = b->noise.pixel_sigma;
  wp.depth_sigma_rel = b->noise.depth_sigma_rel;
  for (int f = 0; f + b->window <= n; f += b->window - 1) {
    if (visible[f] < kMinPoints) continue;
    const ObjectWindowProblem p = syntheticObjectWindow(b->scene, joint, o.object_id, f, b->window,
                                                        b->stride, b->noise, &b->rng);
    std::vector<int> seen(b->window, 0);
    for (const ObjectObservation& ob : p.observations) ++seen[ob.frame];
    bool ok = static_cast<int>(p.points_cam0.size()) >= kMinPoints;
    for (int k = 1; k < b->window; ++k) ok &= seen[k] >= kMinPoints;
    if (!ok) continue;
    const ObjectWindowResult r = solveObjectWindow(p, wp);
    for (int k = 0; k + 1 < b->window; ++k)
      s_window.add(objectMotionError(r.motion_world[k],
                                     syntheticObjectMotion(b->scene, o.object_id, f + k, f + k + 1),
                                     b->objectPose(o.object_id, f + k)));
  }
  const double mt = s_joint.t.empty() ? NAN : ms / s_joint.t.size();
  std::printf("%-6s %-4d %-6s %-8s %5zu | %8.4f %7.3f | %8.4f %7.3f | %8.4f %7.3f | %5.2f | %s\n",
              b->scene.config().scene.c_str(), o.object_id, o.name.c_str(), jointTypeName(o.joint),
              s_joint.t.size(), Stats::mean(s_free.t), Stats::mean(s_free.r) * kDeg,
              Stats::mean(s_joint.t), Stats::mean(s_joint.r) * kDeg, Stats::mean(s_window.t),
              Stats::mean(s_window.r) * kDeg, mt, joint_error.c_str());
  std::printf("RESULT\t%s\t%d\t%s\t%s\t%zu\t%.5f\t%.4f\t%.5f\t%.4f\t%.5f\t%.4f\n",
              b->scene.config().scene.c_str(), o.object_id, o.name.c_str(), jointTypeName(o.joint),
              s_joint.t.size(), Stats::mean(s_free.t), Stats::mean(s_free.r) * kDeg,
              Stats::mean(s_joint.t), Stats::mean(s_joint.r) * kDeg, Stats::mean(s_window.t),
              Stats::mean(s_window.r) * kDeg);
}

// ---- The whole tracker on the rendered sequences ----------------------------------------------

struct PipelineRun {
  TrajectoryErrors camera;
  Stats object;  // per-frame motion error of the tracked objects
  double fps = 0;
  double iou = 0;  // mean over frames of the moving mask against the true one (gt_moving given)
};

/// The frame's true moving-object pixels, CV_8UC1: the objects that moved since the previous
/// frame by more than 5 mm or 0.1 deg (a door at the end of its swing cannot be told from the
/// wall by its motion).
cv::Mat trueMovingMask(const SyntheticScene& scene, const Frame& frame, int i) {
  cv::Mat mask(frame.instance.size(), CV_8UC1, cv::Scalar(0));
  if (i == 0) return mask;
  for (const SyntheticObject& o : scene.objects()) {
    const SE3 M = syntheticObjectMotion(scene, o.object_id, i - 1, i);
    SE3 T_world_object;
    for (const ObjectPoseSample& s : scene.objectPoses(i - 1))
      if (s.object_id == o.object_id) T_world_object = s.T_world_object;
    const MotionError e = objectMotionError(M, SE3(), T_world_object);
    if (e.translation > 0.005 || e.rotation > 0.1 / kDeg)
      mask.setTo(255, frame.instance == o.object_id);
  }
  return mask;
}

/// gt_moving (optional, one per frame): the true moving masks the tracker's moving masks are
/// scored against (intersection over union, resized to the tracker's working size).
PipelineRun runTracker(const SyntheticScene& scene, const std::vector<Frame>& frames,
                       const TrackerParams& params, const std::vector<cv::Mat>* gt_moving = nullptr,
                       const std::string& mask_prefix = "") {
  Tracker tracker(params);
  std::vector<ObjectList> objects;
  double iou_sum = 0;
  int iou_frames = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (size_t i = 0; i < frames.size(); ++i) {
    const TrackerOutput out = tracker.process(frames[i]);
    if (out.has_objects) objects.push_back(out.objects);
    if (gt_moving && i > 0) {  // the first frame has no flow to segment
      const cv::Mat& gt_full = (*gt_moving)[i];
      const cv::Size size = tracker.geometry()->workingSize();
      cv::Mat gt;
      cv::resize(gt_full, gt, size, 0, 0, cv::INTER_NEAREST);
      const cv::Mat est =
          out.moving_mask.empty() ? cv::Mat(size, CV_8UC1, cv::Scalar(0)) : out.moving_mask;
      if (!mask_prefix.empty()) {
        // Blue: the frame's grey image at half brightness, to see what was flagged.
        cv::Mat grey;
        cv::cvtColor(frames[i].color, grey, cv::COLOR_BGR2GRAY);
        cv::resize(grey, grey, size, 0, 0, cv::INTER_AREA);
        cv::Mat overlay;
        cv::merge(std::vector<cv::Mat>{grey / 2, est, gt}, overlay);
        char index[32];
        std::snprintf(index, sizeof(index), "%04zu", i);
        cv::imwrite(mask_prefix + index + ".png", overlay);
      }
      const int uni = cv::countNonZero(gt | est);
      if (uni > 0) {
        iou_sum += static_cast<double>(cv::countNonZero(gt & est)) / uni;
        ++iou_frames;
      }
    }
  }
  const TrackerOutput final_out = tracker.finish();
  PipelineRun run;
  run.iou = iou_frames > 0 ? iou_sum / iou_frames : 0;
  run.fps =
      frames.size() / std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  Trajectory estimate, truth;
  for (const PoseStamped& p : final_out.refreshed_poses)
    estimate.push_back({p.header.utime * 1e-6, p.T_world_cam});
  for (int i = 0; i < scene.numFrames(); ++i)
    truth.push_back({scene.timestamp(i), scene.cameraPose(i)});
  run.camera = evaluateTrajectory(estimate, truth, "se3");
  // The tracker's world is its first camera: A maps it to the ground truth's world.
  const SE3 A = scene.cameraPose(0);
  for (size_t k = 0; k + 1 < objects.size(); ++k) {
    if (objects[k + 1].frame_index != objects[k].frame_index + 1) continue;
    const int i = static_cast<int>(objects[k].frame_index);
    for (const TrackedObject& b : objects[k + 1].objects) {
      if (b.covariance(0, 0) >= 1e6) continue;  // just initialised: no motion measured
      for (const TrackedObject& a : objects[k].objects) {
        if (a.object_id != b.object_id) continue;
        bool known = false;  // segmented objects have ids of their own: no ground truth
        for (const SyntheticObject& o : scene.objects()) known |= o.object_id == a.object_id;
        if (!known) continue;
        const SE3 M_est = A * (b.T_world_object * a.T_world_object.inverse()) * A.inverse();
        SE3 T_world_object_gt;
        for (const ObjectPoseSample& o : scene.objectPoses(i))
          if (o.object_id == a.object_id) T_world_object_gt = o.T_world_object;
        run.object.add(objectMotionError(M_est, syntheticObjectMotion(scene, a.object_id, i, i + 1),
                                         T_world_object_gt));
      }
    }
  }
  return run;
}

/// One scene's sequences for one noise seed: moving, frozen, and moving with masks withheld.
struct PipelineScene {
  SyntheticScene moving, frozen;
  std::vector<Frame> moving_frames, frozen_frames, unlabelled_frames;
  std::vector<cv::Mat> gt_moving;
  // Mean fraction of the image that objects of dynamic classes cover, moving and frozen: a
  // frozen object stays behind as the camera moves on, so it hides less of the static scene.
  double moving_share = 0, frozen_share = 0;
};

double dynamicShare(const std::vector<SemanticClass>& classes, const cv::Mat& class_id) {
  cv::Mat dynamic(class_id.size(), CV_8UC1, cv::Scalar(0));
  for (const SemanticClass& c : classes)
    if (c.dynamic) dynamic |= class_id == c.id;
  return static_cast<double>(cv::countNonZero(dynamic)) / class_id.total();
}

PipelineScene makePipelineScene(SyntheticConfig config) {
  SyntheticScene moving = SyntheticScene::make(config);
  config.freeze_objects = true;
  PipelineScene s{std::move(moving), SyntheticScene::make(config), {}, {}, {}, {}};
  for (int i = 0; i < config.frames; ++i) {
    s.moving_frames.push_back(s.moving.frame(i));
    s.frozen_frames.push_back(s.frozen.frame(i));
    s.gt_moving.push_back(trueMovingMask(s.moving, s.moving_frames.back(), i));
    // Masks withheld: the tracker segments the motion itself.
    s.unlabelled_frames.push_back(s.moving_frames.back());
    s.unlabelled_frames.back().instance.release();
    s.unlabelled_frames.back().class_id.release();
    s.moving_share += dynamicShare(s.moving.classes(), s.moving_frames.back().class_id);
    s.frozen_share += dynamicShare(s.frozen.classes(), s.frozen_frames.back().class_id);
  }
  s.moving_share /= config.frames;
  s.frozen_share /= config.frames;
  return s;
}

/// One table row's figures for one seed.
struct PipelineRow {
  double dyn = NAN, no_dyn = NAN, frozen = NAN, frozen_no_dyn = NAN;  // camera ATE, m
  double joint_t = NAN, joint_r = NAN, free_t = NAN, free_r = NAN;    // m, deg
  double pairs = 0, fps = 0, seg_ate = NAN, iou = NAN, seg_fps = NAN;
  double moving_share = NAN, frozen_share = NAN;  // of the image, see PipelineScene
};

int runPipeline(const std::vector<std::string>& scenes, int frames, int width, double fps,
                double baseline_m, uint64_t first_seed, int seeds,
                const std::vector<std::string>& modes, bool segmentation_only,
                const std::string& mask_dir, const TrackerParams& base) {
  std::printf(
      "whole tracker, %d frames %dx%d with sensor noise (colour sigma 2, depth 0.0015 z^2), "
      "stereo baseline %.2f m, noise seeds %llu..%llu; camera ATE (SE3, m);\nobject motion error "
      "per frame (mean t m / r deg) of the tracker's objects, class joints vs all joints free\n",
      frames, width, width * 3 / 4, baseline_m, static_cast<unsigned long long>(first_seed),
      static_cast<unsigned long long>(first_seed + seeds - 1));
  std::printf(
      "%-6s %3s %-6s | %5s %5s | %8s %8s %8s %9s %6s | %8s %7s | %8s %7s | %5s %5s | %8s %5s "
      "%5s\n",
      "scene", "Hz", "mode", "obj", "frz", "dyn", "no dyn", "frozen", "frz nodyn", "ratio",
      "joint t", "r", "free t", "r", "pairs", "fps", "seg", "IoU", "fps");
  for (const std::string& name : scenes) {
    std::vector<std::vector<PipelineRow>> rows(modes.size());
    double scene_fps = 0;
    for (int k = 0; k < seeds; ++k) {
      SyntheticConfig config;
      config.scene = name;
      config.frames = frames;
      config.width = width;
      config.height = width * 3 / 4;
      config.image_noise_sigma = 2.0;
      config.depth_noise_rel = 0.0015;
      config.fps = fps;
      config.baseline_m = baseline_m;
      config.seed = first_seed + k;
      const PipelineScene s = makePipelineScene(config);
      scene_fps = s.moving.fps();
      std::string free_classes;  // the scene's dynamic classes, all with a free joint
      for (const SemanticClass& c : s.moving.classes()) {
        if (!c.dynamic) continue;
        free_classes += (free_classes.empty() ? "" : ",") + std::to_string(c.id) + ":free";
      }
      for (size_t m = 0; m < modes.size(); ++m) {
        TrackerParams with = base;
        with.mode = modes[m];
        TrackerParams without = with;
        without.dynamic_objects = false;
        TrackerParams all_free = with;
        all_free.dynamic_classes = free_classes;
        PipelineRow row;
        row.moving_share = s.moving_share;
        row.frozen_share = s.frozen_share;
        if (!segmentation_only) {
          const PipelineRun dyn = runTracker(s.moving, s.moving_frames, with);
          const PipelineRun free = runTracker(s.moving, s.moving_frames, all_free);
          row.dyn = dyn.camera.ate_rmse_m;
          row.no_dyn = runTracker(s.moving, s.moving_frames, without).camera.ate_rmse_m;
          row.frozen = runTracker(s.frozen, s.frozen_frames, with).camera.ate_rmse_m;
          row.frozen_no_dyn = runTracker(s.frozen, s.frozen_frames, without).camera.ate_rmse_m;
          row.joint_t = Stats::mean(dyn.object.t);
          row.joint_r = Stats::mean(dyn.object.r) * kDeg;
          row.free_t = Stats::mean(free.object.t);
          row.free_r = Stats::mean(free.object.r) * kDeg;
          row.pairs = static_cast<double>(dyn.object.t.size());
          row.fps = dyn.fps;
        }
        TrackerParams segmenting = with;
        segmenting.motion_segmentation = true;
        const std::string mask_prefix =
            mask_dir.empty() ? ""
                             : mask_dir + "/" + name + "-" + modes[m] + "-" +
                                   (seeds > 1 ? std::to_string(config.seed) + "-" : "");
        const PipelineRun seg =
            runTracker(s.moving, s.unlabelled_frames, segmenting, &s.gt_moving, mask_prefix);
        row.seg_ate = seg.camera.ate_rmse_m;
        row.iou = seg.iou;
        row.seg_fps = seg.fps;
        if (seeds > 1) {
          std::fprintf(
              stderr, "%s %s seed %llu: dyn %.4f frozen %.4f ratio %.2f, IoU %.2f (seg ATE %.4f)\n",
              name.c_str(), modes[m].c_str(), static_cast<unsigned long long>(config.seed), row.dyn,
              row.frozen, row.dyn / row.frozen, row.iou, row.seg_ate);
        }
        rows[m].push_back(row);
      }
    }
    for (size_t m = 0; m < modes.size(); ++m) {
      const auto median = [&](double PipelineRow::*field) {
        std::vector<double> v;
        for (const PipelineRow& r : rows[m]) v.push_back(r.*field);
        return Stats::median(v);
      };
      // The ratio is taken per seed (the same noise in both runs), then its median.
      std::vector<double> ratios;
      for (const PipelineRow& r : rows[m]) ratios.push_back(r.dyn / r.frozen);
      std::printf(
          "%-6s %3.0f %-6s | %5.3f %5.3f | %8.4f %8.4f %8.4f %9.4f %6.2f | %8.4f %7.3f | %8.4f "
          "%7.3f | %5.0f %5.1f | %8.4f %5.2f %5.1f\n",
          name.c_str(), scene_fps, modes[m].c_str(), median(&PipelineRow::moving_share),
          median(&PipelineRow::frozen_share), median(&PipelineRow::dyn),
          median(&PipelineRow::no_dyn), median(&PipelineRow::frozen),
          median(&PipelineRow::frozen_no_dyn), Stats::median(ratios), median(&PipelineRow::joint_t),
          median(&PipelineRow::joint_r), median(&PipelineRow::free_t), median(&PipelineRow::free_r),
          median(&PipelineRow::pairs), median(&PipelineRow::fps), median(&PipelineRow::seg_ate),
          median(&PipelineRow::iou), median(&PipelineRow::seg_fps));
      std::fflush(stdout);
    }
  }
  std::printf(
      "obj, frz: mean share of the image covered by objects of dynamic classes, moving and "
      "frozen.\n"
      "dyn: moving-object pixels kept out of camera tracking, objects tracked; no dyn: every "
      "pixel drives the camera;\n"
      "frozen: the same scene with the objects at their last pose; ratio = dyn / frozen (per "
      "seed). Object errors in the object frame\n"
      "(E = T_o^-1 M_gt^-1 M_est T_o), tracker world mapped to the ground truth's by the first "
      "camera pose.\n"
      "seg: masks withheld, the tracker's motion segmentation instead: camera ATE, the mean "
      "IoU of its moving mask\n"
      "with the true one over the frames where either is non-empty, and frames per second "
      "(frames over the wall time of the run).%s\n",
      seeds > 1 ? "\nEvery figure is the median over the seeds." : "");
  return 0;
}

int run(int argc, char** argv) {
  CommandLine cli(argc, argv, kUsage);
  if (cli.helpRequested()) {
    std::printf("%s", kUsage);
    return 0;
  }
  const bool pipeline = cli.getBool("pipeline", false);
  const std::vector<std::string> scenes = split(cli.get("scenes", "car,door,multi"));
  const int frames = cli.getInt("frames", pipeline ? 150 : 60);
  const int width = cli.getInt("width", pipeline ? 640 : 320);
  const double fps = cli.getDouble("fps", 0);
  const double baseline_m = cli.getDouble("baseline", SyntheticConfig().baseline_m);
  const std::vector<std::string> modes = split(cli.get("modes", "rgbd,stereo"));
  const bool segmentation_only = cli.getBool("segmentation-only", false);
  const std::string mask_dir = cli.get("mask-dir", "");
  const std::string set = cli.get("set", "");
  ObjectNoise noise;
  noise.pixel_sigma = cli.getDouble("pixel-sigma", 1.0);
  noise.depth_sigma_rel = cli.getDouble("depth-noise", 0.002);
  noise.outlier_ratio = cli.getDouble("outliers", 0.05);
  const int stride = cli.getInt("stride", 2);
  const int window = cli.getInt("window", 5);
  const uint64_t seed = static_cast<uint64_t>(cli.getInt("seed", 1));
  const int seeds = cli.getInt("seeds", 1);
  cli.finish();
  for (const std::string& mode : modes)
    if (mode != "rgbd" && mode != "stereo")
      throw std::invalid_argument("--modes: unknown mode '" + mode + "' (rgbd, stereo)");
  if (frames < 2 || width < 32 || stride < 1 || window < 2 || seeds < 1 ||
      !(noise.pixel_sigma > 0) || !(noise.depth_sigma_rel > 0) || noise.outlier_ratio < 0 ||
      noise.outlier_ratio >= 1)
    throw std::invalid_argument(
        "need frames >= 2, width >= 32, stride >= 1, window >= 2, seeds >= 1, pixel-sigma > 0, "
        "depth-noise > 0, 0 <= outliers < 1");

  if (pipeline) {
    std::vector<std::string> overrides;
    std::stringstream items(set);
    for (std::string item; std::getline(items, item, ',');)
      if (!item.empty()) overrides.push_back(item);
    return runPipeline(scenes, frames, width, fps, baseline_m, seed, seeds, modes,
                       segmentation_only, mask_dir, loadTrackerParams("", overrides));
  }
  std::printf(
      "object motion error per frame, mean over frame pairs: translation m, rotation deg\n");
  std::printf("%-6s %-4s %-6s %-8s %5s | %16s | %16s | %16s | %5s | %s\n", "scene", "id", "class",
              "joint", "pairs", "free 6-DOF", "joint (2-frame)", "joint window BA", "ms",
              "joint error");
  std::printf("%-6s %-4s %-6s %-8s %5s | %8s %7s | %8s %7s | %8s %7s | %5s |\n", "", "", "", "", "",
              "t", "r", "t", "r", "t", "r", "");
  for (const std::string& name : scenes) {
    SyntheticConfig config;
    config.scene = name;
    config.frames = frames;
    config.width = width;
    config.height = width * 3 / 4;
    config.fps = fps;
    Bench b{SyntheticScene::make(config), noise, stride, window, std::mt19937_64(seed), {}};
    if (b.scene.objects().empty())
      throw std::invalid_argument("scene '" + name + "' has no moving object");
    for (int f = 0; f < frames; ++f)
      b.views.push_back(b.scene.render(b.scene.cameraPose(f), b.scene.camera(), f));
    for (const SyntheticObject& o : b.scene.objects()) benchObject(&b, o);
  }
  std::printf(
      "Camera poses: ground truth. Correspondences: true projections of the object's pixels of "
      "frame i into frame i+1\n(no flow, no self-occlusion) with %.2f px noise and %.0f%% "
      "outliers; depth noise %.4f z^2 m; %dx%d images, pixel stride %d.\nErrors in the object "
      "frame at frame i (E = T_o^-1 M_gt^-1 M_est T_o). Joints estimated: road plane by RANSAC "
      "on the first frame's\nnoisy road depth; hinge from free-tracked motions of the best-seen "
      "frame to 20 frames either side. "
      "ms = joint-constrained 2-frame tracking per frame.\nWindow BA: %d-frame windows sharing "
      "end frames, points refined with a depth prior, soft constant-velocity term.\n",
      noise.pixel_sigma, 100 * noise.outlier_ratio, noise.depth_sigma_rel, width, width * 3 / 4,
      stride, window);
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-bench-dynamic", radslam::run, argc, argv);
}
