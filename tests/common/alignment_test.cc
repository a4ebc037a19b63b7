// Umeyama and rotation-only alignment: exact recovery, optimality under noise,
// degenerate input.
#include "common/alignment.h"

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

namespace radslam {
namespace {

std::vector<Vec3> randomPoints(size_t n, std::mt19937& gen, double extent = 5.0) {
  std::uniform_real_distribution<double> u(-extent, extent);
  std::vector<Vec3> points(n);
  for (Vec3& p : points) p = Vec3(u(gen), u(gen), u(gen));
  return points;
}

std::vector<Vec3> transformed(const Sim3& S, const std::vector<Vec3>& points) {
  std::vector<Vec3> out;
  for (const Vec3& p : points) out.push_back(S * p);
  return out;
}

double sumSquaredResiduals(const Sim3& S, const std::vector<Vec3>& src,
                           const std::vector<Vec3>& dst) {
  double sum = 0;
  for (size_t i = 0; i < src.size(); ++i) sum += (dst[i] - S * src[i]).squaredNorm();
  return sum;
}

double sumSquaredAngles(const SO3& R, const std::vector<SO3>& src, const std::vector<SO3>& dst) {
  double sum = 0;
  for (size_t i = 0; i < src.size(); ++i)
    sum += (dst[i].inverse() * R * src[i]).log().squaredNorm();
  return sum;
}

TEST(AlignUmeyama, RecoversSim3Exactly) {
  std::mt19937 gen(1);
  const Sim3 S_dst_src(SO3::exp(Vec3(0.4, -1.2, 2.1)), Vec3(3.0, -1.0, 7.5), 0.37);
  const std::vector<Vec3> src = randomPoints(50, gen);
  const Sim3 S = alignUmeyama(src, transformed(S_dst_src, src), true);
  EXPECT_NEAR(S.scale(), 0.37, 1e-12);
  EXPECT_TRUE(S.matrix().isApprox(S_dst_src.matrix(), 1e-10)) << S.matrix();
}

TEST(AlignUmeyama, RecoversSE3ExactlyWithScaleOne) {
  std::mt19937 gen(2);
  const Sim3 T_dst_src(SO3::exp(Vec3(-2.5, 0.3, 0.2)), Vec3(-4.0, 2.0, 0.1), 1.0);
  const std::vector<Vec3> src = randomPoints(20, gen);
  const Sim3 T = alignUmeyama(src, transformed(T_dst_src, src), false);
  EXPECT_EQ(T.scale(), 1.0);
  EXPECT_TRUE(T.matrix().isApprox(T_dst_src.matrix(), 1e-10));
}

TEST(AlignUmeyama, RigidAlignmentIgnoresScaleDifference) {
  std::mt19937 gen(3);
  const Sim3 S_dst_src(SO3::exp(Vec3(0.1, 0.2, 0.3)), Vec3(1, 2, 3), 2.0);
  const std::vector<Vec3> src = randomPoints(30, gen);
  const std::vector<Vec3> dst = transformed(S_dst_src, src);
  const Sim3 T = alignUmeyama(src, dst, false);
  EXPECT_EQ(T.scale(), 1.0);
  // Rotation is still the true one (the scale does not bias it); the residual is not zero.
  EXPECT_TRUE(T.rotation().isApprox(S_dst_src.rotation(), 1e-10));
  EXPECT_GT(sumSquaredResiduals(T, src, dst), 1.0);
}

TEST(AlignUmeyama, MinimalAndPlanarConfigurations) {
  std::mt19937 gen(4);
  const Sim3 S_dst_src(SO3::exp(Vec3(1.0, -0.5, 2.8)), Vec3(0.5, 0.5, -2.0), 1.7);
  // Three points: the minimal case.
  const std::vector<Vec3> three = randomPoints(3, gen);
  EXPECT_TRUE(alignUmeyama(three, transformed(S_dst_src, three), true)
                  .matrix()
                  .isApprox(S_dst_src.matrix(), 1e-9));
  // Coplanar points: the SVD has a zero singular value and a naive solution
  // may return a reflection.
  std::vector<Vec3> planar = randomPoints(12, gen);
  for (Vec3& p : planar) p.z() = 0.0;
  EXPECT_TRUE(alignUmeyama(planar, transformed(S_dst_src, planar), true)
                  .matrix()
                  .isApprox(S_dst_src.matrix(), 1e-9));
}

TEST(AlignUmeyama, CollinearPointsStillFitExactly) {
  const Sim3 S_dst_src(SO3::exp(Vec3(0.3, 0.3, -0.3)), Vec3(1, 0, 0), 1.0);
  std::vector<Vec3> line;
  for (int i = 0; i < 10; ++i) line.push_back(Vec3(0.5 * i, 0.1 * i, -0.2 * i));
  const Sim3 T = alignUmeyama(line, transformed(S_dst_src, line), false);
  EXPECT_LT(sumSquaredResiduals(T, line, transformed(S_dst_src, line)), 1e-18);
}

TEST(AlignUmeyama, IsTheLeastSquaresMinimumUnderNoise) {
  std::mt19937 gen(5);
  std::normal_distribution<double> noise(0.0, 0.05);
  const Sim3 S_dst_src(SO3::exp(Vec3(0.7, 0.1, -0.4)), Vec3(-1, 2, 0.5), 0.8);
  const std::vector<Vec3> src = randomPoints(100, gen);
  std::vector<Vec3> dst = transformed(S_dst_src, src);
  for (Vec3& p : dst) p += Vec3(noise(gen), noise(gen), noise(gen));
  for (bool with_scale : {true, false}) {
    const Sim3 S = alignUmeyama(src, dst, with_scale);
    const double cost = sumSquaredResiduals(S, src, dst);
    // Every small perturbation in the allowed directions raises the cost.
    for (int k = 0; k < (with_scale ? 7 : 6); ++k) {
      for (double h : {-1e-4, 1e-4}) {
        Vec7 d = Vec7::Zero();
        d[k] = h;
        EXPECT_GT(sumSquaredResiduals(S * Sim3::exp(d), src, dst), cost) << k;
      }
    }
  }
}

TEST(AlignUmeyama, RejectsBadInput) {
  std::mt19937 gen(6);
  const std::vector<Vec3> five = randomPoints(5, gen);
  const std::vector<Vec3> four = randomPoints(4, gen);
  EXPECT_THROW(alignUmeyama(five, four, true), std::invalid_argument);
  const std::vector<Vec3> two = randomPoints(2, gen);
  EXPECT_THROW(alignUmeyama(two, two, false), std::invalid_argument);
  EXPECT_THROW(alignUmeyama({}, {}, false), std::invalid_argument);
  std::vector<Vec3> with_nan = five;
  with_nan[3].y() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(alignUmeyama(with_nan, five, false), std::invalid_argument);
  const std::vector<Vec3> same(5, Vec3(1, 2, 3));
  EXPECT_THROW(alignUmeyama(same, five, true), std::invalid_argument);
  EXPECT_THROW(alignUmeyama(five, same, true), std::invalid_argument);
  // Without scale a collapsed set is a pure translation: well defined.
  const Sim3 T = alignUmeyama(same, same, false);
  EXPECT_TRUE((T * Vec3(1, 2, 3)).isApprox(Vec3(1, 2, 3), 1e-12));
  try {
    alignUmeyama(five, four, true);
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("5 source points but 4"), std::string::npos) << e.what();
  }
}

std::vector<SO3> randomRotations(size_t n, std::mt19937& gen, double max_angle) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<SO3> out;
  for (size_t i = 0; i < n; ++i) {
    out.push_back(SO3::exp(max_angle * Vec3(u(gen), u(gen), u(gen)) / std::sqrt(3.0)));
  }
  return out;
}

