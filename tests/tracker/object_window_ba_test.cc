// Dynamic window BA of one object: chained-motion Jacobians against central differences, exact
// recovery without noise, gain over frame-to-frame tracking under noise, covariance consistency,
// static detection and input checks.
#include "tracker/object_window_ba.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>

#include "common/synthetic.h"
#include "tracker/object_synthetic.h"
#include "tracker/object_tracking.h"

namespace radslam {
namespace {

TEST(ObjectWindowBa, ChainedMotionJacobianMatchesCentralDifferences) {
  std::mt19937_64 rng(3);
  std::normal_distribution<double> g(0, 1);
  for (JointType type : {JointType::kFree, JointType::kPlanar, JointType::kRevolute}) {
    const JointBasis A = jointBasis(type);
    const int k = static_cast<int>(A.cols());
    for (int trial = 0; trial < 5; ++trial) {
      std::vector<JointVector> theta(4, JointVector(k));
      for (JointVector& t : theta)
        for (int i = 0; i < k; ++i) t(i) = 0.4 * g(rng);
      const Vec3 q(g(rng), g(rng), g(rng));
      const int f = 3;
      for (int from = 0; from < f; ++from) {  // the frame where the point was measured
        Vec3 moved;
        const Eigen::MatrixXd J = chainedMotionJacobian(A, theta, f, q, &moved, from);
        ASSERT_EQ(J.cols(), f * k);
        const double h = 1e-6;
        for (int m = 0; m < f; ++m) {
          for (int c = 0; c < k; ++c) {
            std::vector<JointVector> tp = theta, tm = theta;
            tp[m](c) += h;
            tm[m](c) -= h;
            Vec3 pp, pm;
            chainedMotionJacobian(A, tp, f, q, &pp, from);
            chainedMotionJacobian(A, tm, f, q, &pm, from);
            const Vec3 fd = (pp - pm) / (2 * h);
            EXPECT_LT((fd - J.col(m * k + c)).norm(), 1e-7 * (1 + fd.norm()))
                << jointTypeName(type) << " theta " << m << " coordinate " << c << " from " << from;
          }
        }
      }
    }
  }
}

SyntheticScene carScene(int frames) {
  SyntheticConfig config;
  config.scene = "car";
  config.frames = frames;
  config.width = 320;
  config.height = 240;
  return SyntheticScene::make(config);
}

// Mean object-frame motion error of a window solution.
MotionError windowError(const SyntheticScene& scene, int object_id, int first,
                        const std::vector<SE3>& motions) {
  MotionError sum;
  for (size_t i = 0; i < motions.size(); ++i) {
    const int f = first + static_cast<int>(i);
    SE3 T_world_object;
    for (const ObjectPoseSample& s : scene.objectPoses(f))
      if (s.object_id == object_id) T_world_object = s.T_world_object;
    const MotionError e = objectMotionError(
        motions[i], syntheticObjectMotion(scene, object_id, f, f + 1), T_world_object);
    sum.translation += e.translation / motions.size();
    sum.rotation += e.rotation / motions.size();
  }
  return sum;
}

TEST(ObjectWindowBa, RecoversTheCarExactlyWithoutNoise) {
  const SyntheticScene scene = carScene(6);
  const Joint joint(JointType::kPlanar, syntheticObject(scene, 100).T_world_joint);
  std::mt19937_64 rng(1);
  const ObjectWindowProblem p = syntheticObjectWindow(scene, joint, 100, 0, 5, 3, {}, &rng);
  ASSERT_GT(p.points_cam0.size(), 50u);
  ObjectWindowParams params;
  params.pixel_sigma = 0.01;
  params.depth_sigma_rel = 1e-4;
  const ObjectWindowResult r = solveObjectWindow(p, params);
  ASSERT_EQ(r.motion_world.size(), 4u);
  const MotionError e = windowError(scene, 100, 0, r.motion_world);
  // The true car speed changes slowly, the constant-velocity term is soft: within 1e-5 m / rad.
  EXPECT_LT(e.translation, 1e-5);
  EXPECT_LT(e.rotation, 1e-5);
  EXPECT_LT(r.rms_px, 1e-3);
  EXPECT_FALSE(r.is_static);
  EXPECT_EQ(r.covariance.rows(), 12);
}

TEST(ObjectWindowBa, RecoversTheCarExactlyFromPointsAnchoredInLaterFrames) {
  const SyntheticScene scene = carScene(6);
  const Joint joint(JointType::kPlanar, syntheticObject(scene, 100).T_world_joint);
  std::mt19937_64 rng(1);
  // Frames 0..4; points measured in frame 0, plus points measured in frame 2 seen in 3 and 4.
  ObjectWindowProblem p = syntheticObjectWindow(scene, joint, 100, 0, 5, 6, {}, &rng);
  const ObjectWindowProblem later = syntheticObjectWindow(scene, joint, 100, 2, 3, 3, {}, &rng);
  p.anchor_frame.assign(p.points_cam0.size(), 0);
  const int offset = static_cast<int>(p.points_cam0.size());
  for (const Vec3& point : later.points_cam0) {
    p.points_cam0.push_back(point);
    p.anchor_frame.push_back(2);
  }
  for (ObjectObservation o : later.observations) {
    o.landmark += offset;
    o.frame += 2;
    p.observations.push_back(o);
  }
  ASSERT_GT(later.points_cam0.size(), 50u);
  ObjectWindowParams params;
  params.pixel_sigma = 0.01;
  params.depth_sigma_rel = 1e-4;
  const ObjectWindowResult r = solveObjectWindow(p, params);
  const MotionError e = windowError(scene, 100, 0, r.motion_world);
  EXPECT_LT(e.translation, 1e-5);
  EXPECT_LT(e.rotation, 1e-5);
  EXPECT_LT(r.rms_px, 1e-3);
  // An anchor must come before the frames that observe it.
  p.anchor_frame.back() = 4;
  EXPECT_THROW(solveObjectWindow(p, params), std::invalid_argument);
}

TEST(ObjectWindowBa, RecoversTheDoorExactlyWithFixedPoints) {
  SyntheticConfig config;
  config.scene = "door";
  config.frames = 6;
  config.width = 160;
  config.height = 120;
  const SyntheticScene scene = SyntheticScene::make(config);
  const Joint joint(JointType::kRevolute, syntheticObject(scene, 100).T_world_joint);
  std::mt19937_64 rng(1);
  const ObjectWindowProblem p = syntheticObjectWindow(scene, joint, 100, 0, 5, 2, {}, &rng);
  ObjectWindowParams params;
  params.optimise_points = false;
  params.pixel_sigma = 1e-3;  // exact data: the (biasing) constant-velocity prior is negligible
  const ObjectWindowResult r = solveObjectWindow(p, params);
  const MotionError e = windowError(scene, 100, 0, r.motion_world);
  EXPECT_LT(e.translation, 1e-6);
  EXPECT_LT(e.rotation, 1e-6);
  EXPECT_EQ(r.covariance.rows(), 4);
  for (const Vec6& xi : r.twist_joint) EXPECT_EQ(xi.head<5>().norm(), 0);  // only wz
}

TEST(ObjectWindowBa, BeatsFrameToFrameTrackingUnderNoise) {
  const SyntheticScene scene = carScene(7);
  const Joint joint(JointType::kPlanar, syntheticObject(scene, 100).T_world_joint);
  ObjectNoise noise;
  noise.pixel_sigma = 1.0;
  noise.depth_sigma_rel = 0.003;
  noise.outlier_ratio = 0.05;
  ObjectWindowParams params;
  params.depth_sigma_rel = noise.depth_sigma_rel;
  std::mt19937_64 rng(5);
  double window_t = 0, window_r = 0, pair_t = 0, pair_r = 0;
  const int trials = 10, frames = 6;
  for (int t = 0; t < trials; ++t) {
    const ObjectWindowProblem p =
        syntheticObjectWindow(scene, joint, 100, 0, frames, 3, noise, &rng);
    const ObjectWindowResult r = solveObjectWindow(p, params);
    const MotionError ew = windowError(scene, 100, 0, r.motion_world);
    window_t += ew.translation;
    window_r += ew.rotation;
    // Frame-to-frame: each frame's motion from the frame-0 points tracked into frames f and
    // f + 1 separately, M_f = M_0,f+1 M_0,f^-1.
    std::vector<SE3> M_0f(1), pairs;
    for (int f = 1; f < frames; ++f) {
      std::vector<ObjectCorrespondence> corr;
      for (const ObjectObservation& o : p.observations)
        if (o.frame == f) corr.push_back({p.points_cam0[o.landmark], o.px});
      M_0f.push_back(
          trackObjectMotion(joint, p.camera, p.T_world_cam[0], p.T_world_cam[f], corr, p.dt)
              .motion_world);
      pairs.push_back(M_0f[f] * M_0f[f - 1].inverse());
    }
    const MotionError ep = windowError(scene, 100, 0, pairs);
    pair_t += ep.translation;
    pair_r += ep.rotation;
  }
  std::printf("  window %.4f m %.4f deg, frame-to-frame %.4f m %.4f deg\n", window_t / trials,
              window_r / trials * 180 / M_PI, pair_t / trials, pair_r / trials * 180 / M_PI);
  EXPECT_LT(window_t, 0.7 * pair_t);
  EXPECT_LT(window_r, 0.7 * pair_r);
}

TEST(ObjectWindowBa, CovarianceMatchesTheScatterOfTheEstimates) {
  const SyntheticScene scene = carScene(4);
  const Joint joint(JointType::kPlanar, syntheticObject(scene, 100).T_world_joint);
  ObjectNoise noise;
  noise.pixel_sigma = 1.0;
  noise.depth_sigma_rel = 0.003;
  ObjectWindowParams params;
  params.depth_sigma_rel = noise.depth_sigma_rel;
  params.huber_px = 1e6;              // Gaussian noise only: plain least squares
  params.cv_sigma_translation = 1e3;  // no motion prior: it would bias the estimate
  params.cv_sigma_rotation = 1e3;
  std::mt19937_64 rng(8);
  std::vector<JointVector> truth;
  for (int f = 0; f < 3; ++f)
    truth.push_back(joint.coordinates(syntheticObjectMotion(scene, 100, f, f + 1)));
  double nees = 0;
  const int trials = 40;
  for (int t = 0; t < trials; ++t) {
    const ObjectWindowProblem p = syntheticObjectWindow(scene, joint, 100, 0, 4, 4, noise, &rng);
    const ObjectWindowResult r = solveObjectWindow(p, params);
    Eigen::VectorXd e(9);
    for (int f = 0; f < 3; ++f) e.segment(3 * f, 3) = r.theta[f] - truth[f];
    nees += e.dot(r.covariance.ldlt().solve(e));
  }
  std::printf("  mean NEES %.2f (dimension 9)\n", nees / trials);
  // 9 for a consistent estimator (40 trials: 5-sigma band about +-3.4).
  EXPECT_GT(nees / trials, 9 - 3.4);
  EXPECT_LT(nees / trials, 9 + 3.4);
}

TEST(ObjectWindowBa, StaticObjectIsFlaggedStatic) {
  const SyntheticScene scene = carScene(5);
  const Joint joint(JointType::kPlanar, SE3());
  // The car's frame-0 points observed as if the car stood still.
  std::mt19937_64 rng(2);
  ObjectWindowProblem p = syntheticObjectWindow(scene, joint, 100, 0, 2, 3, {}, &rng);
  for (ObjectObservation& o : p.observations) {
    const Vec3 pc = p.T_world_cam[1].inverse() * p.T_world_cam[0] * p.points_cam0[o.landmark];
    o.px = Eigen::Vector2d(p.camera.fx * pc.x() / pc.z() + p.camera.cx,
                           p.camera.fy * pc.y() / pc.z() + p.camera.cy);
  }
  EXPECT_TRUE(solveObjectWindow(p).is_static);
  const ObjectWindowProblem moving = syntheticObjectWindow(scene, joint, 100, 0, 2, 3, {}, &rng);
  EXPECT_FALSE(solveObjectWindow(moving).is_static);
}

TEST(ObjectWindowBa, BadInputIsRejected) {
  const SyntheticScene scene = carScene(4);
  const Joint joint(JointType::kPlanar, SE3());
  std::mt19937_64 rng(2);
  const ObjectWindowProblem good = syntheticObjectWindow(scene, joint, 100, 0, 3, 4, {}, &rng);
  ObjectWindowProblem p = good;
  p.T_world_cam.resize(1);
  EXPECT_THROW(solveObjectWindow(p), std::invalid_argument);
  p = good;
  p.observations[0].landmark = 100000;
  EXPECT_THROW(solveObjectWindow(p), std::invalid_argument);
  p = good;
  p.observations[0].frame = 0;
  EXPECT_THROW(solveObjectWindow(p), std::invalid_argument);
  p = good;
  p.dt = 0;
  EXPECT_THROW(solveObjectWindow(p), std::invalid_argument);
  const std::vector<JointVector> wrong(2, JointVector::Zero(6));
  EXPECT_THROW(solveObjectWindow(good, {}, &wrong), std::invalid_argument);
  ObjectWindowParams params;
  params.pixel_sigma = 0;
  EXPECT_THROW(solveObjectWindow(good, params), std::invalid_argument);
  EXPECT_THROW(syntheticObjectWindow(scene, joint, 100, 0, 1, 4, {}, &rng), std::invalid_argument);
}

}  // namespace
}  // namespace radslam
