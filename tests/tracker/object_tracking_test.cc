// Object tracking under joints: residual Jacobians against central differences, exact recovery on
// noise-free synthetic scenes, constrained vs free estimates under noise, robustness, covariance
// calibration and input checks.
#include "tracker/object_tracking.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>

#include "common/synthetic.h"
#include "tracker/object_synthetic.h"

namespace radslam {
namespace {

CameraModel testCamera(int w = 160, int h = 120) {
  CameraModel cam;
  cam.width = w;
  cam.height = h;
  cam.fx = cam.fy = 0.8 * w;
  cam.cx = 0.5 * (w - 1);
  cam.cy = 0.5 * (h - 1);
  return cam;
}

TEST(ObjectTracking, ResidualJacobianMatchesCentralDifferences) {
  std::mt19937_64 rng(2);
  std::normal_distribution<double> g(0, 1);
  const CameraModel cam = testCamera();
  for (JointType type : {JointType::kFree, JointType::kPlanar, JointType::kRevolute}) {
    const JointBasis A = jointBasis(type);
    for (int trial = 0; trial < 20; ++trial) {
      // Camera 1 looks at the joint origin from about 6 m; theta up to ~1 rad / 1 m.
      const SE3 T_cam1_joint(SO3::exp(0.2 * Vec3(g(rng), g(rng), g(rng))), Vec3(0, 0, 6));
      const Vec3 q(g(rng), g(rng), g(rng));
      JointVector theta(A.cols());
      for (int i = 0; i < theta.size(); ++i) theta(i) = 0.5 * g(rng);
      const Eigen::Vector2d px1(80 + 10 * g(rng), 60 + 10 * g(rng));
      Eigen::Vector2d r;
      JointJacobian H;
      ASSERT_TRUE(objectReprojectionResidual(cam, T_cam1_joint, q, px1, A, theta, &r, &H));
      ASSERT_EQ(H.cols(), A.cols());
      const double h = 1e-6;
      for (int i = 0; i < theta.size(); ++i) {
        JointVector tp = theta, tm = theta;
        tp(i) += h;
        tm(i) -= h;
        Eigen::Vector2d rp, rm;
        ASSERT_TRUE(objectReprojectionResidual(cam, T_cam1_joint, q, px1, A, tp, &rp));
        ASSERT_TRUE(objectReprojectionResidual(cam, T_cam1_joint, q, px1, A, tm, &rm));
        const Eigen::Vector2d fd = (rp - rm) / (2 * h);
        EXPECT_LT((fd - H.col(i)).norm(), 1e-6 * (1 + fd.norm()))
            << jointTypeName(type) << " column " << i;
      }
    }
  }
}

TEST(ObjectTracking, ResidualRejectsPointsBehindTheCamera) {
  const CameraModel cam = testCamera();
  Eigen::Vector2d r(7, 7);
  EXPECT_FALSE(objectReprojectionResidual(cam, SE3(SO3(), Vec3(0, 0, -5)), Vec3::Zero(),
                                          Eigen::Vector2d(1, 1), jointBasis(JointType::kPlanar),
                                          JointVector::Zero(3), &r));
  EXPECT_EQ(r, Eigen::Vector2d(7, 7));
}

// One dynamic scene rendered at width x 3/4 width, with the true motions of one object.
struct ObjectSequence {
  SyntheticScene scene;
  SyntheticObject object;
  CameraModel camera;
  std::vector<RenderedView> views;
  std::vector<SE3> T_world_cam, T_world_object;
};

ObjectSequence makeSequence(const std::string& name, int object_id, int first, int count,
                            int width = 160) {
  SyntheticConfig config;
  config.scene = name;
  config.frames = first + count + 1;
  config.width = width;
  config.height = width * 3 / 4;
  ObjectSequence s{SyntheticScene::make(config), {}, {}, {}, {}, {}};
  s.object = syntheticObject(s.scene, object_id);
  s.camera = s.scene.camera();
  for (int f = first; f <= first + count; ++f) {
    s.T_world_cam.push_back(s.scene.cameraPose(f));
    s.views.push_back(s.scene.render(s.T_world_cam.back(), s.camera, f));
    for (const ObjectPoseSample& p : s.scene.objectPoses(f))
      if (p.object_id == object_id) s.T_world_object.push_back(p.T_world_object);
  }
  return s;
}

SE3 trueMotion(const ObjectSequence& s, int i) {
  return s.T_world_object[i + 1] * s.T_world_object[i].inverse();
}

MotionError track(const ObjectSequence& s, const Joint& joint, int i, const ObjectNoise& noise,
                  std::mt19937_64* rng, ObjectMotionEstimate* out = nullptr, int stride = 2,
                  ObjectTrackingParams params = {}) {
  const std::vector<ObjectCorrespondence> corr =
      syntheticObjectCorrespondences(s.camera, s.views[i], s.object.object_id, s.T_world_cam[i],
                                     s.T_world_cam[i + 1], trueMotion(s, i), stride, noise, rng);
  EXPECT_GE(corr.size(), 40u) << "object barely visible in frame " << i;
  params.pixel_sigma = std::max(noise.pixel_sigma, 1e-3);
  const ObjectMotionEstimate est = trackObjectMotion(
      joint, s.camera, s.T_world_cam[i], s.T_world_cam[i + 1], corr, 1.0 / s.scene.fps(), params);
  if (out) *out = est;
  return objectMotionError(est.motion_world, trueMotion(s, i), s.T_world_object[i]);
}

TEST(ObjectTracking, PlanarCarIsRecoveredExactlyWithoutNoise) {
  const ObjectSequence s = makeSequence("car", 100, 0, 4);
  ASSERT_EQ(s.object.joint, JointType::kPlanar);
  std::mt19937_64 rng(1);
  for (JointType type : {JointType::kPlanar, JointType::kFree}) {
    const Joint joint(type, s.object.T_world_joint);
    for (int i = 0; i < 4; ++i) {
      ObjectMotionEstimate est;
      const MotionError err = track(s, joint, i, ObjectNoise{}, &rng, &est);
      // Tolerance: 1e-6 m and 1e-6 rad (the car moves ~1 m and ~0.01-0.1 rad per frame).
      EXPECT_LT(err.translation, 1e-6) << jointTypeName(type) << " frame " << i;
      EXPECT_LT(err.rotation, 1e-6) << jointTypeName(type) << " frame " << i;
      EXPECT_TRUE(est.converged);
      EXPECT_LT(est.rms_px, 1e-6);
      EXPECT_GT(trueMotion(s, i).translation().norm(), 0.1);  // the car does move
    }
  }
}

TEST(ObjectTracking, RevoluteDoorIsRecoveredExactlyWithoutNoise) {
  const ObjectSequence s = makeSequence("door", 100, 0, 3);
  ASSERT_EQ(s.object.joint, JointType::kRevolute);
  std::mt19937_64 rng(1);
  const Joint joint(JointType::kRevolute, s.object.T_world_joint);
  for (int i = 0; i < 3; ++i) {
    ObjectMotionEstimate est;
    const MotionError err = track(s, joint, i, ObjectNoise{}, &rng, &est);
    EXPECT_LT(err.translation, 1e-7) << "frame " << i;
    EXPECT_LT(err.rotation, 1e-7) << "frame " << i;
    // The estimated twist is a pure rotation about the hinge.
    EXPECT_NEAR(est.twist_joint.head<5>().norm(), 0, 1e-15);
  }
}

// Mean object motion error over many noisy trials, constrained vs free.
void compareUnderNoise(const ObjectSequence& s, int pairs, int trials, const ObjectNoise& noise) {
  std::mt19937_64 rng(42);
  const Joint constrained(s.object.joint, s.object.T_world_joint);
  const Joint free(JointType::kFree, s.object.T_world_joint);
  double tc = 0, rc = 0, tf = 0, rf = 0;
  for (int trial = 0; trial < trials; ++trial) {
    const int i = trial % pairs;
    std::mt19937_64 rng_copy = rng;  // same noise for both estimates
    const MotionError ec = track(s, constrained, i, noise, &rng);
    const MotionError ef = track(s, free, i, noise, &rng_copy);
    tc += ec.translation;
    rc += ec.rotation;
    tf += ef.translation;
    rf += ef.rotation;
  }
  std::printf("  %s: translation %.4f vs %.4f m, rotation %.4f vs %.4f deg (constrained/free)\n",
              s.scene.config().scene.c_str(), tc / trials, tf / trials, rc / trials * 180 / M_PI,
              rf / trials * 180 / M_PI);
  EXPECT_LT(tc, 0.7 * tf);
  EXPECT_LT(rc, 0.7 * rf);
}

TEST(ObjectTracking, PlanarConstraintBeatsFreeTrackingUnderNoise) {
  ObjectNoise noise;
  noise.pixel_sigma = 1.0;
  noise.depth_sigma_rel = 0.002;
  noise.outlier_ratio = 0.05;
  compareUnderNoise(makeSequence("car", 100, 0, 4, 320), 4, 60, noise);
}

TEST(ObjectTracking, RevoluteConstraintBeatsFreeTrackingUnderNoise) {
  ObjectNoise noise;
  noise.pixel_sigma = 1.0;
  noise.depth_sigma_rel = 0.003;
  noise.outlier_ratio = 0.05;
  compareUnderNoise(makeSequence("door", 100, 0, 3), 3, 60, noise);
}

TEST(ObjectTracking, HuberKernelResistsOutliers) {
  const ObjectSequence s = makeSequence("car", 100, 0, 1, 320);
  const Joint joint(JointType::kPlanar, s.object.T_world_joint);
  ObjectNoise noise;
  noise.pixel_sigma = 0.5;
  noise.outlier_ratio = 0.15;
  noise.outlier_px = 40;
  ObjectTrackingParams least_squares;
  least_squares.huber_px = 1e6;
  std::mt19937_64 rng(9), rng_copy = rng;  // same data for both
  ObjectMotionEstimate est;
  const MotionError robust = track(s, joint, 0, noise, &rng, &est, 2);
  const MotionError plain = track(s, joint, 0, noise, &rng_copy, nullptr, 2, least_squares);
  EXPECT_LT(robust.translation, 0.5 * plain.translation);
  EXPECT_LT(robust.rotation, 0.5 * plain.rotation);
  EXPECT_GT(est.inliers, 0);
}

TEST(ObjectTracking, CovarianceMatchesTheScatterOfTheEstimates) {
  const ObjectSequence s = makeSequence("car", 100, 0, 1, 320);
  const Joint joint(JointType::kPlanar, s.object.T_world_joint);
  ObjectNoise noise;
  noise.pixel_sigma = 1.0;  // pixel noise only: the model the covariance assumes
  std::mt19937_64 rng(4);
  const JointVector truth = joint.coordinates(trueMotion(s, 0));
  double nees = 0;
  const int trials = 200;
  for (int t = 0; t < trials; ++t) {
    ObjectMotionEstimate est;
    track(s, joint, 0, noise, &rng, &est, 3);
    const JointVector e = est.theta - truth;
    nees += e.dot(est.covariance.ldlt().solve(e));
  }
  // Mean NEES of a consistent 3-DOF estimator is 3 (200 trials: 5-sigma band about +-0.55).
  EXPECT_NEAR(nees / trials, 3.0, 0.6);
}

TEST(ObjectTracking, TrackedObjectFollowsTheCar) {
  const ObjectSequence s = makeSequence("car", 100, 0, 3);
  const Joint joint(JointType::kPlanar, s.object.T_world_joint);
  std::mt19937_64 rng(1);
  TrackedObject object;
  object.T_world_object = s.T_world_object[0];
  // Points are fixed to the object: after each tracked motion, the object frame is the true one.
  for (int i = 0; i < 3; ++i) {
    ObjectMotionEstimate est;
    track(s, joint, i, ObjectNoise{}, &rng, &est);
    applyObjectMotion(est, joint, &object);
    EXPECT_LT((object.T_world_object.matrix() - s.T_world_object[i + 1].matrix()).norm(), 1e-6);
  }
  EXPECT_EQ(object.joint_type, JointType::kPlanar);
  EXPECT_NEAR(object.twist(2), 0, 1e-15);  // no vertical velocity on the road
  EXPECT_GT(object.covariance(0, 0), 0);
  const SE3 T = initialObjectPose(joint, {Vec3(1, 2, 0), Vec3(3, 4, 2)});
  EXPECT_LT((T.translation() - Vec3(2, 3, 1)).norm(), 1e-15);
  EXPECT_THROW(initialObjectPose(joint, {}), std::invalid_argument);
}

TEST(ObjectTracking, BadInputIsRejected) {
  const CameraModel cam = testCamera();
  const Joint joint(JointType::kPlanar, SE3());
  std::vector<ObjectCorrespondence> corr(10, {Vec3(0, 0, 5), Eigen::Vector2d(80, 60)});
  EXPECT_THROW(trackObjectMotion(joint, cam, SE3(), SE3(), corr, 0.0), std::invalid_argument);
  EXPECT_THROW(
      trackObjectMotion(joint, cam, SE3(), SE3(),
                        std::vector<ObjectCorrespondence>(corr.begin(), corr.begin() + 3), 0.1),
      std::invalid_argument);
  const JointVector wrong = JointVector::Zero(6);
  EXPECT_THROW(trackObjectMotion(joint, cam, SE3(), SE3(), corr, 0.1, {}, &wrong),
               std::invalid_argument);
  corr[4].px1.x() = std::nan("");
  EXPECT_THROW(trackObjectMotion(joint, cam, SE3(), SE3(), corr, 0.1), std::invalid_argument);
  CameraModel bad = cam;
  bad.fx = 0;
  EXPECT_THROW(trackObjectMotion(joint, bad, SE3(), SE3(), corr, 0.1), std::invalid_argument);
}

TEST(ObjectTracking, CorrespondencesFromFlowFollowTheMaskAndTheFlow) {
  const CameraModel cam = testCamera(16, 12);
  cv::Mat depth(12, 16, CV_32FC1, cv::Scalar(4.0f));
  cv::Mat instance(12, 16, CV_16UC1, cv::Scalar(1));
  instance(cv::Rect(2, 3, 5, 4)).setTo(100);  // 20 object pixels
  depth.at<float>(3, 2) = 0;                  // no depth: skipped
  cv::Mat flow(12, 16, CV_32FC2, cv::Scalar(1.5f, -0.5f));
  const auto corr = objectCorrespondencesFromFlow(cam, depth, instance, 100, flow);
  ASSERT_EQ(corr.size(), 19u);
  EXPECT_NEAR(corr[0].p_cam0.z(), 4.0, 1e-12);
  EXPECT_NEAR(corr[0].px1.x(), 3 + 1.5, 1e-6);  // first valid pixel is (3, 3)
  EXPECT_NEAR(corr[0].px1.y(), 3 - 0.5, 1e-6);
  EXPECT_EQ(objectCorrespondencesFromFlow(cam, depth, instance, 100, flow, 2).size(),
            6u);  // x 2,4,6 by y 4,6
  EXPECT_THROW(objectCorrespondencesFromFlow(cam, depth, instance, 100, cv::Mat(12, 16, CV_32FC1)),
               std::invalid_argument);
  EXPECT_THROW(objectCorrespondencesFromFlow(cam, depth(cv::Rect(0, 0, 8, 8)), instance, 100, flow),
               std::invalid_argument);
}

}  // namespace
}  // namespace radslam
