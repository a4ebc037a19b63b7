// Joints: twist bases and projectors, adjoint transport, joint motions and coordinates, plane
// fitting with RANSAC, hinge estimation from motion.
#include "tracker/joints.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>

#include "common/synthetic.h"

namespace radslam {
namespace {

const JointType kTypes[] = {JointType::kFree, JointType::kPlanar, JointType::kRevolute};

SE3 randomPose(std::mt19937_64* rng, double t_scale = 2.0) {
  std::normal_distribution<double> g(0, 1);
  Vec6 xi;
  for (int i = 0; i < 6; ++i) xi(i) = g(*rng) * (i < 3 ? t_scale : 1.0);
  return SE3::exp(xi);
}

Vec6 randomTwist(std::mt19937_64* rng) {
  std::normal_distribution<double> g(0, 1);
  Vec6 xi;
  for (int i = 0; i < 6; ++i) xi(i) = g(*rng);
  return xi;
}

TEST(Joints, DofAndBasisShape) {
  EXPECT_EQ(jointDof(JointType::kFree), 6);
  EXPECT_EQ(jointDof(JointType::kPlanar), 3);
  EXPECT_EQ(jointDof(JointType::kRevolute), 1);
  for (JointType t : kTypes) {
    const JointBasis A = jointBasis(t);
    EXPECT_EQ(A.rows(), 6);
    EXPECT_EQ(A.cols(), jointDof(t));
    EXPECT_TRUE((A.transpose() * A).isIdentity(1e-15)) << jointTypeName(t);
  }
  EXPECT_THROW(jointDof(static_cast<JointType>(7)), std::invalid_argument);
}

TEST(Joints, ProjectorIsIdempotentSymmetricAndKeepsTheBasis) {
  for (JointType t : kTypes) {
    const JointBasis A = jointBasis(t);
    const Mat6 Pi = twistProjector(A);
    EXPECT_LT((Pi * Pi - Pi).norm(), 1e-14) << jointTypeName(t);
    EXPECT_LT((Pi.transpose() - Pi).norm(), 1e-14) << jointTypeName(t);
    const Eigen::MatrixXd PiA = Pi * Eigen::MatrixXd(A);  // dynamic: avoids a GCC false warning
    EXPECT_LT((PiA - Eigen::MatrixXd(A)).norm(), 1e-14) << jointTypeName(t);
    EXPECT_NEAR(Pi.trace(), jointDof(t), 1e-12);
  }
  // A non-orthonormal basis spanning the same plane gives the same projector.
  JointBasis B = jointBasis(JointType::kPlanar);
  B.col(0) = 2.0 * B.col(0) + B.col(2);
  EXPECT_LT((twistProjector(B) - twistProjector(jointBasis(JointType::kPlanar))).norm(), 1e-12);
}

TEST(Joints, ProjectorRemovesMotionOutsideTheJoint) {
  const Mat6 Pi_planar = twistProjector(jointBasis(JointType::kPlanar));
  Vec6 xi;
  xi << 1.0, -2.0, 0.7, 0.3, -0.4, 0.9;  // vz, wx, wy leave the plane
  Vec6 expected;
  expected << 1.0, -2.0, 0, 0, 0, 0.9;
  EXPECT_LT((Pi_planar * xi - expected).norm(), 1e-15);
  const Mat6 Pi_rev = twistProjector(jointBasis(JointType::kRevolute));
  expected.setZero();
  expected(5) = 0.9;
  EXPECT_LT((Pi_rev * xi - expected).norm(), 1e-15);
  // The removed part is orthogonal to the kept one.
  EXPECT_NEAR((Pi_planar * xi).dot(xi - Pi_planar * xi), 0, 1e-14);
}

TEST(Joints, ProjectorRejectsBadBases) {
  EXPECT_THROW(twistProjector(JointBasis::Zero(6, 0)), std::invalid_argument);
  JointBasis B = jointBasis(JointType::kPlanar);
  B.col(1) = B.col(0);
  EXPECT_THROW(twistProjector(B), std::invalid_argument);
}

TEST(Joints, AdjointIdentitiesAndTransportRoundTrip) {
  std::mt19937_64 rng(3);
  for (int trial = 0; trial < 20; ++trial) {
    const SE3 T1 = randomPose(&rng), T2 = randomPose(&rng);
    EXPECT_LT(((T1 * T2).adjoint() - T1.adjoint() * T2.adjoint()).norm(), 1e-9);
    EXPECT_LT((T1.inverse().adjoint() - T1.adjoint().inverse()).norm(), 1e-9);
    const Vec6 xi_a = 0.3 * randomTwist(&rng);
    const Vec6 xi_b = transportTwist(T1, xi_a);
    EXPECT_LT((transportTwist(T1.inverse(), xi_b) - xi_a).norm(), 1e-12);
    // The same motion written in frame b: Exp(xi_b) = T_b_a Exp(xi_a) T_b_a^-1.
    const SE3 lhs = SE3::exp(xi_b), rhs = T1 * SE3::exp(xi_a) * T1.inverse();
    EXPECT_LT((lhs.matrix() - rhs.matrix()).norm(), 1e-9);
  }
}

TEST(Joints, PlanarMotionStaysOnThePlaneAndCoordinatesRoundTrip) {
  std::mt19937_64 rng(5);
  for (int trial = 0; trial < 20; ++trial) {
    const SE3 T_world_joint = randomPose(&rng);
    const Joint joint(JointType::kPlanar, T_world_joint);
    JointVector theta(3);
    theta << 0.8, -0.5, 1.3;
    theta *= 0.5 + trial * 0.1;
    const SE3 M = joint.motionWorld(theta);
    // A point on the plane (joint z = 0) stays on it.
    const Vec3 p = T_world_joint * Vec3(1.5, -0.7, 0.0);
    EXPECT_NEAR((T_world_joint.inverse() * (M * p)).z(), 0, 1e-12);
    // The normal direction is preserved.
    const Vec3 n = T_world_joint.rotation().col(2);
    EXPECT_LT((M.rotation() * n - n).norm(), 1e-12);
    EXPECT_LT((joint.coordinates(M) - theta).norm(), 1e-9);
    EXPECT_LT((joint.twist(theta, 0.1) - joint.basis() * theta / 0.1).norm(), 1e-12);
  }
  const Joint joint(JointType::kRevolute, SE3());
  EXPECT_THROW(joint.motionJoint(JointVector::Zero(3)), std::invalid_argument);
  EXPECT_THROW(joint.twist(JointVector::Zero(1), 0.0), std::invalid_argument);
}

TEST(Joints, CoordinatesDropTheMotionTheJointCannotMake) {
  const Joint joint(JointType::kRevolute, SE3(SO3::exp(Vec3(0.3, 0, 0)), Vec3(1, 2, 0)));
  JointVector theta(1);
  theta << 0.4;
  const SE3 lift = SE3::exp((Vec6() << 0, 0, 0.2, 0, 0, 0).finished());  // along the hinge
  const SE3 M =
      joint.T_world_joint() * lift * joint.motionJoint(theta) * joint.T_world_joint().inverse();
  EXPECT_NEAR(joint.coordinates(M)(0), 0.4, 1e-12);
}

TEST(Joints, SvdPlaneFitIsExactOnPlanarPoints) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-5, 5);
  const Vec3 n = Vec3(0.1, -0.2, 1.0).normalized();
  const double d = -0.4;
  std::vector<Vec3> pts;
  for (int i = 0; i < 50; ++i) {
    Vec3 p(u(rng), u(rng), u(rng));
    pts.push_back(p - (n.dot(p) + d) * n);
  }
  const Plane plane = fitPlaneSvd(pts);
  const double s = plane.normal.dot(n) > 0 ? 1 : -1;
  EXPECT_LT((s * plane.normal - n).norm(), 1e-10);
  EXPECT_NEAR(s * plane.d, d, 1e-10);
  EXPECT_THROW(fitPlaneSvd({Vec3(0, 0, 0), Vec3(1, 1, 1)}), std::invalid_argument);
  EXPECT_THROW(fitPlaneSvd({Vec3(0, 0, 0), Vec3(1, 1, 1), Vec3(2, 2, 2), Vec3(3, 3, 3)}),
               std::invalid_argument);
}

