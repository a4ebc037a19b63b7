// Dense BA: the Schur-complement step and the marginal covariances equal those of the full
// (6N + M) normal equations, assembled here pixel by pixel from denseBaResidual and
// denseBaDepthResidual (whose Jacobians dense_ba_test.cc checks against finite differences) and
// the priors (a level prior included),
// and solved / inverted densely; and the dense LLT and CHOLMOD paths agree.
#include "tracker/dense_ba.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "tests/tracker/ba_synthetic.h"
#include "tracker/dense_ba_kernel.h"

namespace radslam {
namespace {

using test::makeEdge;
using test::makeProblem;
using test::makeScene;
using test::richProblem;

// ---------------------------------------------------------------------------------------------
// Reference: the full (6F + M) normal equations, assembled pixel by pixel from denseBaResidual
// with a plain dense layout, damped the same way, solved densely.

struct FullSystem {
  Eigen::MatrixXd H;
  Eigen::VectorXd b;
  std::vector<int> pose_col;                // per keyframe, -1 if fixed
  std::vector<int> pose_dim;                // 6, or 5 for the scale-gauge keyframe
  std::vector<Eigen::MatrixXd> pose_basis;  // 6 x dim: delta = basis * a
  std::vector<std::vector<int>> depth_col;  // per keyframe and pixel, -1 if not a variable
};

FullSystem buildFullSystem(const DenseBaProblem& prob, const DenseBaOptions& opt, double lambda) {
  const CameraModel& cam = prob.camera;
  const int K = static_cast<int>(prob.keyframes.size());
  const int npix = cam.width * cam.height;
  FullSystem fs;
  fs.pose_col.assign(K, -1);
  fs.pose_dim.assign(K, 0);
  fs.pose_basis.resize(K);
  int n = 0;
  for (int k = 0; k < K; ++k) {
    bool fixed = prob.keyframes[k].fixed_pose;
    if (opt.gauge != DenseBaGauge::kFlaggedOnly && k == 0) fixed = true;
    if (opt.gauge == DenseBaGauge::kFirstTwoPoses && k == 1) fixed = true;
    if (fixed) continue;
    fs.pose_col[k] = n;
    if (opt.gauge == DenseBaGauge::kFirstPoseAndScale && k == 1) {
      // delta such that the centre moves orthogonally to the baseline: n^T v = 0.
      const Vec3 u = (prob.keyframes[1].T_world_cam.translation() -
                      prob.keyframes[0].T_world_cam.translation())
                         .normalized();
      Eigen::Matrix<double, 1, 6> row = Eigen::Matrix<double, 1, 6>::Zero();
      row.head<3>() = (prob.keyframes[1].T_world_cam.so3().inverse() * u).transpose();
      Eigen::FullPivLU<Eigen::MatrixXd> lu(row);
      fs.pose_basis[k] = lu.kernel();
      Eigen::HouseholderQR<Eigen::MatrixXd> qr(fs.pose_basis[k]);
      fs.pose_basis[k] = qr.householderQ() * Eigen::MatrixXd::Identity(6, 5);
    } else {
      fs.pose_basis[k] = Eigen::MatrixXd::Identity(6, 6);
    }
    fs.pose_dim[k] = static_cast<int>(fs.pose_basis[k].cols());
    n += fs.pose_dim[k];
  }
  const int n_pose = n;
  const int total = n_pose + K * npix;
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(total, total);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(total);
  auto dcol = [&](int k, int p) { return n_pose + k * npix + p; };
  int depth_residuals = 0;

  for (const DenseBaEdge& e : prob.edges) {
    const SE3& T_wi = prob.keyframes[e.i].T_world_cam;
    const SE3 T_wj = e.T_i_other ? T_wi * *e.T_i_other : prob.keyframes[e.j].T_world_cam;
    for (int v = 0; v < cam.height; ++v) {
      for (int u = 0; u < cam.width; ++u) {
        const cv::Vec2f t = e.target.at<cv::Vec2f>(v, u);
        Eigen::Matrix2d Wf;
        if (!flowInformation(e.weight.at<cv::Vec3f>(v, u), &Wf(0, 0), &Wf(0, 1), &Wf(1, 1))) {
          continue;
        }
        Wf(1, 0) = Wf(0, 1);
        const double d = prob.keyframes[e.i].inv_depth.at<float>(v, u);
        Eigen::Vector2d r, Hd;
        Mat26 Hi, Hj;
        if (!denseBaResidual(cam, T_wi, T_wj, u, v, d, Eigen::Vector2d(t[0], t[1]),
                             opt.min_depth_ratio, &r, &Hi, &Hj, &Hd)) {
          continue;
        }
        const double s2 = r.dot(Wf * r);
        double irls;
        dense_ba::huber(s2, opt.robust_scale, &irls);
        const Eigen::Matrix2d W = irls * Wf;
        Eigen::MatrixXd J = Eigen::MatrixXd::Zero(2, total);
        const int p = v * cam.width + u;
        J(0, dcol(e.i, p)) = Hd(0);
        J(1, dcol(e.i, p)) = Hd(1);
        if (!e.T_i_other) {
          if (fs.pose_col[e.i] >= 0) {
            J.middleCols(fs.pose_col[e.i], fs.pose_dim[e.i]) = Hi * fs.pose_basis[e.i];
          }
          if (fs.pose_col[e.j] >= 0) {
            J.middleCols(fs.pose_col[e.j], fs.pose_dim[e.j]) = Hj * fs.pose_basis[e.j];
          }
        } else {
          // The right camera moves with keyframe i: the pose Jacobians must cancel.
          const Mat26 total_pose = Hi + Hj * e.T_i_other->inverse().adjoint();
          EXPECT_LT(total_pose.norm(), 1e-9 * (1 + Hi.norm()));
        }
        H += J.transpose() * W * J;
        b -= J.transpose() * W * r;
        const DenseBaKeyframe& kj = prob.keyframes[e.j < 0 ? e.i : e.j];
        if (e.T_i_other || kj.measured_inv_depth.empty()) continue;
        double rz, wz, Hdz;
        Eigen::Matrix<double, 1, 6> Hiz, Hjz;
        if (!denseBaDepthResidual(cam, T_wi, T_wj, u, v, d, kj.measured_inv_depth,
                                  kj.measured_inv_depth_var, opt.min_depth_ratio,
                                  opt.depth_residual_max_jump, &rz, &wz, &Hiz, &Hjz, &Hdz)) {
          continue;
        }
        // The measurement's information is shared by its uses: its prior and the edges into it.
        int uses = kj.prior_inv_depth.empty() ? 0 : 1;
        for (const DenseBaEdge& other : prob.edges) uses += !other.T_i_other && other.j == e.j;
        wz /= uses;
        double irls_z;
        dense_ba::huber(wz * rz * rz, opt.robust_scale, &irls_z);
        Eigen::RowVectorXd Jz = Eigen::RowVectorXd::Zero(total);
        Jz(dcol(e.i, p)) = Hdz;
        if (fs.pose_col[e.i] >= 0) {
          Jz.segment(fs.pose_col[e.i], fs.pose_dim[e.i]) = Hiz * fs.pose_basis[e.i];
        }
        if (fs.pose_col[e.j] >= 0) {
          Jz.segment(fs.pose_col[e.j], fs.pose_dim[e.j]) = Hjz * fs.pose_basis[e.j];
        }
        H += irls_z * wz * Jz.transpose() * Jz;
        b -= irls_z * wz * rz * Jz.transpose();
        ++depth_residuals;
      }
    }
  }
  EXPECT_GT(depth_residuals, 10);
  for (int k = 0; k < K; ++k) {
    const DenseBaKeyframe& kf = prob.keyframes[k];
    if (kf.prior_inv_depth.empty()) continue;
    for (int p = 0; p < npix; ++p) {
      const double mu = kf.prior_inv_depth.at<float>(p), var = kf.prior_inv_depth_var.at<float>(p);
      if (!(var > 0) || !std::isfinite(mu)) continue;
      H(dcol(k, p), dcol(k, p)) += 1 / var;
      b(dcol(k, p)) += (mu - kf.inv_depth.at<float>(p)) / var;
    }
    // Level prior: (mean over the prior pixels of (mu - d))^2 / level_var.
    if (kf.prior_level_var > 0) {
      std::vector<int> pixels;
      double mean_residual = 0;
      for (int p = 0; p < npix; ++p) {
        const double mu = kf.prior_inv_depth.at<float>(p);
        if (!(kf.prior_inv_depth_var.at<float>(p) > 0) || !std::isfinite(mu)) continue;
        pixels.push_back(p);
        mean_residual += mu - kf.inv_depth.at<float>(p);
      }
      const double n_prior = static_cast<double>(pixels.size());
      mean_residual /= n_prior;
      const double alpha = 1 / kf.prior_level_var;
      for (int p : pixels) {
        b(dcol(k, p)) += alpha * mean_residual / n_prior;
        for (int q : pixels) H(dcol(k, p), dcol(k, q)) += alpha / (n_prior * n_prior);
      }
    }
  }
  // Keep the depths with information; damp as the optimiser does (Marquardt: poses floored,
  // the depth block, diagonal but for a level prior, by the factor 1 + lambda).
  std::vector<int> keep;
  for (int i = 0; i < n_pose; ++i) keep.push_back(i);
  fs.depth_col.assign(K, std::vector<int>(npix, -1));
  for (int k = 0; k < K; ++k) {
    for (int p = 0; p < npix; ++p) {
      if (H(dcol(k, p), dcol(k, p)) > 0) {
        fs.depth_col[k][p] = static_cast<int>(keep.size());
        keep.push_back(dcol(k, p));
      }
    }
  }
  const int m = static_cast<int>(keep.size());
  fs.H.resize(m, m);
  fs.b.resize(m);
  for (int a = 0; a < m; ++a) {
    fs.b(a) = b(keep[a]);
    for (int c = 0; c < m; ++c) {
      fs.H(a, c) = H(keep[a], keep[c]);
      if (a >= n_pose && c >= n_pose) fs.H(a, c) *= 1 + lambda;
    }
    if (a < n_pose) fs.H(a, a) += lambda * std::max(fs.H(a, a), opt.min_lm_diagonal);
  }
  return fs;
}

double relErr(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).norm() / std::max(b.norm(), 1e-300);
}

class DenseBaGaugeTest : public ::testing::TestWithParam<DenseBaGauge> {};

TEST_P(DenseBaGaugeTest, SchurStepEqualsDenseSolveOfTheFullSystem) {
  std::mt19937 rng(3);
  const DenseBaProblem prob = richProblem(&rng);
  DenseBaOptions opt;
  opt.gauge = GetParam();
  // Damping is compared on the unreduced coordinates, which the scale gauge rotates.
  const std::vector<double> lambdas = opt.gauge == DenseBaGauge::kFirstPoseAndScale
                                          ? std::vector<double>{0.0}
                                          : std::vector<double>{0.0, 1e-3, 10.0};
  for (double lambda : lambdas) {
    DenseBundleAdjuster ba(opt);
    DenseBaStep step;
    std::string error;
    ASSERT_TRUE(ba.computeStep(prob, lambda, &step, &error)) << error;
    const FullSystem fs = buildFullSystem(prob, opt, lambda);
    const Eigen::VectorXd x = fs.H.ldlt().solve(fs.b);
    Eigen::VectorXd ref(x.size() + 6 * 3), got(x.size() + 6 * 3);
    int n = 0;
    for (int k = 0; k < 3; ++k) {
      if (fs.pose_col[k] < 0) {
        EXPECT_EQ(step.dxi[k].norm(), 0.0);
        continue;
      }
      const Vec6 dref = fs.pose_basis[k] * x.segment(fs.pose_col[k], fs.pose_dim[k]);
      ref.segment<6>(n) = dref;
      got.segment<6>(n) = step.dxi[k];
      n += 6;
    }
    for (int k = 0; k < 3; ++k) {
      for (int p = 0; p < 48; ++p) {
        const int c = fs.depth_col[k][p];
        if (c < 0) {
          EXPECT_EQ(step.dd[k].at<double>(p), 0.0);
          continue;
        }
        ref(n) = x(c);
        got(n) = step.dd[k].at<double>(p);
        ++n;
      }
    }
    ASSERT_GT(n, 100);
    EXPECT_LT(relErr(got.head(n), ref.head(n)), 1e-8) << "lambda " << lambda;
  }
}

TEST_P(DenseBaGaugeTest, MarginalsEqualTheDenseInverseOfTheFullHessian) {
  std::mt19937 rng(4);
  const DenseBaProblem prob = richProblem(&rng);
  DenseBaOptions opt;
  opt.gauge = GetParam();
  const FullSystem fs = buildFullSystem(prob, opt, 0.0);
  const Eigen::MatrixXd Sigma = fs.H.inverse();
  for (auto method :
       {DenseBaOptions::DepthMarginal::kInverseBlocks, DenseBaOptions::DepthMarginal::kHalfSolve}) {
    opt.depth_marginal = method;
    DenseBundleAdjuster ba(opt);
    const DenseBaMarginals m = ba.computeMarginals(prob);
    ASSERT_TRUE(m.ok) << m.error;
    for (int k = 0; k < 3; ++k) {
      if (fs.pose_col[k] < 0) {
        EXPECT_EQ(m.pose_covariance[k].norm(), 0.0);
        continue;
      }
      const int c = fs.pose_col[k], n = fs.pose_dim[k];
      const Mat6 ref = fs.pose_basis[k] * Sigma.block(c, c, n, n) * fs.pose_basis[k].transpose();
      EXPECT_LT(relErr(m.pose_covariance[k], ref), 1e-8) << k;
    }
    int finite = 0;
    for (int k = 0; k < 3; ++k) {
      for (int p = 0; p < 48; ++p) {
        const int c = fs.depth_col[k][p];
        const float got = m.inv_depth_var[k].at<float>(p);
        if (c < 0) {
          EXPECT_TRUE(std::isinf(got));
          continue;
        }
        ++finite;
        EXPECT_NEAR(got, Sigma(c, c), 1e-6 * Sigma(c, c)) << k << " " << p;
        const double d = prob.keyframes[k].inv_depth.at<float>(p);
        EXPECT_NEAR(m.depth_var[k].at<float>(p), Sigma(c, c) / std::pow(d, 4),
                    1e-6 * Sigma(c, c) / std::pow(d, 4));
      }
    }
    EXPECT_GT(finite, 100);
  }
}

// The depth right-hand side is minus half the gradient of the cost (no 1/2 in the cost), the
// level prior's coupling of a keyframe's pixels included: central differences of evaluateCost.
TEST(DenseBa, DepthRhsIsMinusHalfTheCostGradient) {
  std::mt19937 rng(5);
  DenseBaProblem prob = richProblem(&rng);
  DenseBaOptions opt;
  DenseBundleAdjuster ba(opt);
  DenseBaStep step;
  std::string error;
  ASSERT_TRUE(ba.computeStep(prob, 0.0, &step, &error)) << error;
  int checked = 0;
  for (int k = 0; k < 3; ++k) {
    for (int p = 0; p < 48; ++p) {
      float& d = prob.keyframes[k].inv_depth.at<float>(p);
      const float d0 = d, h = 1e-3f * d0;
      d = d0 + h;
      const double up = ba.evaluateCost(prob);
      const double step_up = static_cast<double>(d) - d0;
      d = d0 - h;
      const double down = ba.evaluateCost(prob);
      const double step_down = d0 - static_cast<double>(d);
      d = d0;
      const double numeric = -0.5 * (up - down) / (step_up + step_down);
      const double analytic = step.depth_rhs[k].at<double>(p);
      EXPECT_NEAR(analytic, numeric, 1e-4 * (1 + std::abs(numeric))) << k << " " << p;
      ++checked;
    }
  }
  EXPECT_EQ(checked, 144);
}

INSTANTIATE_TEST_SUITE_P(Gauges, DenseBaGaugeTest,
                         ::testing::Values(DenseBaGauge::kFirstPose, DenseBaGauge::kFirstTwoPoses,
                                           DenseBaGauge::kFirstPoseAndScale));

TEST(DenseBa, DenseAndCholmodPathsAgree) {
  std::mt19937 rng(5);
  const test::SyntheticScene s = makeScene(6, 12, 9, 10.0, &rng, 0.3);
  DenseBaProblem prob = makeProblem(s, 0.0, &rng, 2);
  for (int k = 2; k < 6; ++k) test::perturbPose(&prob.keyframes[k].T_world_cam, 0.01, 0.02, &rng);
  DenseBaOptions opt;
  opt.solver.backend = ReducedCameraSolverOptions::Backend::kDense;
  DenseBundleAdjuster dense(opt);
  for (bool supernodal : {true, false}) {
    DenseBaOptions copt = opt;
    copt.solver.backend = ReducedCameraSolverOptions::Backend::kCholmod;
    copt.solver.cholmod_supernodal = supernodal;
    DenseBundleAdjuster sparse(copt);
    DenseBaStep a, b;
    ASSERT_TRUE(dense.computeStep(prob, 1e-4, &a));
    ASSERT_TRUE(sparse.computeStep(prob, 1e-4, &b));
    for (int k = 0; k < 6; ++k) {
      EXPECT_LT((a.dxi[k] - b.dxi[k]).norm(), 1e-10 * (1 + a.dxi[k].norm()));
      EXPECT_LT(cv::norm(a.dd[k], b.dd[k]), 1e-10 * (1 + cv::norm(a.dd[k])));
    }
    const DenseBaMarginals ma = dense.computeMarginals(prob), mb = sparse.computeMarginals(prob);
    ASSERT_TRUE(ma.ok && mb.ok);
    for (int k = 0; k < 6; ++k) {
      EXPECT_LT((ma.pose_covariance[k] - mb.pose_covariance[k]).norm(),
                1e-9 * (1e-30 + ma.pose_covariance[k].norm()) + 1e-300);
      EXPECT_LT(
          cv::norm(ma.inv_depth_var[k], mb.inv_depth_var[k], cv::NORM_RELATIVE | cv::NORM_INF),
          1e-6);
    }
    DenseBaProblem pa = prob, pb = prob;
    const DenseBaSummary sa = dense.optimize(&pa), sb = sparse.optimize(&pb);
    EXPECT_FALSE(sa.used_cholmod);
    EXPECT_TRUE(sb.used_cholmod);
    EXPECT_NEAR(sa.final_cost, sb.final_cost, 1e-9 * (1 + sa.final_cost));
  }
}

}  // namespace
}  // namespace radslam
