// SO(3), SE(3), Sim(3): exp/log, group identities, adjoints and every
// Jacobian against central finite differences.
#include "common/lie.h"

#include <cmath>
#include <random>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>
#include <unsupported/Eigen/MatrixFunctions>

namespace radslam {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kFdStep = 1e-6;
constexpr double kFdTol = 1e-7;

std::mt19937& rng() {
  static std::mt19937 gen(42);
  return gen;
}

template <int N>
Eigen::Matrix<double, N, 1> randomVec(double scale = 1.0) {
  std::uniform_real_distribution<double> u(-scale, scale);
  Eigen::Matrix<double, N, 1> x;
  for (int i = 0; i < N; ++i) x[i] = u(rng());
  return x;
}

Vec3 randomAxis() { return randomVec<3>().normalized(); }

// Rotation vectors exercising every branch: zero, tiny, around the Taylor
// thresholds, generic, and close to pi.
std::vector<Vec3> testRotationVectors() {
  std::vector<Vec3> ws = {Vec3::Zero()};
  for (double angle :
       {1e-12, 1e-8, 9e-6, 1.1e-5, 5e-3, 1.1e-2, 0.3, 1.0, 2.0, 3.0, kPi - 1e-3, kPi - 1e-6}) {
    ws.push_back(angle * randomAxis());
  }
  return ws;
}

Vec6 makeXi(const Vec3& v, const Vec3& w) {
  Vec6 xi;
  xi << v, w;
  return xi;
}

Vec7 makeX(const Vec3& v, const Vec3& w, double sigma) {
  Vec7 x;
  x << v, w, sigma;
  return x;
}

// Generator of Sim(3) (SE(3) when sigma = 0) as a 4x4 matrix, for the
// reference exponential Eigen computes by Pade approximation.
Mat4 generator(const Vec3& v, const Vec3& w, double sigma) {
  Mat4 X = Mat4::Zero();
  X.block<3, 3>(0, 0) = hat(w) + sigma * Mat3::Identity();
  X.block<3, 1>(0, 3) = v;
  return X;
}

// Numerical Jacobian of f: R^N -> R^M (central differences).
template <int M, int N, typename F>
Eigen::Matrix<double, M, N> numericalJacobian(F f, double h = kFdStep) {
  Eigen::Matrix<double, M, N> J;
  for (int i = 0; i < N; ++i) {
    Eigen::Matrix<double, N, 1> d = Eigen::Matrix<double, N, 1>::Zero();
    d[i] = h;
    J.col(i) = (f(d) - f(-d)) / (2 * h);
  }
  return J;
}

TEST(SO3, ExpMatchesMatrixExponential) {
  for (const Vec3& w : testRotationVectors()) {
    const Mat3 expected = Mat3(hat(w)).exp();
    EXPECT_TRUE(SO3::exp(w).matrix().isApprox(expected, 1e-12)) << w.transpose();
  }
}

TEST(SO3, ExpLogRoundTrip) {
  for (const Vec3& w : testRotationVectors()) {
    const Vec3 back = SO3::exp(w).log();
    EXPECT_LT((back - w).norm(), 1e-9 * std::max(1.0, 1.0 / (kPi - w.norm())) + 1e-15)
        << w.transpose();
    const SO3 R = SO3::exp(w);
    EXPECT_TRUE(SO3::exp(R.log()).matrix().isApprox(R.matrix(), 1e-12));
  }
}

TEST(SO3, LogAtPiGivesAngleInRange) {
  const Vec3 axis = randomAxis();
  const SO3 R = SO3::exp(kPi * axis);
  const Vec3 w = R.log();
  EXPECT_NEAR(w.norm(), kPi, 1e-9);
  EXPECT_NEAR(std::abs(w.normalized().dot(axis)), 1.0, 1e-9);
  // A rotation by more than pi comes back as the equivalent one below pi.
  const Vec3 w_big = (kPi + 0.5) * axis;
  EXPECT_NEAR(SO3::exp(w_big).log().norm(), kPi - 0.5, 1e-12);
}

TEST(SO3, MatrixConstructorProjects) {
  const SO3 R = SO3::exp(Vec3(0.3, -0.2, 0.9));
  Mat3 noisy = R.matrix();
  noisy(0, 1) += 1e-3;
  EXPECT_LT((SO3(noisy).matrix() - R.matrix()).norm(), 2e-3);
  EXPECT_NEAR(SO3(noisy).matrix().determinant(), 1.0, 1e-12);
}

TEST(SO3, InverseAndComposition) {
  const SO3 A = SO3::exp(randomVec<3>(2.0));
  const SO3 B = SO3::exp(randomVec<3>(2.0));
  EXPECT_TRUE((A * A.inverse()).matrix().isApprox(Mat3::Identity(), 1e-12));
  EXPECT_TRUE((A * B).matrix().isApprox(A.matrix() * B.matrix(), 1e-12));
  const Vec3 p = randomVec<3>();
  EXPECT_TRUE(((A * B) * p).isApprox(A * (B * p), 1e-12));
}

TEST(SO3, AdjointIdentity) {
  const SO3 R = SO3::exp(randomVec<3>(2.0));
  const Vec3 w = randomVec<3>(0.5);
  const Mat3 lhs = (R * SO3::exp(w) * R.inverse()).matrix();
  EXPECT_TRUE(lhs.isApprox(SO3::exp(R.adjoint() * w).matrix(), 1e-12));
}

TEST(SO3, JacobiansMatchFiniteDifferences) {
  for (const Vec3& w : testRotationVectors()) {
    if (w.norm() > kPi - 1e-2) continue;  // log jumps at pi: no finite differences there
    const SO3 R = SO3::exp(w);
    // Exp(w + d) = Exp(J_l d) Exp(w).
    const Mat3 Jl_num = numericalJacobian<3, 3>(
        [&](const Vec3& d) { return (SO3::exp(w + d) * R.inverse()).log(); });
    EXPECT_LT((SO3::leftJacobian(w) - Jl_num).norm(), kFdTol) << w.transpose();
    // Exp(w + d) = Exp(w) Exp(J_r d).
    const Mat3 Jr_num = numericalJacobian<3, 3>(
        [&](const Vec3& d) { return (R.inverse() * SO3::exp(w + d)).log(); });
    EXPECT_LT((SO3::rightJacobian(w) - Jr_num).norm(), kFdTol) << w.transpose();
    // Inverses as derivatives of log: log(Exp(d) R) = w + J_l^-1 d, log(R Exp(d)) = w + J_r^-1 d.
    const Mat3 Jl_inv_num =
        numericalJacobian<3, 3>([&](const Vec3& d) { return (SO3::exp(d) * R).log(); });
    EXPECT_LT((SO3::leftJacobianInverse(w) - Jl_inv_num).norm(), kFdTol) << w.transpose();
    const Mat3 Jr_inv_num =
        numericalJacobian<3, 3>([&](const Vec3& d) { return (R * SO3::exp(d)).log(); });
    EXPECT_LT((SO3::rightJacobianInverse(w) - Jr_inv_num).norm(), kFdTol) << w.transpose();
  }
}

TEST(SO3, JacobianInversesNearPi) {
  for (double angle : {kPi - 1e-2, kPi - 1e-6, kPi}) {
    const Vec3 w = angle * randomAxis();
    EXPECT_TRUE(
        (SO3::leftJacobian(w) * SO3::leftJacobianInverse(w)).isApprox(Mat3::Identity(), 1e-10));
    EXPECT_TRUE(
        (SO3::rightJacobian(w) * SO3::rightJacobianInverse(w)).isApprox(Mat3::Identity(), 1e-10));
  }
}

TEST(SE3, ExpMatchesMatrixExponential) {
  for (const Vec3& w : testRotationVectors()) {
    const Vec3 v = randomVec<3>(2.0);
    const Mat4 expected = generator(v, w, 0.0).exp();
    EXPECT_TRUE(SE3::exp(makeXi(v, w)).matrix().isApprox(expected, 1e-12)) << w.transpose();
  }
}

TEST(SE3, ExpLogRoundTrip) {
  for (const Vec3& w : testRotationVectors()) {
    if (w.norm() > kPi - 1e-5) continue;  // v is ill-conditioned at the pi jump
    const Vec6 xi = makeXi(randomVec<3>(2.0), w);
    EXPECT_LT((SE3::exp(xi).log() - xi).norm(), 1e-9) << xi.transpose();
  }
  const SE3 T(SO3::exp(Vec3(0.1, kPi - 1e-9, 0.0).normalized() * kPi), Vec3(1, 2, 3));
  EXPECT_TRUE(SE3::exp(T.log()).matrix().isApprox(T.matrix(), 1e-9));
}

TEST(SE3, MatrixRoundTripInverseComposition) {
  const SE3 A = SE3::exp(randomVec<6>(1.5));
  const SE3 B = SE3::exp(randomVec<6>(1.5));
  EXPECT_TRUE(SE3(A.matrix()).matrix().isApprox(A.matrix(), 1e-12));
  EXPECT_TRUE((A * A.inverse()).matrix().isApprox(Mat4::Identity(), 1e-12));
  EXPECT_TRUE((A.inverse() * A).matrix().isApprox(Mat4::Identity(), 1e-12));
  EXPECT_TRUE((A * B).matrix().isApprox(A.matrix() * B.matrix(), 1e-12));
  EXPECT_TRUE((A * B).inverse().matrix().isApprox((B.inverse() * A.inverse()).matrix(), 1e-12));
  const Vec3 p = randomVec<3>();
  EXPECT_TRUE((A * p).isApprox((A.matrix() * p.homogeneous()).head<3>(), 1e-12));
}

TEST(SE3, AdjointIdentity) {
  for (int trial = 0; trial < 10; ++trial) {
    const SE3 T = SE3::exp(randomVec<6>(2.0));
    const Vec6 xi = randomVec<6>(0.7);
    const Mat4 lhs = (T * SE3::exp(xi) * T.inverse()).matrix();
    EXPECT_TRUE(lhs.isApprox(SE3::exp(T.adjoint() * xi).matrix(), 1e-12));
  }
}

TEST(SE3, JacobiansMatchFiniteDifferences) {
  for (const Vec3& w : testRotationVectors()) {
    if (w.norm() > kPi - 1e-2) continue;
    const Vec6 xi = makeXi(randomVec<3>(2.0), w);
    const SE3 T = SE3::exp(xi);
    const Mat6 Jl_num = numericalJacobian<6, 6>(
        [&](const Vec6& d) { return (SE3::exp(xi + d) * T.inverse()).log(); });
    EXPECT_LT((SE3::leftJacobian(xi) - Jl_num).norm(), kFdTol) << xi.transpose();
    const Mat6 Jr_num = numericalJacobian<6, 6>(
        [&](const Vec6& d) { return (T.inverse() * SE3::exp(xi + d)).log(); });
    EXPECT_LT((SE3::rightJacobian(xi) - Jr_num).norm(), kFdTol) << xi.transpose();
    const Mat6 Jl_inv_num =
        numericalJacobian<6, 6>([&](const Vec6& d) { return (SE3::exp(d) * T).log(); });
    EXPECT_LT((SE3::leftJacobianInverse(xi) - Jl_inv_num).norm(), kFdTol) << xi.transpose();
    const Mat6 Jr_inv_num =
        numericalJacobian<6, 6>([&](const Vec6& d) { return (T * SE3::exp(d)).log(); });
    EXPECT_LT((SE3::rightJacobianInverse(xi) - Jr_inv_num).norm(), kFdTol) << xi.transpose();
    EXPECT_TRUE(
        (SE3::leftJacobian(xi) * SE3::leftJacobianInverse(xi)).isApprox(Mat6::Identity(), 1e-10));
  }
}

TEST(SE3, TransformJacobiansMatchFiniteDifferences) {
  for (int trial = 0; trial < 10; ++trial) {
    const SE3 T = SE3::exp(randomVec<6>(2.0));
    const Vec3 p = randomVec<3>(3.0);
    Mat36 H_pose;
    Mat3 H_point;
    const Vec3 q = T.transform(p, &H_pose, &H_point);
    EXPECT_TRUE(q.isApprox(T * p, 1e-14));
    const Mat36 H_pose_num =
        numericalJacobian<3, 6>([&](const Vec6& d) { return (T * SE3::exp(d)) * p; });
    const Mat3 H_point_num = numericalJacobian<3, 3>([&](const Vec3& d) { return T * (p + d); });
    EXPECT_LT((H_pose - H_pose_num).norm(), kFdTol);
    EXPECT_LT((H_point - H_point_num).norm(), kFdTol);
  }
}

TEST(Sim3, ExpMatchesMatrixExponential) {
  for (const Vec3& w : testRotationVectors()) {
    for (double sigma : {0.0, 1e-12, 1e-7, -0.05, 0.099, 0.11, -0.7, 2.0}) {
      const Vec3 v = randomVec<3>(2.0);
      const Mat4 expected = generator(v, w, sigma).exp();
      const Sim3 S = Sim3::exp(makeX(v, w, sigma));
      EXPECT_TRUE(S.matrix().isApprox(expected, 1e-12))
          << "w " << w.transpose() << " sigma " << sigma << "\n"
          << S.matrix() << "\n"
          << expected;
      EXPECT_NEAR(S.scale(), std::exp(sigma), 1e-15 * std::exp(sigma));
    }
  }
}

TEST(Sim3, ExpLogRoundTrip) {
  for (const Vec3& w : testRotationVectors()) {
    if (w.norm() > kPi - 1e-5) continue;
    for (double sigma : {0.0, 1e-9, -1e-4, 0.05, -0.3, 1.5}) {
      const Vec7 x = makeX(randomVec<3>(2.0), w, sigma);
      EXPECT_LT((Sim3::exp(x).log() - x).norm(), 1e-9) << x.transpose();
    }
  }
  // Group element -> log -> exp for a rotation of exactly pi.
  const Sim3 S(SO3::exp(kPi * randomAxis()), Vec3(0.5, -1, 2), 0.25);
  EXPECT_TRUE(Sim3::exp(S.log()).matrix().isApprox(S.matrix(), 1e-12));
}

TEST(Sim3, ConstructionAndValidation) {
  const Sim3 S(SO3::exp(Vec3(0.2, 0.4, -1.0)), Vec3(1, 2, 3), 2.5);
  const Sim3 from_matrix(S.matrix());
  EXPECT_TRUE(from_matrix.matrix().isApprox(S.matrix(), 1e-12));
  EXPECT_NEAR(from_matrix.scale(), 2.5, 1e-12);
  const SE3 T = SE3::exp(randomVec<6>());
  EXPECT_TRUE(Sim3(T).matrix().isApprox(T.matrix(), 1e-14));
  EXPECT_THROW(Sim3(SO3(), Vec3::Zero(), 0.0), std::invalid_argument);
  EXPECT_THROW(Sim3(SO3(), Vec3::Zero(), -1.0), std::invalid_argument);
  EXPECT_THROW(Sim3(SO3(), Vec3::Zero(), std::nan("")), std::invalid_argument);
  Mat4 reflection = Mat4::Identity();
  reflection(2, 2) = -1;
  EXPECT_THROW(Sim3{reflection}, std::invalid_argument);
}

TEST(Sim3, InverseAndComposition) {
  for (int trial = 0; trial < 10; ++trial) {
    const Sim3 A = Sim3::exp(randomVec<7>(1.5));
    const Sim3 B = Sim3::exp(randomVec<7>(1.5));
    EXPECT_TRUE((A * A.inverse()).matrix().isApprox(Mat4::Identity(), 1e-12));
    EXPECT_TRUE((A.inverse() * A).matrix().isApprox(Mat4::Identity(), 1e-12));
    EXPECT_TRUE((A * B).matrix().isApprox(A.matrix() * B.matrix(), 1e-12));
    EXPECT_TRUE(A.inverse().matrix().isApprox(A.matrix().inverse(), 1e-12));
    const Vec3 p = randomVec<3>(2.0);
    EXPECT_TRUE(((A * B) * p).isApprox(A * (B * p), 1e-12));
    EXPECT_TRUE((A * p).isApprox((A.matrix() * p.homogeneous()).head<3>(), 1e-12));
  }
}

TEST(Sim3, TransformPoseKeepsCameraMetric) {
  const Sim3 S(SO3::exp(Vec3(0.1, -0.3, 0.2)), Vec3(1, -2, 0.5), 3.0);
  const SE3 T_b_c = SE3::exp(randomVec<6>());
  const SE3 T_a_c = S.transformPose(T_b_c);
  EXPECT_TRUE(T_a_c.translation().isApprox(S * T_b_c.translation(), 1e-12));
  EXPECT_TRUE(T_a_c.rotation().isApprox(S.rotation() * T_b_c.rotation(), 1e-12));
  // A point seen from the camera lands where the similarity maps its world position
  // only up to scale: the camera centre and its viewing directions are preserved.
  const Vec3 dir = randomVec<3>().normalized();
  const Vec3 in_b = T_b_c * dir - T_b_c.translation();
  const Vec3 in_a = T_a_c * dir - T_a_c.translation();
  EXPECT_TRUE(in_a.isApprox(S.rotation() * in_b, 1e-12));
}

TEST(Sim3, AdjointIdentity) {
  for (int trial = 0; trial < 10; ++trial) {
    const Sim3 T = Sim3::exp(randomVec<7>(1.5));
    const Vec7 x = randomVec<7>(0.6);
    const Mat4 lhs = (T * Sim3::exp(x) * T.inverse()).matrix();
    EXPECT_TRUE(lhs.isApprox(Sim3::exp(T.adjoint() * x).matrix(), 1e-12));
  }
}

TEST(Sim3, TransformJacobiansMatchFiniteDifferences) {
  for (int trial = 0; trial < 10; ++trial) {
    const Sim3 T = Sim3::exp(randomVec<7>(1.5));
    const Vec3 p = randomVec<3>(3.0);
    Mat37 H_pose;
    Mat3 H_point;
    const Vec3 q = T.transform(p, &H_pose, &H_point);
    EXPECT_TRUE(q.isApprox(T * p, 1e-14));
    const Mat37 H_pose_num =
        numericalJacobian<3, 7>([&](const Vec7& d) { return (T * Sim3::exp(d)) * p; });
    const Mat3 H_point_num = numericalJacobian<3, 3>([&](const Vec3& d) { return T * (p + d); });
    EXPECT_LT((H_pose - H_pose_num).norm(), kFdTol * std::max(1.0, T.scale()));
    EXPECT_LT((H_point - H_point_num).norm(), kFdTol * std::max(1.0, T.scale()));
  }
}

}  // namespace
}  // namespace radslam
