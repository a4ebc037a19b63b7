// Mechanical joints of moving objects (TwistSLAM): the twist subspace a joint allows, its
// projector, adjoint transport of twists, and the estimation of joint frames (parent plane by
// RANSAC + SVD, hinge axis from observed motion).
//
/// Object motion convention. Between frames i and i+1 an object moves by the world-frame left
/// motion M_w,i = T_world_object,i+1 * T_world_object,i^-1. Written in the joint frame j
/// (z = parent plane normal or hinge axis, origin on the plane / on the axis) it is
///   M_j,i = T_joint_world * M_w,i * T_world_joint = Exp(A theta_i),
/// with A the 6 x k twist basis of the joint and theta_i in R^k the joint coordinates of the
/// displacement (metres and radians per frame). The object velocity (TwistSLAM's xi) is
/// xi_j = A theta_i / dt, twist ordering (v, w) as in common/lie.h, and the joint keeps it in
/// span(A): Pi xi_j = xi_j. The columns of A are unit vectors of the canonical basis, so A has
/// orthonormal columns, Pi = A A^T and |theta| = |Pi xi dt|.
///  - planar (3 DOF): vx, vy, wz: in-plane translation and rotation about the normal. This set
///    is the Lie algebra of the motions that map the plane z = 0 onto itself (SE(2)), so
///    Exp(A theta) never leaves the plane, whatever theta.
///  - revolute (1 DOF): wz, rotation about the hinge (the joint z axis through its origin).
///  - free (6 DOF): A = I.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "common/lie.h"
#include "common/types.h"

namespace radslam {

/// 6 x k twist basis (k <= 6) and k-vectors of joint coordinates, without heap allocation.
using JointBasis = Eigen::Matrix<double, 6, Eigen::Dynamic, 0, 6, 6>;
using JointVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 6, 1>;
using JointMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 6, 6>;

/// Degrees of freedom: free 6, planar 3, revolute 1.
int jointDof(JointType type);

/// The twist basis A of a joint, in its own frame (see the header comment).
JointBasis jointBasis(JointType type);
/// Pi = A (A^T A)^-1 A^T: the orthogonal projector onto span(A). Throws std::invalid_argument
/// if A has no columns or is rank deficient.
Mat6 twistProjector(const JointBasis& A);

/// xi_b = Ad(T_b_a) xi_a: the same rigid motion, written in frame b instead of frame a
/// (Exp(xi_b) = T_b_a Exp(xi_a) T_b_a^-1).
Vec6 transportTwist(const SE3& T_b_a, const Vec6& xi_a);

/// A joint: its type and frame. Immutable value type.
class Joint {
 public:
  Joint() = default;
  /// T_world_joint: z = plane normal (planar) or hinge axis (revolute), origin on the plane or
  /// on the axis; ignored by the free joint's motion model but kept as its frame.
  Joint(JointType type, const SE3& T_world_joint);

  JointType type() const { return type_; }
  int dof() const { return static_cast<int>(A_.cols()); }
  const SE3& T_world_joint() const { return T_world_joint_; }
  const JointBasis& basis() const { return A_; }
  const Mat6& projector() const { return Pi_; }

  /// M_j = Exp(A theta): the displacement in the joint frame. Throws std::invalid_argument if
  /// theta has the wrong size.
  SE3 motionJoint(const JointVector& theta) const;
  /// M_w = T_world_joint Exp(A theta) T_joint_world.
  SE3 motionWorld(const JointVector& theta) const;
  /// The joint coordinates of the joint-frame displacement closest to M_w:
  /// theta = A^T Log(T_joint_world M_w T_world_joint) (the part of the motion the joint
  /// cannot make is dropped).
  JointVector coordinates(const SE3& M_world) const;
  /// The velocity twist in the joint frame, A theta / dt (m/s, rad/s). dt > 0 (s).
  Vec6 twist(const JointVector& theta, double dt) const;

 private:
  JointType type_ = JointType::kFree;
  SE3 T_world_joint_;
  JointBasis A_ = JointBasis::Identity(6, 6);
  Mat6 Pi_ = Mat6::Identity();
};

/// Plane n . p + d = 0 with |n| = 1.
struct Plane {
  Vec3 normal = Vec3::UnitZ();
  double d = 0;                                                       // m
  double distance(const Vec3& p) const { return normal.dot(p) + d; }  // signed, m
};

/// Least-squares plane through the points (SVD of the centred points: the normal is the
/// singular vector of the smallest singular value). Throws std::invalid_argument with fewer than
/// 3 points, non-finite points, or collinear points.
Plane fitPlaneSvd(const std::vector<Vec3>& points);

struct PlaneRansacParams {
  int iterations = 200;
  double inlier_threshold = 0.05;  // m, point-to-plane distance
  int min_inliers = 10;
  uint64_t seed = 1;  // same seed -> same result
};

struct PlaneFit {
  Plane plane;
  std::vector<int> inliers;  // indices into the input points
  double rms = 0;            // m, point-to-plane distance of the inliers after the refit
};

/// RANSAC on 3-point samples, then an SVD refit on the best consensus set (repeated once with
/// the refit plane's inliers). Throws std::invalid_argument if there are fewer than
/// max(3, min_inliers) points or no plane gathers min_inliers inliers.
PlaneFit fitPlaneRansac(const std::vector<Vec3>& points, const PlaneRansacParams& params = {});

/// A joint frame on a plane: z = the plane normal (flipped to point towards `up_hint` when the
/// hint is non-zero), origin = the projection of `near_point` onto the plane, x = the component
/// of the world x axis (or y if x is near the normal) in the plane.
SE3 planeJointFrame(const Plane& plane, const Vec3& near_point, const Vec3& up_hint = Vec3::Zero());

/// A rotation axis: unit direction and a point on it (world frame, m).
struct Hinge {
  Vec3 axis = Vec3::UnitZ();
  Vec3 point = Vec3::Zero();
};

/// The screw axis of rigid motions M_w of one object (each = T_world_object,b *
/// T_world_object,a^-1 for some pair of frames), combined by least squares: the axis is the
/// principal direction of the rotation vectors (weighted by angle), the point the one closest to
/// all the screw lines, taken nearest to the origin along the axis. Motions rotating less than
/// min_angle (rad) are skipped. Throws std::invalid_argument if none is left.
Hinge hingeFromMotions(const std::vector<SE3>& motions_world, double min_angle = 1e-3);

/// The hinge of a flat object that turns about an axis in its own plane (a door, a gate, a lid):
/// the intersection of its planes in two poses, with the point nearest to `near_point`. Plane
/// fits to thousands of depth points give it far more precisely than tracked motions, whose
/// errors accumulate (synthetic door: axis 26-37 deg off from the motions of its first frames,
/// 0.02-0.2 deg from its planes). Off by up to half the object's thickness when the planes are
/// fitted to one face. Throws std::invalid_argument when the planes are within min_angle (rad).
Hinge hingeFromPlanes(const Plane& a, const Plane& b, const Vec3& near_point, double min_angle);

/// A joint frame on a hinge: z = axis, origin = point, x perpendicular to the axis.
SE3 hingeJointFrame(const Hinge& hinge);

}  // namespace radslam
