// Moving objects inside the tracker (TwistSLAM): which pixels belong to moving objects (kept out
// of camera tracking and of mapping), and every object's pose and twist under its joint, frame
// to frame, from the depth of the previous frame and the dense flow to the current one.
// DESIGN.md section 5.
//
/// Clusters. The frame's instance mask splits the image into clusters; the class mask and the
/// class table (DynamicClass) say which clusters may move and how: a planar joint on the plane of
/// a static parent class (a car on the road), a revolute joint (a door: its hinge is estimated
/// from the motion observed while the object is tracked with a free joint), or a free joint.
/// Static classes drive the camera. An object of a dynamic class is moving until its twist has
/// stayed below static_speed / static_angular_speed for static_frames frames; it then returns to
/// the static map (its pixels take part in camera tracking) until it moves again.
///
/// Objects are tracked only where the frame has depth (RGB-D sensor depth, stereo disparity, or
/// none in monocular mode, where only the masking applies).
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/binary_io.h"
#include "common/lie.h"
#include "common/types.h"
#include "tracker/frontend_flow.h"
#include "tracker/joints.h"
#include "tracker/object_tracking.h"
#include "tracker/object_window_ba.h"

namespace radslam {

/// A class whose instances may move, its joint and the static class that carries it.
struct DynamicClass {
  int class_id = 0;
  JointType joint = JointType::kFree;
  int parent_class = -1;  // class whose plane carries a planar joint; -1 = none
};

/// Parses the class table "ID:JOINT[:PARENT],...", JOINT = free | planar | revolute, e.g.
/// "10:planar:1,11:revolute:2". "" = no dynamic class. Throws std::invalid_argument naming the
/// item that is wrong (a planar joint needs a parent class, ids are 1..65535 and unique).
std::vector<DynamicClass> parseDynamicClasses(const std::string& spec);

struct ObjectTrackerParams {
  std::vector<DynamicClass> classes;
  int stride = 2;  // working px between the sample points of an object
  // The flow for objects is warped by the prediction of each object's last motion, smoothed
  // by this Gaussian sigma (working px): less than the camera's, as an object's flow differs
  // from the background's right at its silhouette (12 px put 5 cm per frame on the cars).
  double flow_warp_smoothing_px = 4;
  int min_points = 30;            // points an object needs to be tracked in a frame
  double max_depth_m = 30.0;      // farther depths are not used (noise grows with z^2)
  int hinge_min_motions = 5;      // tracked frames before a hinge is estimated
  double hinge_min_angle = 0.05;  // rad: motions used for the hinge turn at least this much
  // An object is flat (a door: its hinge comes from its planes once they have turned by
  // hinge_min_angle, hingeFromPlanes) when this fraction of its points lies on one plane
  // (plane.inlier_threshold).
  double flat_fraction = 0.8;
  double static_speed = 0.05;  // m/s: below it (and static_angular_speed) an object is still
  double static_angular_speed = 0.02;  // rad/s
  int static_frames = 10;              // still frames before an object returns to the static map
  // The moving mask grows by this many working px: the background next to a moving object's
  // silhouette is occluded and revealed from frame to frame, and its flow there is wrong
  // (synthetic car, RGB-D camera ATE: 0.0121 m without, 0.0093 m with 3 px).
  int mask_dilation_px = 3;
  ObjectTrackingParams tracking;
  PlaneRansacParams plane;  // parent plane fit (inlier_threshold in m)
  // Dynamic BA (object_window_ba.h) over each object's last window_frames frames: the frame to
  // frame estimate seeds it, its newest displacement moves the object. <= 1: frame to frame only.
  int window_frames = 5;
  int window_points = 1000;  // points measured per frame for the window (evenly picked)
  // The points stay at their measured depth: refined along their rays they let the motion slide
  // along the rays too (synthetic car, 10 Hz, seed 1, RGB-D: 0.0594 m / 1.04 deg per frame
  // refined, 0.0421 m / 0.364 deg fixed; frame to frame 0.0652 m / 0.390 deg).
  ObjectWindowParams window = [] {
    ObjectWindowParams w;
    w.optimise_points = false;
    return w;
  }();
};

/// One frame at working resolution.
struct ObjectFrame {
  Header header;
  int64_t frame_index = 0;
  cv::Mat grey;      // CV_8UC1
  cv::Mat depth;     // CV_32FC1 m, 0 = invalid; empty = no depth (objects are not tracked)
  cv::Mat instance;  // CV_16UC1; empty = no instance mask (classes alone mask pixels)
  cv::Mat class_id;  // CV_16UC1; empty = no segmentation (nothing is masked)
  SE3 T_world_cam;
};

class ObjectTracker {
 public:
  /// `camera`: the working camera (pinhole) of every frame. Throws std::invalid_argument on an
  /// invalid camera or parameters.
  ObjectTracker(ObjectTrackerParams params, const CameraModel& camera,
                const FlowOptions& flow_options);

