// Frame-to-frame tracking of a moving object constrained by its joint (TwistSLAM): Gauss-Newton
// over the joint coordinates theta of the object's displacement (see tracker/joints.h), from the
// object's 3-D points in frame i (depth) and their pixels in frame i+1 (flow), camera poses
// given.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "common/lie.h"
#include "common/types.h"
#include "tracker/joints.h"

namespace radslam {

/// One point of the object: where it is in camera i and where it is seen in frame i+1.
struct ObjectCorrespondence {
  Vec3 p_cam0 = Vec3::Zero();                     // m, camera frame of frame i
  Eigen::Vector2d px1 = Eigen::Vector2d::Zero();  // pixel in frame i+1
};

using JointJacobian = Eigen::Matrix<double, 2, Eigen::Dynamic, 0, 2, 6>;

/// Reprojection residual of a point fixed to the object:
///   r = project(T_cam1_joint Exp(A theta) q_joint) - px1,
/// q_joint = the point in the joint frame at frame i. H_theta = dr / dtheta (2 x k), exact
/// (through the left Jacobian of SE(3)). Returns false (r, H untouched) if the point lands
/// behind camera i+1 (z < 1e-6 m).
bool objectReprojectionResidual(const CameraModel& camera, const SE3& T_cam1_joint,
                                const Vec3& q_joint, const Eigen::Vector2d& px1,
                                const JointBasis& A, const JointVector& theta, Eigen::Vector2d* r,
                                JointJacobian* H_theta = nullptr);

struct ObjectTrackingParams {
  int max_iterations = 30;
  double huber_px = 2.0;          // px, Huber threshold on the residual norm
  double pixel_sigma = 1.0;       // px, correspondence noise (scales the covariance)
  double step_tolerance = 1e-10;  // stop when |delta theta| falls below (m, rad)
  int min_points = 6;
};

struct ObjectMotionEstimate {
  JointVector theta;       // joint coordinates of the displacement (m, rad per frame)
  SE3 motion_world;        // M_w = T_world_object,i+1 T_world_object,i^-1
  Vec6 twist_joint;        // A theta / dt in the joint frame (m/s, rad/s)
  JointMatrix covariance;  // of theta, pixel_sigma^2 (J^T W J)^-1
  Mat6 twist_covariance;   // of twist_joint: A cov A^T / dt^2, ordering (v, w)
  double rms_px = 0;       // residual RMS of the inliers at the solution
  int inliers = 0;         // points with |r| < huber_px
  int iterations = 0;
  bool converged = false;
};

/// Estimates the object's displacement between frames i and i+1 (dt seconds apart) under its
/// joint. `initial` (optional) seeds theta (e.g. the previous velocity); zero otherwise.
/// Throws std::invalid_argument on an invalid camera, dt <= 0, fewer than min_points
/// correspondences, non-finite input or an initial vector of the wrong size.
ObjectMotionEstimate trackObjectMotion(const Joint& joint, const CameraModel& camera,
                                       const SE3& T_world_cam0, const SE3& T_world_cam1,
                                       const std::vector<ObjectCorrespondence>& correspondences,
                                       double dt, const ObjectTrackingParams& params = {},
                                       const JointVector* initial = nullptr);

/// Correspondences of one object from its instance mask and depth in frame i and the dense
/// flow i -> i+1: every `stride`-th pixel (in x and y) with instance == object_id, depth > 0
/// and a finite flow landing inside the image. depth CV_32FC1 (m), instance CV_16UC1 or
/// CV_32SC1, flow CV_32FC2 (px). Throws std::invalid_argument on mismatched sizes or types.
std::vector<ObjectCorrespondence> objectCorrespondencesFromFlow(const CameraModel& camera,
                                                                const cv::Mat& depth,
                                                                const cv::Mat& instance,
                                                                int object_id, const cv::Mat& flow,
                                                                int stride = 1);

/// The pose given to a newly seen object: origin at the centroid of its points (world, m), axes
/// those of its joint frame (so a planar object's x-y plane is parallel to its parent plane).
/// Throws std::invalid_argument on no or non-finite points.
SE3 initialObjectPose(const Joint& joint, const std::vector<Vec3>& points_world);

/// Moves a tracked object by an estimate: T_world_object <- M_w T_world_object, and sets its
/// twist (joint frame), twist covariance, joint type and joint frame.
void applyObjectMotion(const ObjectMotionEstimate& estimate, const Joint& joint,
                       TrackedObject* object);

/// Error of an estimated object motion (VDO-SLAM / DynoSAM style), written in the object frame
/// so it does not depend on where the world origin is: E = T_world_object^-1 M_gt^-1 M_est
/// T_world_object, the error of the object's pose at frame i+1 when its pose at frame i is
/// right. M_* = T_world_object,i+1 T_world_object,i^-1.
struct MotionError {
  double translation = 0;  // m, |t(E)|
  double rotation = 0;     // rad, angle of R(E)
};
MotionError objectMotionError(const SE3& M_est_world, const SE3& M_gt_world,
                              const SE3& T_world_object);

}  // namespace radslam