TEST(Joints, RansacFindsTheRoadAmongOutliers) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-10, 10);
  std::normal_distribution<double> g(0, 0.01);  // m of sensor noise
  std::vector<Vec3> pts;
  for (int i = 0; i < 300; ++i) pts.emplace_back(u(rng), u(rng), 0.2 + g(rng));
  for (int i = 0; i < 200; ++i) pts.emplace_back(u(rng), u(rng), 0.5 + std::abs(u(rng)));
  PlaneRansacParams params;
  params.inlier_threshold = 0.05;
  const PlaneFit fit = fitPlaneRansac(pts, params);
  EXPECT_GT(std::abs(fit.plane.normal.z()), 0.9999);
  EXPECT_NEAR(std::abs(fit.plane.d), 0.2, 0.005);
  EXPECT_GE(fit.inliers.size(), 295u);
  EXPECT_LE(fit.inliers.size(), 300u);
  for (int i : fit.inliers) EXPECT_LT(i, 300);
  EXPECT_LT(fit.rms, 0.02);
  // The joint frame sits on the plane with z up.
  const SE3 T_world_joint = planeJointFrame(fit.plane, Vec3(3, 4, 7), Vec3::UnitZ());
  EXPECT_GT(T_world_joint.rotation()(2, 2), 0.9999);
  EXPECT_NEAR(T_world_joint.translation().z(), 0.2, 0.005);
  EXPECT_NEAR(T_world_joint.translation().x(), 3, 0.01);

  EXPECT_THROW(fitPlaneRansac(std::vector<Vec3>(pts.begin(), pts.begin() + 5)),
               std::invalid_argument);
  params.min_inliers = 400;
  EXPECT_THROW(fitPlaneRansac(pts, params), std::invalid_argument);
  params.min_inliers = 10;
  params.inlier_threshold = 0;
  EXPECT_THROW(fitPlaneRansac(pts, params), std::invalid_argument);
}

