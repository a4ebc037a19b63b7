// Lie groups SO(3), SE(3), Sim(3) in double precision.
//
/// Conventions (as Sophus):
///  - Quaternions are Eigen's (storage x, y, z, w; constructor order w, x, y, z).
///  - SE(3) tangent vectors are xi = (v, w): translation part first.
///  - Sim(3) tangent vectors are (v, w, sigma) with scale s = exp(sigma).
///  - T_a_b maps points from frame b to frame a: p_a = T_a_b * p_b.
///  - Jacobians with an "H_" prefix are of right perturbations: for f(T),
///    H = d f(T * Exp(delta)) / d delta at delta = 0.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace radslam {

using Vec3 = Eigen::Vector3d;
using Vec4 = Eigen::Vector4d;
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Vec7 = Eigen::Matrix<double, 7, 1>;
using Mat3 = Eigen::Matrix3d;
using Mat4 = Eigen::Matrix4d;
using Mat6 = Eigen::Matrix<double, 6, 6>;
using Mat7 = Eigen::Matrix<double, 7, 7>;
using Mat36 = Eigen::Matrix<double, 3, 6>;
using Mat37 = Eigen::Matrix<double, 3, 7>;

/// Skew-symmetric matrix: hat(a) * b = a x b.
Mat3 hat(const Vec3& a);

class SO3 {
 public:
  SO3() : q_(Eigen::Quaterniond::Identity()) {}
  /// Normalises q.
  explicit SO3(const Eigen::Quaterniond& q);
  /// Projects R onto SO(3) (nearest rotation).
  explicit SO3(const Mat3& R);
  /// A quaternion already of unit norm, kept bit for bit (files that store poses exactly).
  static SO3 fromUnitQuaternion(const Eigen::Quaterniond& q) { return SO3(q, true); }

  static SO3 exp(const Vec3& w);
  Vec3 log() const;

  SO3 inverse() const { return SO3(q_.conjugate(), true); }
  SO3 operator*(const SO3& other) const { return SO3(q_ * other.q_); }
  Vec3 operator*(const Vec3& p) const { return q_ * p; }
  Mat3 matrix() const { return q_.toRotationMatrix(); }
  const Eigen::Quaterniond& quaternion() const { return q_; }
  /// Ad(R) = R: R Exp(w) R^-1 = Exp(R w).
  Mat3 adjoint() const { return matrix(); }

  /// Left Jacobian J_l(w): Exp(w + d) ~= Exp(J_l(w) d) Exp(w).
  static Mat3 leftJacobian(const Vec3& w);
  static Mat3 leftJacobianInverse(const Vec3& w);
  /// Right Jacobian J_r(w) = J_l(-w): Exp(w + d) ~= Exp(w) Exp(J_r(w) d).
  static Mat3 rightJacobian(const Vec3& w) { return leftJacobian(-w); }
  static Mat3 rightJacobianInverse(const Vec3& w) { return leftJacobianInverse(-w); }

 private:
  SO3(const Eigen::Quaterniond& q, bool /*already_unit*/) : q_(q) {}
  Eigen::Quaterniond q_;
};

class SE3 {
 public:
  SE3() : t_(Vec3::Zero()) {}
  SE3(const SO3& R, const Vec3& t) : R_(R), t_(t) {}
  SE3(const Eigen::Quaterniond& q, const Vec3& t) : R_(q), t_(t) {}
  /// From a 4x4 homogeneous matrix (rotation block projected onto SO(3)).
  explicit SE3(const Mat4& T);

  static SE3 exp(const Vec6& xi);
  Vec6 log() const;

  SE3 inverse() const;
  SE3 operator*(const SE3& other) const { return SE3(R_ * other.R_, R_ * other.t_ + t_); }
  Vec3 operator*(const Vec3& p) const { return R_ * p + t_; }

  /// p_a = T * p_b with optional Jacobians wrt a right perturbation of T (3x6)
  /// and wrt p_b (3x3).
  Vec3 transform(const Vec3& p, Mat36* H_pose = nullptr, Mat3* H_point = nullptr) const;

  /// Ad(T) = [[R, hat(t) R], [0, R]] for xi = (v, w): T Exp(xi) T^-1 = Exp(Ad xi).
  Mat6 adjoint() const;

  const SO3& so3() const { return R_; }
  const Vec3& translation() const { return t_; }
  Vec3& translation() { return t_; }
  Mat3 rotation() const { return R_.matrix(); }
  Eigen::Quaterniond quaternion() const { return R_.quaternion(); }
  Mat4 matrix() const;

  /// Left Jacobian of SE(3), (v, w) ordering: Exp(xi + d) ~= Exp(J_l d) Exp(xi).
  static Mat6 leftJacobian(const Vec6& xi);
  static Mat6 rightJacobian(const Vec6& xi) { return leftJacobian(-xi); }
  /// Closed form [[J^-1, -J^-1 Q J^-1], [0, J^-1]]; singular only at |w| = 2 pi.
  static Mat6 leftJacobianInverse(const Vec6& xi);
  static Mat6 rightJacobianInverse(const Vec6& xi) { return leftJacobianInverse(-xi); }

 private:
  SO3 R_;
  Vec3 t_;
};

/// Similarity transform p_a = s R p_b + t (scale s > 0), e.g. the alignment of
/// a monocular trajectory to ground truth: T_gt_est.
/// Tangent vectors are x = (v, w, sigma), sigma = log(s); Exp(x) has rotation
/// Exp(w), scale exp(sigma) and translation W(sigma, w) v.
class Sim3 {
 public:
  Sim3() : t_(Vec3::Zero()) {}
  /// Throws std::invalid_argument unless scale is finite and > 0.
  Sim3(const SO3& R, const Vec3& t, double scale);
  /// The rigid transform T as a similarity of scale 1.
  explicit Sim3(const SE3& T) : R_(T.so3()), t_(T.translation()) {}
  /// From [[s R, t], [0, 1]]; s = cbrt(det) and R is projected onto SO(3).
  /// Throws std::invalid_argument if the 3x3 block has det <= 0 or is not finite.
  explicit Sim3(const Mat4& T);

  static Sim3 exp(const Vec7& x);
  /// Rotation angle in [0, pi].
  Vec7 log() const;

  Sim3 inverse() const;
  Sim3 operator*(const Sim3& other) const;
  Vec3 operator*(const Vec3& p) const { return scale_ * (R_ * p) + t_; }

  /// p_a = s R p_b + t with optional Jacobians wrt a right perturbation
  /// T * Exp(v, w, sigma) (3x7) and wrt p_b (3x3).
  Vec3 transform(const Vec3& p, Mat37* H_pose = nullptr, Mat3* H_point = nullptr) const;

  /// Moves a rigid pose into frame a: T_a_c from T_b_c. The rotation is
  /// composed and the camera centre is transformed (scaled); frame c itself
  /// stays metric, so the result is an SE(3) pose.
  SE3 transformPose(const SE3& T_b_c) const;

  /// Ad(T) = [[s R, hat(t) R, -t], [0, R, 0], [0, 0, 1]] for x = (v, w, sigma):
  /// T Exp(x) T^-1 = Exp(Ad x).
  Mat7 adjoint() const;

  const SO3& so3() const { return R_; }
  Mat3 rotation() const { return R_.matrix(); }
  const Vec3& translation() const { return t_; }
  double scale() const { return scale_; }
  Mat4 matrix() const;

 private:
  SO3 R_;
  Vec3 t_;
  double scale_ = 1.0;
};

}  // namespace radslam
