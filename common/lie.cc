#include "common/lie.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace radslam {
namespace {
// Below this angle (radians) the Taylor expansions are used; their error is
// far below double precision there.
constexpr double kSmallAngle = 1e-5;
// The SE(3) coupling coefficients lose ~eps/theta^4 to cancellation in closed
// form, so their Taylor series is used up to this larger angle (radians).
constexpr double kSeriesAngle = 1e-2;
// Sim(3): below this |(sigma, theta)| the coefficients of W come from their
// double series (truncation error < 1e-20), above it from the closed form
// (cancellation error ~ eps / 0.1).
constexpr double kSimSeries = 0.1;
constexpr int kSimSeriesDegree = 14;

// W(sigma, w) = int_0^1 exp(tau (sigma I + hat(w))) dtau = a I + b hat(w) + c hat(w)^2,
// the translation Jacobian of the Sim(3) exponential (SO(3)'s J_l when sigma = 0).
struct SimWCoefficients {
  double a, b, c;
};

SimWCoefficients simWCoefficients(double sigma, double theta) {
  SimWCoefficients k;
  k.a = sigma == 0.0 ? 1.0 : std::expm1(sigma) / sigma;
  if (std::hypot(sigma, theta) < kSimSeries) {
    // b = int e^(sigma tau) sin(theta tau) / theta, c = int e^(sigma tau) (1 - cos(theta tau)) /
    // theta^2, expanded: sum (-1)^k sigma^m theta^2k / (m! (2k+1)! (m+2k+2)) and
    // sum (-1)^k sigma^m theta^2k / (m! (2k+2)! (m+2k+3)).
    k.b = 0.0;
    k.c = 0.0;
    const double theta2 = theta * theta;
    double theta_pow = 1.0, fact_odd = 1.0, fact_even = 2.0;  // theta^2k, (2k+1)!, (2k+2)!
    for (int kk = 0; 2 * kk <= kSimSeriesDegree; ++kk) {
      const double sign = (kk % 2 == 0) ? 1.0 : -1.0;
      double sigma_pow = 1.0, fact_m = 1.0;  // sigma^m, m!
      for (int m = 0; m + 2 * kk <= kSimSeriesDegree; ++m) {
        const double common = sign * sigma_pow * theta_pow / fact_m;
        k.b += common / (fact_odd * (m + 2 * kk + 2));
        k.c += common / (fact_even * (m + 2 * kk + 3));
        sigma_pow *= sigma;
        fact_m *= m + 1;
      }
      theta_pow *= theta2;
      fact_odd *= (2 * kk + 2) * (2 * kk + 3);
      fact_even *= (2 * kk + 3) * (2 * kk + 4);
    }
    return k;
  }
  const double s = std::exp(sigma);
  const double em1 = std::expm1(sigma);
  if (theta < 1e-6) {
    // Here |sigma| >= ~0.1: the theta = 0 limits, int tau e^(sigma tau) and
    // int tau^2 / 2 e^(sigma tau); the theta^2 corrections are below 1e-12.
    const double sigma2 = sigma * sigma;
    k.b = (sigma * s - em1) / sigma2;
    k.c = (s * sigma2 - 2.0 * sigma * s + 2.0 * em1) / (2.0 * sigma2 * sigma);
    return k;
  }
  // With C + i S = int_0^1 e^((sigma + i theta) tau) dtau = (e^(sigma + i theta) - 1) /
  // (sigma + i theta): b = S / theta, c = (a - C) / theta^2.
  const double st = std::sin(theta), ct = std::cos(theta);
  const double half_sin = std::sin(0.5 * theta);
  const double s_cos_m1 = em1 * ct - 2.0 * half_sin * half_sin;  // s cos(theta) - 1
  const double rho2 = sigma * sigma + theta * theta;
  k.b = (sigma * s * st / theta - s_cos_m1) / rho2;
  const double C = (sigma * s_cos_m1 + theta * s * st) / rho2;
  k.c = (k.a - C) / (theta * theta);
  return k;
}

Mat3 simW(double sigma, const Vec3& w) {
  const SimWCoefficients k = simWCoefficients(sigma, w.norm());
  const Mat3 W = hat(w);
  return k.a * Mat3::Identity() + k.b * W + k.c * W * W;
}
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
  return SO3(
      Eigen::Quaterniond(real, imag_factor * w.x(), imag_factor * w.y(), imag_factor * w.z()));
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
  // 1 - cos(theta) = 2 sin^2(theta / 2) without cancellation.
  const double half_sin = std::sin(0.5 * theta);
  return Mat3::Identity() + 2.0 * half_sin * half_sin / t2 * W +
         (theta - std::sin(theta)) / (t2 * theta) * W * W;
}

