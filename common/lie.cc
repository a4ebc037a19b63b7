#include "common/lie.h"

#include <cmath>

namespace radslam {
namespace {
// Below this angle (radians) the Taylor expansions are used; their error is
// far below double precision there.
constexpr double kSmallAngle = 1e-5;
}  // namespace

Mat3 hat(const Vec3& a) {
  Mat3 m;
  m << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
  return m;
}

SO3::SO3(const Eigen::Quaterniond& q) : q_(q.normalized()) {}

SO3::SO3(const Mat3& R) {
  Eigen::JacobiSVD<Mat3> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 U = svd.matrixU();
  const Mat3 V = svd.matrixV();
  if ((U * V.transpose()).determinant() < 0) U.col(2) *= -1;
  q_ = Eigen::Quaterniond(Mat3(U * V.transpose())).normalized();
}

SO3 SO3::exp(const Vec3& w) {
  const double theta = w.norm();
  const double half = 0.5 * theta;
  double imag_factor, real;
  if (theta < kSmallAngle) {
    const double theta2 = theta * theta;
    imag_factor = 0.5 - theta2 / 48.0;
    real = 1.0 - theta2 / 8.0;
  } else {
    imag_factor = std::sin(half) / theta;
    real = std::cos(half);
  }
  return SO3(Eigen::Quaterniond(real, imag_factor * w.x(), imag_factor * w.y(),
                                imag_factor * w.z()));
}

Vec3 SO3::log() const {
  // Use the quaternion with w >= 0 so the angle lies in [0, pi].
  Eigen::Quaterniond q = q_;
  if (q.w() < 0) q.coeffs() *= -1;
  const Vec3 v = q.vec();
  const double sin_half = v.norm();
  if (sin_half < kSmallAngle) {
    // theta ~= 2 sin_half / w; keep the second-order term.
    return (2.0 / q.w() - 2.0 / 3.0 * sin_half * sin_half / (q.w() * q.w() * q.w())) * v;
  }
  const double theta = 2.0 * std::atan2(sin_half, q.w());
  return theta / sin_half * v;
}

Mat3 SO3::leftJacobian(const Vec3& w) {
  const double theta = w.norm();
  const Mat3 W = hat(w);
  if (theta < kSmallAngle) return Mat3::Identity() + 0.5 * W + W * W / 6.0;
  const double t2 = theta * theta;
  return Mat3::Identity() + (1.0 - std::cos(theta)) / t2 * W +
         (theta - std::sin(theta)) / (t2 * theta) * W * W;
}

Mat3 SO3::leftJacobianInverse(const Vec3& w) {
  const double theta = w.norm();
  const Mat3 W = hat(w);
  if (theta < kSmallAngle) return Mat3::Identity() - 0.5 * W + W * W / 12.0;
  const double t2 = theta * theta;
  const double coef =
      1.0 / t2 - (1.0 + std::cos(theta)) / (2.0 * theta * std::sin(theta));
  return Mat3::Identity() - 0.5 * W + coef * W * W;
}

SE3::SE3(const Mat4& T) : R_(Mat3(T.block<3, 3>(0, 0))), t_(T.block<3, 1>(0, 3)) {}

SE3 SE3::exp(const Vec6& xi) {
  const Vec3 v = xi.head<3>();
  const Vec3 w = xi.tail<3>();
  return SE3(SO3::exp(w), SO3::leftJacobian(w) * v);
}

Vec6 SE3::log() const {
  const Vec3 w = R_.log();
  Vec6 xi;
  xi << SO3::leftJacobianInverse(w) * t_, w;
  return xi;
}

SE3 SE3::inverse() const {
  const SO3 R_inv = R_.inverse();
  return SE3(R_inv, -(R_inv * t_));
}

Vec3 SE3::transform(const Vec3& p, Mat36* H_pose, Mat3* H_point) const {
  const Mat3 R = R_.matrix();
  // d/d(v, w) of R (exp(w) p + v) + t at 0 = [R, -R hat(p)].
  if (H_pose) *H_pose << R, -R * hat(p);
  if (H_point) *H_point = R;
  return R * p + t_;
}

Mat6 SE3::adjoint() const {
  const Mat3 R = R_.matrix();
  Mat6 ad;
  ad << R, hat(t_) * R, Mat3::Zero(), R;
  return ad;
}

Mat4 SE3::matrix() const {
  Mat4 T = Mat4::Identity();
  T.block<3, 3>(0, 0) = R_.matrix();
  T.block<3, 1>(0, 3) = t_;
  return T;
}

Mat6 SE3::leftJacobian(const Vec6& xi) {
  // Barfoot, State Estimation for Robotics, (7.86), reordered for (v, w).
  const Vec3 v = xi.head<3>();
  const Vec3 w = xi.tail<3>();
  const Mat3 Jw = SO3::leftJacobian(w);
  const Mat3 V = hat(v);
  const Mat3 W = hat(w);
  const double theta = w.norm();
  Mat3 Q;
  if (theta < kSmallAngle) {
    Q = 0.5 * V + (W * V + V * W + W * V * W) / 6.0;
  } else {
    const double t2 = theta * theta, t3 = t2 * theta, t4 = t3 * theta, t5 = t4 * theta;
    const double s = std::sin(theta), c = std::cos(theta);
    Q = 0.5 * V + (theta - s) / t3 * (W * V + V * W + W * V * W) +
        (t2 + 2 * c - 2) / (2 * t4) * (W * W * V + V * W * W - 3 * W * V * W) +
        (2 * theta - 3 * s + theta * c) / (2 * t5) * (W * V * W * W + W * W * V * W);
  }
  Mat6 J;
  J << Jw, Q, Mat3::Zero(), Jw;
  return J;
}

}  // namespace radslam
