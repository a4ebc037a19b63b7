// The reduced camera system of bundle adjustment: a symmetric positive definite matrix made of
// 6x6 blocks (one block row per free camera pose), stored block-sparse, and its Cholesky solver.
//
// Two back ends give the same answers (to rounding):
//  - dense: Eigen::LLT on the assembled n x n matrix; best for the local window (<= ~32 poses);
//  - CHOLMOD: sparse supernodal/simplicial Cholesky with a fill-reducing ordering, for the
//    larger, sparser graphs of global and dynamic BA.
// Besides solves, the solver provides what exact marginal covariances need: the full inverse
// H^-1 (or any of its columns) and the "half solve" y = L^-1 P b, whose squared norm is
// b^T H^-1 b (H = P^T L L^T P, P the fill-reducing permutation; identity on the dense path).
#pragma once

#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "common/lie.h"

namespace radslam {

/// Symmetric matrix of 6x6 blocks; only blocks (r, c) with r >= c are stored.
class BlockSymmetricMatrix {
 public:
  explicit BlockSymmetricMatrix(int num_blocks = 0) { reset(num_blocks); }

  /// Drops all blocks and sets the size (num_blocks block rows, 6 * num_blocks rows).
  void reset(int num_blocks);
  int numBlocks() const { return static_cast<int>(columns_.size()); }
  int dim() const { return 6 * numBlocks(); }

  /// Adds M to block (r, c) (and so M^T to block (c, r)). For r == c the caller passes the
  /// contribution of the symmetric matrix; only its lower triangle is read by the solvers.
  void add(int r, int c, const Mat6& M);
  /// Block (r, c), r >= c, created as zero if absent.
  Mat6& lower(int r, int c);
  /// Block (r, c) for any r, c (transposed when r < c); zero if absent.
  Mat6 block(int r, int c) const;
  bool hasBlock(int r, int c) const;

  /// Stored blocks of block column c: (row, block) with row >= c, sorted by row.
  const std::map<int, Mat6>& column(int c) const { return columns_[c]; }
  int numStoredBlocks() const;

  /// Dense symmetric n x n copy (both triangles filled).
  Eigen::MatrixXd toDense() const;

 private:
  std::vector<std::map<int, Mat6>> columns_;
};

struct ReducedCameraSolverOptions {
  enum class Backend { kAuto, kDense, kCholmod };
  /// kAuto: dense below cholmod_min_blocks block rows, CHOLMOD from there on.
  Backend backend = Backend::kAuto;
  int cholmod_min_blocks = 32;
  /// CHOLMOD only: true = supernodal, false = simplicial (both leave an LL^T factor).
  bool cholmod_supernodal = true;
};

/// Cholesky factorisation of a BlockSymmetricMatrix and the solves built on it.
/// Typical use: factorize(H) once, then solve(b), and for marginals inverse() or halfSolve().
/// Not copyable (owns CHOLMOD state). Not thread-safe.
class ReducedCameraSolver {
 public:
  explicit ReducedCameraSolver(const ReducedCameraSolverOptions& options = {});
  ~ReducedCameraSolver();
  ReducedCameraSolver(const ReducedCameraSolver&) = delete;
  ReducedCameraSolver& operator=(const ReducedCameraSolver&) = delete;

  /// Factorises H = L L^T (after a fill-reducing permutation on the CHOLMOD path). Returns
  /// false when H is empty-sized, not positive definite or not finite; error() says why.
  bool factorize(const BlockSymmetricMatrix& H);

  /// True after a successful factorize().
  bool factorized() const { return factorized_; }
  /// True when the last factorize() used CHOLMOD.
  bool usingCholmod() const { return using_cholmod_; }
  int dim() const { return dim_; }
  const std::string& error() const { return error_; }

  /// x = H^-1 b (b: dim() rows, any number of columns; a VectorXd converts implicitly).
  Eigen::MatrixXd solve(const Eigen::MatrixXd& b) const;
  /// The full inverse H^-1 (dim x dim), exact up to rounding; cached until the next factorize().
  const Eigen::MatrixXd& inverse() const;
  /// y = L^-1 P b, so that ||y||^2 = b^T H^-1 b (columns independently).
  Eigen::MatrixXd halfSolve(const Eigen::MatrixXd& b) const;
  /// Dense path only: the lower Cholesky factor L of H (P = identity). Empty on the CHOLMOD path.
  Eigen::MatrixXd denseFactorL() const;

 private:
  struct Cholmod;
  bool factorizeDense(const BlockSymmetricMatrix& H);
  bool factorizeCholmod(const BlockSymmetricMatrix& H);

  ReducedCameraSolverOptions options_;
  bool factorized_ = false;
  bool using_cholmod_ = false;
  int dim_ = 0;
  std::string error_;
  Eigen::MatrixXd dense_L_;  // lower factor (dense path)
  std::unique_ptr<Cholmod> cholmod_;
  mutable bool inverse_valid_ = false;
  mutable Eigen::MatrixXd inverse_;
};

}  // namespace radslam