TEST(Joints, HingeFromTheSyntheticDoorsMotion) {
  SyntheticConfig config;
  config.scene = "door";
  config.frames = 60;
  config.width = 64;
  config.height = 48;
  const SyntheticScene scene = SyntheticScene::make(config);
  ASSERT_EQ(scene.objects().size(), 1u);
  const SyntheticObject door = scene.objects()[0];
  ASSERT_EQ(door.joint, JointType::kRevolute);
  auto pose = [&](int frame) { return scene.objectPoses(frame)[0].T_world_object; };
  std::vector<SE3> motions;
  for (int f = 10; f < 60; f += 10) motions.push_back(pose(f) * pose(0).inverse());
  const Hinge hinge = hingeFromMotions(motions);
  const Vec3 axis_gt = door.T_world_joint.rotation().col(2);
  EXPECT_GT(std::abs(hinge.axis.dot(axis_gt)), 1 - 1e-9);
  const Vec3 offset = hinge.point - door.T_world_joint.translation();
  EXPECT_LT((offset - offset.dot(axis_gt) * axis_gt).norm(), 1e-6);  // m, distance to the axis
  // The hinge's joint frame reproduces the motions as pure rotations about z.
  const Joint joint(JointType::kRevolute, hingeJointFrame(hinge));
  for (const SE3& M : motions) {
    const SE3 again = joint.motionWorld(joint.coordinates(M));
    EXPECT_LT((again.matrix() - M.matrix()).norm(), 1e-6);
  }
  EXPECT_THROW(hingeFromMotions({SE3(), SE3(SO3(), Vec3(1, 0, 0))}), std::invalid_argument);
}

// A door's plane closed and opened by 20 deg about a tilted hinge in it: the hinge is the
// planes' intersection, with the point nearest to the given one.
TEST(Joints, HingeFromTheDoorsPlanes) {
  const Vec3 axis = Vec3(0.1, 0.2, 1).normalized(), on_axis(2, -1, 0.5);
  const Vec3 normal_closed = axis.cross(Vec3::UnitX()).normalized();  // the axis lies in the door
  const Plane closed{normal_closed, -normal_closed.dot(on_axis)};
  const Vec3 normal_open = SO3::exp(axis * 20 * M_PI / 180) * normal_closed;
  for (const double sign : {1.0, -1.0}) {  // a fitted normal's sign is arbitrary
    const Plane open{sign * normal_open, -sign * normal_open.dot(on_axis)};
    const Vec3 near = on_axis + 0.7 * axis + Vec3(0.3, -0.2, 0.1);
    const Hinge hinge = hingeFromPlanes(closed, open, near, 0.1);
    EXPECT_GT(std::abs(hinge.axis.dot(axis)), 1 - 1e-12);
    const Vec3 offset = hinge.point - on_axis;
    EXPECT_LT((offset - offset.dot(axis) * axis).norm(), 1e-12);  // on the axis
    // The point of the line nearest to `near`: their difference is across the axis.
    EXPECT_LT(std::abs((near - hinge.point).dot(axis)), 1e-12);
  }
  EXPECT_THROW(hingeFromPlanes(closed, closed, on_axis, 0.1), std::invalid_argument);
  const Plane slightly{SO3::exp(axis * 0.05) * normal_closed, 0};
  EXPECT_THROW(hingeFromPlanes(closed, slightly, on_axis, 0.1), std::invalid_argument);
}

}  // namespace
}  // namespace radslam
