#include "tracker/joints.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

#include <Eigen/Dense>

namespace radslam {

int jointDof(JointType type) {
  switch (type) {
    case JointType::kPlanar:
      return 3;
    case JointType::kRevolute:
      return 1;
    case JointType::kFree:
      return 6;
  }
  throw std::invalid_argument("jointDof: unknown joint type " +
                              std::to_string(static_cast<int>(type)));
}

JointBasis jointBasis(JointType type) {
  const int k = jointDof(type);
  JointBasis A = JointBasis::Zero(6, k);
  switch (type) {
    case JointType::kPlanar:  // vx, vy, wz
      A(0, 0) = 1;
      A(1, 1) = 1;
      A(5, 2) = 1;
      break;
    case JointType::kRevolute:  // wz
      A(5, 0) = 1;
      break;
    case JointType::kFree:
      A.setIdentity();
      break;
  }
  return A;
}

Mat6 twistProjector(const JointBasis& A) {
  if (A.cols() == 0) throw std::invalid_argument("twistProjector: empty basis");
  const JointMatrix AtA = A.transpose() * A;
  Eigen::LDLT<JointMatrix> ldlt(AtA);
  const double min_pivot = ldlt.vectorD().cwiseAbs().minCoeff();
  if (ldlt.info() != Eigen::Success || !(min_pivot > 1e-12 * AtA.trace()))
    throw std::invalid_argument("twistProjector: basis is rank deficient");
  return A * ldlt.solve(A.transpose());
}

Vec6 transportTwist(const SE3& T_b_a, const Vec6& xi_a) { return T_b_a.adjoint() * xi_a; }

Joint::Joint(JointType type, const SE3& T_world_joint)
    : type_(type), T_world_joint_(T_world_joint), A_(jointBasis(type)), Pi_(twistProjector(A_)) {}

SE3 Joint::motionJoint(const JointVector& theta) const {
  if (theta.size() != dof())
    throw std::invalid_argument("Joint: " + std::to_string(theta.size()) +
                                " coordinates given for a " + jointTypeName(type_) + " joint of " +
                                std::to_string(dof()) + " DOF");
  return SE3::exp(A_ * theta);
}

SE3 Joint::motionWorld(const JointVector& theta) const {
  return T_world_joint_ * motionJoint(theta) * T_world_joint_.inverse();
}

JointVector Joint::coordinates(const SE3& M_world) const {
  const SE3 M_joint = T_world_joint_.inverse() * M_world * T_world_joint_;
  return A_.transpose() * M_joint.log();
}

Vec6 Joint::twist(const JointVector& theta, double dt) const {
  if (!(dt > 0)) throw std::invalid_argument("Joint::twist: dt must be > 0 s");
  if (theta.size() != dof()) throw std::invalid_argument("Joint::twist: wrong coordinate count");
  return A_ * theta / dt;
}

Plane fitPlaneSvd(const std::vector<Vec3>& points) {
  if (points.size() < 3)
    throw std::invalid_argument("fitPlaneSvd: need at least 3 points, got " +
                                std::to_string(points.size()));
  Vec3 mean = Vec3::Zero();
  for (const Vec3& p : points) {
    if (!p.allFinite()) throw std::invalid_argument("fitPlaneSvd: non-finite point");
    mean += p;
  }
  mean /= static_cast<double>(points.size());
  Mat3 scatter = Mat3::Zero();
  for (const Vec3& p : points) scatter += (p - mean) * (p - mean).transpose();
  // Eigenvalues ascending: the smallest one's vector is the normal.
  Eigen::SelfAdjointEigenSolver<Mat3> eig(scatter);
  const Vec3 ev = eig.eigenvalues();
  if (!(ev(1) > 1e-12 * std::max(ev(2), 1e-300)))
    throw std::invalid_argument("fitPlaneSvd: points are collinear or coincident");
  Plane plane;
  plane.normal = eig.eigenvectors().col(0).normalized();
  plane.d = -plane.normal.dot(mean);
  return plane;
}

namespace {

std::vector<int> planeInliers(const std::vector<Vec3>& points, const Plane& plane,
                              double threshold) {
  std::vector<int> inliers;
  for (size_t i = 0; i < points.size(); ++i)
    if (std::abs(plane.distance(points[i])) < threshold) inliers.push_back(static_cast<int>(i));
  return inliers;
}

std::vector<Vec3> select(const std::vector<Vec3>& points, const std::vector<int>& idx) {
  std::vector<Vec3> out;
  out.reserve(idx.size());
  for (int i : idx) out.push_back(points[i]);
  return out;
}

}  // namespace

PlaneFit fitPlaneRansac(const std::vector<Vec3>& points, const PlaneRansacParams& params) {
  const size_t needed = static_cast<size_t>(std::max(3, params.min_inliers));
  if (points.size() < needed)
    throw std::invalid_argument("fitPlaneRansac: " + std::to_string(points.size()) +
                                " points, need at least " + std::to_string(needed));
  if (!(params.inlier_threshold > 0))
    throw std::invalid_argument("fitPlaneRansac: inlier_threshold must be > 0 m");
  for (const Vec3& p : points)
    if (!p.allFinite()) throw std::invalid_argument("fitPlaneRansac: non-finite point");
  std::mt19937_64 rng(params.seed);
  std::uniform_int_distribution<size_t> pick(0, points.size() - 1);
  std::vector<int> best;
  for (int it = 0; it < params.iterations; ++it) {
    const Vec3& a = points[pick(rng)];
    const Vec3& b = points[pick(rng)];
    const Vec3& c = points[pick(rng)];
    const Vec3 n = (b - a).cross(c - a);
    if (!(n.norm() > 1e-12)) continue;  // degenerate sample
    Plane plane;
    plane.normal = n.normalized();
    plane.d = -plane.normal.dot(a);
    std::vector<int> inliers = planeInliers(points, plane, params.inlier_threshold);
    if (inliers.size() > best.size()) best.swap(inliers);
  }
  if (best.size() < needed)
    throw std::invalid_argument("fitPlaneRansac: no plane with " + std::to_string(needed) +
                                " inliers (best " + std::to_string(best.size()) + ")");
  PlaneFit fit;
  // Refit on the consensus set, then once more on the refit plane's inliers.
  for (int pass = 0; pass < 2; ++pass) {
    fit.plane = fitPlaneSvd(select(points, best));
    std::vector<int> inliers = planeInliers(points, fit.plane, params.inlier_threshold);
    if (inliers.size() < needed) break;
    best.swap(inliers);
  }
  fit.plane = fitPlaneSvd(select(points, best));
  fit.inliers = best;
  double sq = 0;
  for (int i : best) sq += std::pow(fit.plane.distance(points[i]), 2);
  fit.rms = std::sqrt(sq / static_cast<double>(best.size()));
  return fit;
}

namespace {

// A rotation whose z column is `z` (unit), x as close as possible to the world x axis.
Mat3 frameWithZ(const Vec3& z) {
  Vec3 ref = Vec3::UnitX();
  if (std::abs(z.dot(ref)) > 0.9) ref = Vec3::UnitY();
  const Vec3 x = (ref - z.dot(ref) * z).normalized();
  Mat3 R;
  R.col(0) = x;
  R.col(1) = z.cross(x);
  R.col(2) = z;
  return R;
}

}  // namespace

SE3 planeJointFrame(const Plane& plane, const Vec3& near_point, const Vec3& up_hint) {
  if (!plane.normal.allFinite() || !(plane.normal.norm() > 0.5) || !std::isfinite(plane.d))
    throw std::invalid_argument("planeJointFrame: invalid plane");
  const double scale = plane.normal.norm();
  const Vec3 n0 = plane.normal / scale;
  const Vec3 origin = near_point - (n0.dot(near_point) + plane.d / scale) * n0;
  const Vec3 n = n0.dot(up_hint) < 0 ? Vec3(-n0) : n0;
  return SE3(SO3(frameWithZ(n)), origin);
}

Hinge hingeFromMotions(const std::vector<SE3>& motions_world, double min_angle) {
  Mat3 scatter = Mat3::Zero();
  std::vector<Vec6> logs;
  for (const SE3& M : motions_world) {
    const Vec6 xi = M.log();
    if (!xi.allFinite()) throw std::invalid_argument("hingeFromMotions: non-finite motion");
    const double angle = xi.tail<3>().norm();
    if (angle < min_angle) continue;
    logs.push_back(xi);
    const Vec3 a = xi.tail<3>() / angle;
    scatter += angle * a * a.transpose();
  }
  if (logs.empty())
    throw std::invalid_argument("hingeFromMotions: no motion rotates more than " +
                                std::to_string(min_angle) + " rad");
  Eigen::SelfAdjointEigenSolver<Mat3> eig(scatter);
  Vec3 axis = eig.eigenvectors().col(2).normalized();
  double sign = 0;
  for (const Vec6& xi : logs) sign += axis.dot(xi.tail<3>());
  if (sign < 0) axis = -axis;
  // Screw line of xi = (v, w): points q + s w with q = w x v / |w|^2. The least-squares point
  // minimises the angle-weighted squared distances to all lines; the axis term picks the
  // solution nearest the origin along the (otherwise free) axis direction.
  Mat3 H = 1e-9 * axis * axis.transpose();
  Vec3 b = Vec3::Zero();
  for (const Vec6& xi : logs) {
    const Vec3 w = xi.tail<3>();
    const double angle = w.norm();
    const Vec3 a = w / angle;
    const Vec3 q = w.cross(xi.head<3>()) / (angle * angle);
    const Mat3 P = Mat3::Identity() - a * a.transpose();
    H += angle * P;
    b += angle * P * q;
  }
  Hinge hinge;
  hinge.axis = axis;
  hinge.point = H.ldlt().solve(b);
  hinge.point -= axis.dot(hinge.point) * axis;
  return hinge;
}

Hinge hingeFromPlanes(const Plane& a, const Plane& b, const Vec3& near_point, double min_angle) {
  const Vec3 cross = a.normal.normalized().cross(b.normal.normalized());
  // A fitted normal's sign is arbitrary: the angle between the planes is taken up to 90 deg.
  if (!cross.allFinite() || !near_point.allFinite() ||
      !(std::asin(std::min(1.0, cross.norm())) >= min_angle))
    throw std::invalid_argument("hingeFromPlanes: the planes turn less than " +
                                std::to_string(min_angle) + " rad");
  // The point of both planes nearest to near_point: p = q - N^T (N N^T)^-1 (N q + d).
  Eigen::Matrix<double, 2, 3> N;
  N << a.normal.transpose(), b.normal.transpose();
  const Eigen::Vector2d residual = N * near_point + Eigen::Vector2d(a.d, b.d);
  Hinge hinge;
  hinge.axis = cross.normalized();
  hinge.point = near_point - N.transpose() * (N * N.transpose()).ldlt().solve(residual);
  return hinge;
}

SE3 hingeJointFrame(const Hinge& hinge) {
  if (!hinge.axis.allFinite() || !(hinge.axis.norm() > 1e-9) || !hinge.point.allFinite())
    throw std::invalid_argument("hingeJointFrame: invalid hinge");
  return SE3(SO3(frameWithZ(hinge.axis.normalized())), hinge.point);
}

}  // namespace radslam