  /// CV_8UC1 working size, 255 where a pixel belongs to a moving object (the classes and the
  /// objects' state of the frames tracked so far), grown by mask_dilation_px; empty when
  /// nothing moves. Throws std::invalid_argument on masks of the wrong type or size.
  cv::Mat movingMask(const cv::Mat& instance, const cv::Mat& class_id) const;

  /// Tracks the objects from the previous frame given to track() to this one (frames in order)
  /// and returns the objects seen in this frame with their pose, twist, joint and covariance.
  ObjectList track(const ObjectFrame& frame);

  bool hasDynamicClasses() const { return !params_.classes.empty(); }

  /// The state carried from frame to frame (tracker checkpoints); load() replaces it.
  void save(BinaryWriter* out) const;
  void load(BinaryReader* in);

 private:
  struct ObjectState {
    TrackedObject object;
    Joint joint;               // in use (free until a planar or revolute joint is known)
    bool joint_final = false;  // the class's joint is known
    SE3 T_world_object_first;  // for the hinge: motions since the first tracked frame
    // Revolute: the plane of a flat object there; zero normal: not flat.
    Plane first_plane{Vec3::Zero(), 0.0};
    std::vector<SE3> motions;  // M_w from the first tracked frame, while the hinge is unknown
    JointVector last_theta;    // last displacement (warm start), joint coordinates
    SE3 last_motion_world;     // last frame-to-frame motion M_w (flow prediction)
    double last_dt = 0;        // s, of last_motion_world
    int still_frames = 0;
    bool is_static = false;  // returned to the static map
    // Dynamic BA window: its frames' camera poses and times, the displacements between them
    // (joint coordinates of `joint`), and points measured in one frame with their pixels in the
    // frames after it.
    std::vector<SE3> window_T_world_cam;
    std::vector<int64_t> window_utime;  // us
    std::vector<JointVector> window_theta;
    struct WindowPoint {
      int anchor = 0;                   // window frame where the point was measured
      Vec3 p_anchor;                    // m, camera of the anchor frame
      std::vector<Eigen::Vector2d> px;  // in frames anchor + 1, anchor + 2, ...
      bool alive = true;                // still followed by the flow
    };
    std::vector<WindowPoint> window_points;
    void resetWindow();
  };
  struct InstanceInfo {
    int class_id = 0;
    int pixels = 0;
  };

  const DynamicClass* dynamicClass(int class_id) const;
  /// Instances of dynamic classes in a frame (instance id -> class and size).
  std::map<int, InstanceInfo> dynamicInstances(const cv::Mat& instance,
                                               const cv::Mat& class_id) const;
  std::vector<Vec3> objectPoints(const ObjectFrame& frame, int instance_id) const;
  /// The plane most of the points lie on (flat_fraction); false if none.
  bool flatPlane(const std::vector<Vec3>& points_world, Plane* plane) const;
  /// The joint of a new object of class `dc`; false (free joint in *joint) when its frame
  /// cannot be estimated yet.
  bool estimateJoint(const DynamicClass& dc, const ObjectFrame& frame,
                     const std::vector<Vec3>& points_world, Joint* joint) const;
  void updateObject(ObjectState* state, const DynamicClass& dc, const ObjectFrame& frame,
                    const std::vector<ObjectCorrespondence>& correspondences, const cv::Mat& flow,
                    double dt);
  /// Adds the frame to the object's window (its points followed along `flow`, previous ->
  /// frame, new points from `correspondences`) and replaces `estimate` (the frame-to-frame
  /// one, which seeds it) by the window BA's newest displacement.
  void refineInWindow(ObjectState* state, const ObjectFrame& frame,
                      const std::vector<ObjectCorrespondence>& correspondences, const cv::Mat& flow,
                      ObjectMotionEstimate* estimate) const;
  /// Flow previous -> frame predicted by the previous frame's depth, the camera poses and each
  /// tracked object's last motion at constant velocity (working px, CV_32FC2; NaN without depth).
  cv::Mat flowPrediction(const ObjectFrame& frame, double dt) const;

  ObjectTrackerParams params_;
  CameraModel camera_;
  DenseFlow flow_;
  std::map<int, ObjectState> objects_;  // by instance id
  bool has_previous_ = false;
  ObjectFrame previous_;
};

}  // namespace radslam
