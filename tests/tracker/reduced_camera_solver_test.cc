// Reduced camera solver: dense LLT and CHOLMOD (supernodal, simplicial) agree on solves,
// inverses and half solves; failures are reported, not crashed on.
#include "tracker/reduced_camera_solver.h"

#include <gtest/gtest.h>

#include <random>

#include <Eigen/Dense>

namespace radslam {
namespace {

using Backend = ReducedCameraSolverOptions::Backend;

// A random SPD block matrix with the pattern of a pose graph: a chain plus random loop blocks.
BlockSymmetricMatrix randomPoseGraph(int n, int extra, std::mt19937* rng) {
  std::normal_distribution<double> N(0.0, 1.0);
  std::uniform_int_distribution<int> pick(0, n - 1);
  BlockSymmetricMatrix H(n);
  auto addEdge = [&](int a, int b) {
    // J^T J of a random 6 x 12 edge Jacobian: a PSD contribution to blocks aa, ab, bb.
    Eigen::Matrix<double, 6, 12> J;
    for (int r = 0; r < 6; ++r) {
      for (int c = 0; c < 12; ++c) J(r, c) = N(*rng);
    }
    const Eigen::Matrix<double, 12, 12> JtJ = J.transpose() * J;
    H.lower(a, a) += JtJ.block<6, 6>(0, 0);
    H.lower(b, b) += JtJ.block<6, 6>(6, 6);
    H.add(a, b, JtJ.block<6, 6>(0, 6));
  };
  for (int i = 0; i + 1 < n; ++i) addEdge(i, i + 1);
  for (int e = 0; e < extra; ++e) {
    const int a = pick(*rng), b = pick(*rng);
    if (a != b) addEdge(a, b);
  }
  for (int i = 0; i < n; ++i) H.lower(i, i) += 0.1 * Mat6::Identity();  // a weak prior
  return H;
}

TEST(BlockSymmetricMatrix, StoresTheLowerTriangleAndTransposes) {
  BlockSymmetricMatrix H(3);
  Mat6 M = Mat6::Zero();
  M(0, 1) = 2;
  H.add(0, 2, M);  // upper block: stored transposed at (2, 0)
  EXPECT_TRUE(H.hasBlock(2, 0));
  EXPECT_EQ(H.block(2, 0)(1, 0), 2);
  EXPECT_EQ(H.block(0, 2)(0, 1), 2);
  const Eigen::MatrixXd D = H.toDense();
  EXPECT_EQ(D(0, 13), 2);
  EXPECT_EQ(D(13, 0), 2);
  EXPECT_EQ(H.numStoredBlocks(), 1);
  EXPECT_THROW(H.lower(1, 2), std::out_of_range);
}

class SolverBackendTest : public ::testing::TestWithParam<int> {};

TEST_P(SolverBackendTest, DenseAndCholmodAgree) {
  const int n = GetParam();
  std::mt19937 rng(n);
  const BlockSymmetricMatrix H = randomPoseGraph(n, n / 2, &rng);
  const Eigen::MatrixXd A = H.toDense();
  const Eigen::MatrixXd B = Eigen::MatrixXd::Random(6 * n, 3);
  const Eigen::MatrixXd x_ref = A.ldlt().solve(B);
  const Eigen::MatrixXd inv_ref = A.inverse();

  ReducedCameraSolverOptions dense_opt;
  dense_opt.backend = Backend::kDense;
  ReducedCameraSolver dense(dense_opt);
  ASSERT_TRUE(dense.factorize(H)) << dense.error();
  EXPECT_FALSE(dense.usingCholmod());
  const Eigen::MatrixXd L = dense.denseFactorL();
  EXPECT_LT((L * L.transpose() - A).norm(), 1e-10 * A.norm());

  for (bool supernodal : {true, false}) {
    ReducedCameraSolverOptions opt;
    opt.backend = Backend::kCholmod;
    opt.cholmod_supernodal = supernodal;
    ReducedCameraSolver sparse(opt);
    ASSERT_TRUE(sparse.factorize(H)) << sparse.error();
    EXPECT_TRUE(sparse.usingCholmod());
    EXPECT_EQ(sparse.denseFactorL().size(), 0);
    for (const ReducedCameraSolver* s : {&dense, &sparse}) {
      EXPECT_LT((s->solve(B) - x_ref).norm(), 1e-9 * x_ref.norm());
      EXPECT_LT((s->inverse() - inv_ref).norm(), 1e-9 * inv_ref.norm());
      // ||L^-1 P b||^2 = b^T H^-1 b, column by column.
      const Eigen::VectorXd q = s->halfSolve(B).colwise().squaredNorm().transpose();
      const Eigen::VectorXd q_ref = (B.transpose() * x_ref).diagonal();
      EXPECT_LT((q - q_ref).norm(), 1e-9 * q_ref.norm());
    }
    // Refactorising a changed matrix with the same pattern reuses the analysis.
    BlockSymmetricMatrix H2 = H;
    H2.lower(0, 0) += Mat6::Identity();
    ASSERT_TRUE(sparse.factorize(H2));
    const Eigen::VectorXd b = B.col(0);
    EXPECT_LT((sparse.solve(b) - H2.toDense().ldlt().solve(b)).norm(), 1e-9 * b.norm());
  }
}

INSTANTIATE_TEST_SUITE_P(Sizes, SolverBackendTest, ::testing::Values(1, 5, 40));

TEST(ReducedCameraSolver, AutoBackendSwitchesAtTheThreshold) {
  std::mt19937 rng(3);
  ReducedCameraSolverOptions opt;
  opt.cholmod_min_blocks = 10;
  ReducedCameraSolver s(opt);
  ASSERT_TRUE(s.factorize(randomPoseGraph(9, 3, &rng)));
  EXPECT_FALSE(s.usingCholmod());
  ASSERT_TRUE(s.factorize(randomPoseGraph(10, 3, &rng)));
  EXPECT_TRUE(s.usingCholmod());
}

TEST(ReducedCameraSolver, ReportsIndefiniteAndEmptyMatrices) {
  for (Backend b : {Backend::kDense, Backend::kCholmod}) {
    ReducedCameraSolverOptions opt;
    opt.backend = b;
    ReducedCameraSolver s(opt);
    BlockSymmetricMatrix H(2);
    H.lower(0, 0) = Mat6::Identity();
    H.lower(1, 1) = Mat6::Identity();
    H.lower(1, 1)(3, 3) = -1;  // indefinite
    EXPECT_FALSE(s.factorize(H));
    EXPECT_NE(s.error().find("not positive definite"), std::string::npos) << s.error();
    EXPECT_THROW(s.solve(Eigen::VectorXd::Zero(12)), std::logic_error);
    EXPECT_FALSE(s.factorize(BlockSymmetricMatrix(0)));
    BlockSymmetricMatrix bad(1);
    bad.lower(0, 0) = Mat6::Identity();
    bad.lower(0, 0)(2, 2) = std::nan("");
    EXPECT_FALSE(s.factorize(bad));
    EXPECT_NE(s.error().find("non-finite"), std::string::npos) << s.error();
  }
}

}  // namespace
}  // namespace radslam
