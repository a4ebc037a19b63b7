// Motion-only alignment: Jacobian/Hessian against finite differences, convergence, covariance
// calibration, robustness and input checks.
#include "tracker/motion_only.h"

#include <gtest/gtest.h>

#include <random>

#include <Eigen/Dense>

#include "tests/tracker/ba_synthetic.h"

namespace radslam {
namespace {

// Keyframes 0..K-2 of the scene form the window; the last scene camera is the frame.
struct AlignmentCase {
  test::SyntheticScene scene;
  std::vector<DenseBaKeyframe> keyframes;
  std::vector<MotionOnlyEdge> edges;
  SE3 T_world_frame;  // ground truth
};

AlignmentCase makeCase(std::mt19937* rng, double sigma, int K = 3, int w = 32, int h = 24) {
  AlignmentCase s;
  s.scene = test::makeScene(K + 1, w, h, 0.9 * w, rng, 0.25);
  s.T_world_frame = s.scene.T_world_cam[K];
  for (int k = 0; k < K; ++k) {
    DenseBaKeyframe kf;
    kf.T_world_cam = s.scene.T_world_cam[k];
    kf.inv_depth = s.scene.inv_depth[k];
    s.keyframes.push_back(kf);
    const DenseBaEdge e = test::makeEdge(s.scene, k, K, sigma, 1.0, rng);
    s.edges.push_back({k, e.target, e.weight});
  }
  return s;
}

TEST(MotionOnly, GradientIsHalfTheDerivativeOfTheRobustCost) {
  std::mt19937 rng(1);
  AlignmentCase s = makeCase(&rng, 0.8);
  std::uniform_real_distribution<double> U(0, 1);
  for (MotionOnlyEdge& e : s.edges) {  // some gross outliers so the kernel is active
    for (int q = 0; q < static_cast<int>(e.target.total()); ++q) {
      if (U(rng) < 0.1) e.target.at<cv::Vec2f>(q) += cv::Vec2f(5.0f, -3.0f);
      // Anisotropic information (an aperture at some angle) on about half of the pixels.
      cv::Vec3f& w = e.weight.at<cv::Vec3f>(q);
      if (U(rng) < 0.5) w[1] = static_cast<float>(0.9 * (2 * U(rng) - 1) * std::sqrt(w[0] * w[2]));
    }
  }
  SE3 T = s.T_world_frame;
  test::perturbPose(&T, 0.01, 0.02, &rng);
  MotionOnlyAligner aligner;
  Mat6 H;
  Vec6 g;
  aligner.linearize(s.scene.camera, s.keyframes, s.edges, T, &H, &g);
  const double h = 1e-6;
  for (int q = 0; q < 6; ++q) {
    const Vec6 dq = h * Vec6::Unit(q);
    const double cp =
        aligner.linearize(s.scene.camera, s.keyframes, s.edges, T * SE3::exp(dq), nullptr, nullptr);
    const double cm = aligner.linearize(s.scene.camera, s.keyframes, s.edges, T * SE3::exp(-dq),
                                        nullptr, nullptr);
    const double num = 0.5 * (cp - cm) / (2 * h);
    EXPECT_NEAR(g(q), num, 1e-5 * (1 + std::abs(num))) << q;
  }
}

TEST(MotionOnly, GradientWithTheFrameDepthIsHalfTheDerivativeOfTheRobustCost) {
  std::mt19937 rng(3);
  const AlignmentCase s = makeCase(&rng, 0.5);
  // A smooth measured depth of the frame that disagrees with the scene (the kernel bites), with
  // a hole.
  const CameraModel& cam = s.scene.camera;
  const double mean = cv::mean(s.scene.inv_depth.back())[0];
  MotionOnlyDepth depth;
  depth.inv_depth.create(cam.height, cam.width, CV_32FC1);
  depth.inv_depth_var.create(cam.height, cam.width, CV_32FC1);
  for (int v = 0; v < cam.height; ++v) {
    for (int u = 0; u < cam.width; ++u) {
      depth.inv_depth.at<float>(v, u) = static_cast<float>(mean * (1 + 0.004 * u - 0.003 * v));
      depth.inv_depth_var.at<float>(v, u) = static_cast<float>(1e-3 * mean * mean);
    }
  }
  depth.inv_depth_var.at<float>(5, 7) = 0;
  SE3 T = s.T_world_frame;
  test::perturbPose(&T, 0.01, 0.02, &rng);
  MotionOnlyAligner aligner;
  Mat6 H, H_flow;
  Vec6 g, g_flow;
  aligner.linearize(cam, s.keyframes, s.edges, T, &H, &g, nullptr, nullptr, depth);
  aligner.linearize(cam, s.keyframes, s.edges, T, &H_flow, &g_flow);
  EXPECT_GT((H - H_flow).norm(), 1e-3 * H_flow.norm());  // the depth residual takes part
  const double h = 1e-6;
  for (int q = 0; q < 6; ++q) {
    const Vec6 dq = h * Vec6::Unit(q);
    const double cp = aligner.linearize(cam, s.keyframes, s.edges, T * SE3::exp(dq), nullptr,
                                        nullptr, nullptr, nullptr, depth);
    const double cm = aligner.linearize(cam, s.keyframes, s.edges, T * SE3::exp(-dq), nullptr,
                                        nullptr, nullptr, nullptr, depth);
    const double num = 0.5 * (cp - cm) / (2 * h);
    EXPECT_NEAR(g(q), num, 1e-5 * (1 + std::abs(num))) << q;
  }
}

TEST(MotionOnly, HessianIsTheCostCurvatureAtAZeroResidualPose) {
  // At r = 0 the cost's Hessian is exactly 2 J^T W J: checks J itself, not only J^T W r.
  std::mt19937 rng(2);
  const AlignmentCase s = makeCase(&rng, 0.0, 2, 16, 12);
  MotionOnlyOptions opt;
  opt.robust_scale = 0;
  MotionOnlyAligner aligner(opt);
  Mat6 H;
  Vec6 g;
  aligner.linearize(s.scene.camera, s.keyframes, s.edges, s.T_world_frame, &H, &g);
  EXPECT_LT(g.norm(), 1e-3);  // float targets: not exactly zero
  const double h = 1e-4;
  auto cost = [&](const Vec6& d) {
    return aligner.linearize(s.scene.camera, s.keyframes, s.edges, s.T_world_frame * SE3::exp(d),
                             nullptr, nullptr);
  };
  Mat6 num;
  for (int a = 0; a < 6; ++a) {
    for (int b = 0; b < 6; ++b) {
      const Vec6 ea = h * Vec6::Unit(a), eb = h * Vec6::Unit(b);
      num(a, b) = (cost(ea + eb) - cost(ea - eb) - cost(eb - ea) + cost(-ea - eb)) / (4 * h * h);
    }
  }
  EXPECT_LT((2 * H - num).norm(), 1e-3 * H.norm()) << "2H\n" << 2 * H << "\nnumeric\n" << num;
}

TEST(MotionOnly, NoiseFreeConvergesToTheTruePose) {
  std::mt19937 rng(3);
  const AlignmentCase s = makeCase(&rng, 0.0);
  SE3 T0 = s.T_world_frame;
  test::perturbPose(&T0, 0.03, 0.05, &rng);
  MotionOnlyOptions opt;
  opt.max_iterations = 30;
  const MotionOnlyResult r = MotionOnlyAligner(opt).align(s.scene.camera, s.keyframes, s.edges, T0);
  ASSERT_TRUE(r.ok) << r.error;
  const Vec6 e = test::poseError(s.T_world_frame, r.T_world_frame);
  EXPECT_LT(e.norm(), 1e-6) << e.transpose();
  EXPECT_LT(r.final_cost, 1e-6 * r.initial_cost);
  EXPECT_LT(r.mean_reprojection_error_px, 1e-4);
  EXPECT_GT(r.num_residuals, 1000);
}

TEST(MotionOnly, CovarianceIsCalibrated) {
  // Known Gaussian target noise, weights 1/sigma^2, no robust kernel: the NEES of the pose
  // (6-dof chi-square) falls below chi2_6(0.954) = 12.85 for about 95.4% of the trials.
  std::mt19937 rng(4);
  MotionOnlyOptions opt;
  opt.robust_scale = 0;
  opt.max_iterations = 20;
  const MotionOnlyAligner aligner(opt);
  int below = 0, trials = 300;
  for (int trial = 0; trial < trials; ++trial) {
    const AlignmentCase s = makeCase(&rng, 0.5, 2, 16, 12);
    SE3 T0 = s.T_world_frame;
    test::perturbPose(&T0, 0.005, 0.01, &rng);
    const MotionOnlyResult r = aligner.align(s.scene.camera, s.keyframes, s.edges, T0);
    ASSERT_TRUE(r.ok) << r.error;
    const Vec6 e = test::poseError(s.T_world_frame, r.T_world_frame);
    below += e.dot(r.covariance.ldlt().solve(e)) < 12.85;
  }
  const double frac = double(below) / trials;
  EXPECT_GE(frac, 0.85);
  EXPECT_LE(frac, 0.99);
  RecordProperty("nees_fraction", std::to_string(frac));
}

TEST(MotionOnly, HuberKernelResistsOutliers) {
  std::mt19937 rng(5);
  AlignmentCase s = makeCase(&rng, 0.3);
  std::uniform_real_distribution<double> U(0, 1);
  for (MotionOnlyEdge& e : s.edges) {
    for (int q = 0; q < static_cast<int>(e.target.total()); ++q) {
      if (U(rng) < 0.15) e.target.at<cv::Vec2f>(q) += cv::Vec2f(8.0f, 5.0f);
    }
  }
  double err[2];
  for (int robust = 0; robust < 2; ++robust) {
    MotionOnlyOptions opt;
    opt.robust_scale = robust ? 2.4477 : 0.0;
    opt.max_iterations = 30;
    const MotionOnlyResult r =
        MotionOnlyAligner(opt).align(s.scene.camera, s.keyframes, s.edges, s.T_world_frame);
    ASSERT_TRUE(r.ok) << r.error;
    err[robust] = test::poseError(s.T_world_frame, r.T_world_frame).norm();
  }
  EXPECT_LT(err[1], 0.5 * err[0]) << "least squares " << err[0] << ", Huber " << err[1];
}

TEST(MotionOnly, TooFewPixelsFailsCleanly) {
  std::mt19937 rng(6);
  AlignmentCase s = makeCase(&rng, 0.0, 1, 16, 12);
  s.edges[0].weight.setTo(cv::Scalar(0, 0));
  s.edges[0].weight.at<cv::Vec3f>(3, 3) = cv::Vec3f(1, 0, 1);
  const MotionOnlyResult r =
      MotionOnlyAligner().align(s.scene.camera, s.keyframes, s.edges, s.T_world_frame);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("valid pixels"), std::string::npos) << r.error;
}

TEST(MotionOnly, RejectsMalformedInput) {
  std::mt19937 rng(7);
  AlignmentCase s = makeCase(&rng, 0.0, 2, 16, 12);
  MotionOnlyAligner aligner;
  auto expectThrow = [&](const std::vector<MotionOnlyEdge>& edges, const std::string& needle) {
    try {
      aligner.align(s.scene.camera, s.keyframes, edges, s.T_world_frame);
      ADD_FAILURE() << "no exception for " << needle;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  std::vector<MotionOnlyEdge> edges = s.edges;
  edges[1].keyframe = 5;
  expectThrow(edges, "edge 1 (keyframe 5): keyframe out of range");
  edges = s.edges;
  edges[0].weight = cv::Mat(12, 16, CV_32FC1);
  expectThrow(edges, "edge 0 (keyframe 0) weight is 16x12 CV_32FC1");
}

}  // namespace
}  // namespace radslam
