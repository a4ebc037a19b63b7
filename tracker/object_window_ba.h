// Dynamic bundle adjustment of one moving object over a window of frames (TwistSLAM): the
// object's per-frame displacements in joint coordinates and its points, with reprojection terms,
// a depth prior on the points and a soft constant-velocity term on consecutive projected twists.
// Camera poses are given (they come from the static-scene tracker).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "common/lie.h"
#include "common/types.h"
#include "tracker/joints.h"

namespace radslam {

/// Landmark l seen at pixel px in window frame `frame` (after the frame where the landmark was
/// measured, its anchor).
struct ObjectObservation {
  int landmark = 0;
  int frame = 1;
  Eigen::Vector2d px = Eigen::Vector2d::Zero();
};

struct ObjectWindowProblem {
  Joint joint;
  CameraModel camera;
  std::vector<SE3> T_world_cam;  // N >= 2 frames of the window
  // m, the object's points, each measured (depth) in the camera of its anchor frame.
  std::vector<Vec3> points_cam0;
  // The anchor frame of each point, 0..N-2; empty: every point is measured in frame 0.
  std::vector<int> anchor_frame;
  std::vector<ObjectObservation> observations;
  double dt = 0.1;  // s between frames
};

struct ObjectWindowParams {
  int max_iterations = 20;
  double pixel_sigma = 1.0;        // px, observation noise
  double huber_px = 2.0;           // px, Huber threshold on the reprojection error norm
  double depth_sigma_rel = 0.002;  // 1/m, depth sigma = depth_sigma_rel z^2 of points_cam0
  double lateral_sigma_px = 0.1;   // px, uncertainty of points_cam0 across their rays
  // Constant-velocity term |Pi xi_{i+1} - Pi xi_i| dt: sigma of the change of the displacement
  // per frame, translation (m) and rotation (rad) coordinates.
  double cv_sigma_translation = 0.05;
  double cv_sigma_rotation = 0.01;
  bool optimise_points = true;  // false: points fixed at their depth measurement
  // An object is static when every displacement stays below both (m, rad per frame).
  double static_translation = 0.01;
  double static_rotation = 0.002;
};

struct ObjectWindowResult {
  std::vector<JointVector> theta;      // N-1 displacements, joint coordinates (m, rad)
  std::vector<SE3> motion_world;       // M_w,i = T_world_object,i+1 T_world_object,i^-1
  std::vector<Vec6> twist_joint;       // A theta_i / dt (m/s, rad/s)
  std::vector<Mat6> twist_covariance;  // of twist_joint, from the marginal covariance
  Eigen::MatrixXd covariance;          // of (theta_0, ..., theta_{N-2}), points marginalised out
  std::vector<Vec3> points_cam0;       // refined points, camera of their anchor frame (m)
  double rms_px = 0;                   // reprojection RMS of the inliers
  int iterations = 0;
  bool converged = false;
  bool is_static = false;
};

/// Solves the window by Levenberg-Marquardt with the points eliminated by a Schur complement.
/// `initial` (optional, N-1 vectors) seeds the displacements; zero otherwise.
/// Throws std::invalid_argument on an invalid camera, fewer than 2 frames, an observation of an
/// unknown landmark or frame, non-finite input, dt <= 0 or initial of the wrong shape.
ObjectWindowResult solveObjectWindow(const ObjectWindowProblem& problem,
                                     const ObjectWindowParams& params = {},
                                     const std::vector<JointVector>* initial = nullptr);

/// The derivative of the point q moved by Exp(A theta_{f-1}) ... Exp(A theta_from) (joint frame)
/// w.r.t. each theta_m, m < f: columns m*k .. m*k+k-1 of the 3 x (f k) result (zero for
/// m < from). Exposed for the finite-difference test.
Eigen::MatrixXd chainedMotionJacobian(const JointBasis& A, const std::vector<JointVector>& theta,
                                      int f, const Vec3& q, Vec3* moved = nullptr, int from = 0);

}  // namespace radslam
