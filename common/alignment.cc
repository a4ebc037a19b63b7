#include "common/alignment.h"

#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Geometry>

namespace radslam {
namespace {

Eigen::Matrix3Xd toMatrix(const std::vector<Vec3>& points, const char* name) {
  Eigen::Matrix3Xd m(3, points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    if (!points[i].allFinite()) {
      throw std::invalid_argument(std::string("alignUmeyama: ") + name + " point " +
                                  std::to_string(i) + " is not finite");
    }
    m.col(static_cast<Eigen::Index>(i)) = points[i];
  }
  return m;
}

// RMS distance of the points to their centroid (m).
double spread(const Eigen::Matrix3Xd& m) {
  const Vec3 mean = m.rowwise().mean();
  return std::sqrt((m.colwise() - mean).squaredNorm() / static_cast<double>(m.cols()));
}

bool collapsed(const Eigen::Matrix3Xd& m) {
  const double magnitude = m.rowwise().mean().norm();
  return spread(m) <= 1e-12 * std::max(1.0, magnitude);
}

}  // namespace

Sim3 alignUmeyama(const std::vector<Vec3>& src, const std::vector<Vec3>& dst, bool with_scale) {
  if (src.size() != dst.size()) {
    throw std::invalid_argument("alignUmeyama: " + std::to_string(src.size()) +
                                " source points but " + std::to_string(dst.size()) +
                                " destination points");
  }
  if (src.size() < 3) {
    throw std::invalid_argument("alignUmeyama: need at least 3 point pairs, got " +
                                std::to_string(src.size()));
  }
  const Eigen::Matrix3Xd s = toMatrix(src, "source");
  const Eigen::Matrix3Xd d = toMatrix(dst, "destination");
  if (with_scale && collapsed(s)) {
    throw std::invalid_argument("alignUmeyama: all source points coincide, the scale is undefined");
  }
  if (with_scale && collapsed(d)) {
    throw std::invalid_argument(
        "alignUmeyama: all destination points coincide, the scale would be 0");
  }
  // Eigen's implementation handles the reflection case (det(U V^T) < 0).
  const Mat4 T = Eigen::umeyama(s, d, with_scale);
  if (!with_scale) return Sim3(SO3(Mat3(T.block<3, 3>(0, 0))), T.block<3, 1>(0, 3), 1.0);
  return Sim3(T);
}

SO3 alignRotationOnly(const std::vector<SO3>& src, const std::vector<SO3>& dst) {
  if (src.size() != dst.size()) {
    throw std::invalid_argument("alignRotationOnly: " + std::to_string(src.size()) +
                                " source rotations but " + std::to_string(dst.size()) +
                                " destination rotations");
  }
  if (src.empty()) throw std::invalid_argument("alignRotationOnly: no rotations given");

  // Chordal L2 mean: maximise tr(R^T sum R_dst_i R_src_i^T); SO3(Mat3) projects.
  Mat3 M = Mat3::Zero();
  for (size_t i = 0; i < src.size(); ++i) M += dst[i].matrix() * src[i].matrix().transpose();
  SO3 R(M);

  // Gauss-Newton on r_i(R) = log(R_dst_i^-1 R R_src_i) with R <- Exp(d) R:
  // dr_i/dd = J_r^-1(r_i) (R R_src_i)^T. A step is kept only if it lowers the
  // cost, so the result is never worse than the chordal start.
  const auto evaluate = [&](const SO3& R_try, Mat3* H, Vec3* g) {
    H->setZero();
    g->setZero();
    double cost = 0.0;
    for (size_t i = 0; i < src.size(); ++i) {
      const SO3 R_cam = R_try * src[i];
      const Vec3 r = (dst[i].inverse() * R_cam).log();
      const Mat3 J = SO3::rightJacobianInverse(r) * R_cam.matrix().transpose();
      *H += J.transpose() * J;
      *g += J.transpose() * r;
      cost += r.squaredNorm();
    }
    return cost;
  };
  constexpr int kMaxIterations = 20;
  Mat3 H;
  Vec3 g;
  double cost = evaluate(R, &H, &g);
  for (int iter = 0; iter < kMaxIterations; ++iter) {
    const Vec3 step = -H.ldlt().solve(g);
    if (!step.allFinite()) break;
    const SO3 candidate = SO3::exp(step) * R;
    Mat3 H_next;
    Vec3 g_next;
    const double next_cost = evaluate(candidate, &H_next, &g_next);
    if (!(next_cost < cost)) break;  // converged to double precision
    R = candidate;
    cost = next_cost;
    H = H_next;
    g = g_next;
    if (step.norm() < 1e-12) break;
  }
  return R;
}

}  // namespace radslam