Mat3 SO3::leftJacobianInverse(const Vec3& w) {
  const double theta = w.norm();
  const Mat3 W = hat(w);
  if (theta < kSmallAngle) return Mat3::Identity() - 0.5 * W + W * W / 12.0;
  // (1 + cos) / sin = cot(theta / 2) stays accurate near theta = pi.
  const double coef = 1.0 / (theta * theta) - 0.5 / (theta * std::tan(0.5 * theta));
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

namespace {
// The coupling block Q of the SE(3) left Jacobian (Barfoot, State Estimation
// for Robotics, (7.86), (v, w) ordering).
Mat3 se3Q(const Vec3& v, const Vec3& w) {
  const Mat3 V = hat(v);
  const Mat3 W = hat(w);
  const double theta = w.norm();
  double c1, c2, c3;
  if (theta < kSeriesAngle) {
    const double t2 = theta * theta, t4 = t2 * t2;
    c1 = 1.0 / 6.0 - t2 / 120.0 + t4 / 5040.0;
    c2 = 1.0 / 24.0 - t2 / 720.0 + t4 / 40320.0;
    c3 = 1.0 / 120.0 - t2 / 2520.0 + t4 / 120960.0;
  } else {
    const double t2 = theta * theta, t3 = t2 * theta, t4 = t3 * theta, t5 = t4 * theta;
    const double s = std::sin(theta), c = std::cos(theta);
    c1 = (theta - s) / t3;
    c2 = (t2 + 2 * c - 2) / (2 * t4);
    c3 = (2 * theta - 3 * s + theta * c) / (2 * t5);
  }
  return 0.5 * V + c1 * (W * V + V * W + W * V * W) + c2 * (W * W * V + V * W * W - 3 * W * V * W) +
         c3 * (W * V * W * W + W * W * V * W);
}
}  // namespace

Mat6 SE3::leftJacobian(const Vec6& xi) {
  const Vec3 w = xi.tail<3>();
  const Mat3 Jw = SO3::leftJacobian(w);
  Mat6 J;
  J << Jw, se3Q(xi.head<3>(), w), Mat3::Zero(), Jw;
  return J;
}

Mat6 SE3::leftJacobianInverse(const Vec6& xi) {
  const Vec3 w = xi.tail<3>();
  const Mat3 Jw_inv = SO3::leftJacobianInverse(w);
  Mat6 J;
  J << Jw_inv, -Jw_inv * se3Q(xi.head<3>(), w) * Jw_inv, Mat3::Zero(), Jw_inv;
  return J;
}

Sim3::Sim3(const SO3& R, const Vec3& t, double scale) : R_(R), t_(t), scale_(scale) {
  if (!(std::isfinite(scale) && scale > 0.0)) {
    throw std::invalid_argument("Sim3: scale must be finite and > 0, got " + std::to_string(scale));
  }
}

Sim3::Sim3(const Mat4& T) : t_(T.block<3, 1>(0, 3)) {
  const Mat3 sR = T.block<3, 3>(0, 0);
  const double det = sR.determinant();
  if (!sR.allFinite() || !t_.allFinite() || !(det > 0.0)) {
    throw std::invalid_argument("Sim3: the 3x3 block is not a positive-scale similarity (det = " +
                                std::to_string(det) + ")");
  }
  scale_ = std::cbrt(det);
  R_ = SO3(Mat3(sR / scale_));
}

Sim3 Sim3::exp(const Vec7& x) {
  const Vec3 v = x.head<3>();
  const Vec3 w = x.segment<3>(3);
  const double sigma = x[6];
  return Sim3(SO3::exp(w), simW(sigma, w) * v, std::exp(sigma));
}

Vec7 Sim3::log() const {
  const Vec3 w = R_.log();
  const double sigma = std::log(scale_);
  // W is invertible for |w| <= pi (its eigenvalues vanish only at sigma = 0, |w| = 2 pi k).
  Vec7 x;
  x << simW(sigma, w).partialPivLu().solve(t_), w, sigma;
  return x;
}

Sim3 Sim3::inverse() const {
  const SO3 R_inv = R_.inverse();
  const double s_inv = 1.0 / scale_;
  return Sim3(R_inv, -s_inv * (R_inv * t_), s_inv);
}

Sim3 Sim3::operator*(const Sim3& other) const {
  return Sim3(R_ * other.R_, scale_ * (R_ * other.t_) + t_, scale_ * other.scale_);
}

Vec3 Sim3::transform(const Vec3& p, Mat37* H_pose, Mat3* H_point) const {
  const Mat3 sR = scale_ * R_.matrix();
  // T Exp(v, w, sigma) p ~= s R ((1 + sigma) (p + w x p) + v) + t to first order.
  if (H_pose) *H_pose << sR, -sR * hat(p), sR * p;
  if (H_point) *H_point = sR;
  return sR * p + t_;
}

SE3 Sim3::transformPose(const SE3& T_b_c) const {
  return SE3(R_ * T_b_c.so3(), *this * T_b_c.translation());
}

Mat7 Sim3::adjoint() const {
  const Mat3 R = R_.matrix();
  Mat7 ad = Mat7::Zero();
  ad.block<3, 3>(0, 0) = scale_ * R;
  ad.block<3, 3>(0, 3) = hat(t_) * R;
  ad.block<3, 1>(0, 6) = -t_;
  ad.block<3, 3>(3, 3) = R;
  ad(6, 6) = 1.0;
  return ad;
}

Mat4 Sim3::matrix() const {
  Mat4 T = Mat4::Identity();
  T.block<3, 3>(0, 0) = scale_ * R_.matrix();
  T.block<3, 1>(0, 3) = t_;
  return T;
}

}  // namespace radslam