TEST(AlignRotationOnly, RecoversKnownRotationExactly) {
  std::mt19937 gen(7);
  const SO3 R_dst_src = SO3::exp(Vec3(2.0, -1.0, 0.5));
  const std::vector<SO3> src = randomRotations(40, gen, 3.0);
  std::vector<SO3> dst;
  for (const SO3& R : src) dst.push_back(R_dst_src * R);
  EXPECT_TRUE(alignRotationOnly(src, dst).matrix().isApprox(R_dst_src.matrix(), 1e-10));
  // A single rotation pins the answer down.
  EXPECT_TRUE(alignRotationOnly({src[0]}, {dst[0]}).matrix().isApprox(R_dst_src.matrix(), 1e-12));
}

TEST(AlignRotationOnly, MinimisesGeodesicErrorUnderNoise) {
  std::mt19937 gen(8);
  std::normal_distribution<double> noise(0.0, 0.15);  // rad, large enough to separate
                                                      // chordal and geodesic optima
  const SO3 R_dst_src = SO3::exp(Vec3(-0.3, 1.4, 0.2));
  const std::vector<SO3> src = randomRotations(60, gen, 2.5);
  std::vector<SO3> dst;
  for (const SO3& R : src) {
    dst.push_back(R_dst_src * R * SO3::exp(Vec3(noise(gen), noise(gen), 3 * noise(gen))));
  }
  const SO3 R = alignRotationOnly(src, dst);
  const double cost = sumSquaredAngles(R, src, dst);
  for (int k = 0; k < 3; ++k) {
    for (double h : {-1e-4, 1e-4}) {
      Vec3 d = Vec3::Zero();
      d[k] = h;
      EXPECT_GT(sumSquaredAngles(SO3::exp(d) * R, src, dst), cost) << k;
    }
  }
  // The chordal solution alone is not the geodesic optimum here.
  Mat3 M = Mat3::Zero();
  for (size_t i = 0; i < src.size(); ++i) M += dst[i].matrix() * src[i].matrix().transpose();
  EXPECT_LT(cost, sumSquaredAngles(SO3(M), src, dst));
  EXPECT_LT((R.inverse() * R_dst_src).log().norm(), 0.1);
}

TEST(AlignRotationOnly, RejectsBadInput) {
  EXPECT_THROW(alignRotationOnly({}, {}), std::invalid_argument);
  EXPECT_THROW(alignRotationOnly({SO3(), SO3()}, {SO3()}), std::invalid_argument);
}

}  // namespace
}  // namespace radslam
