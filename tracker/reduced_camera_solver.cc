#include "tracker/reduced_camera_solver.h"

#include <cholmod.h>

#include <cmath>
#include <stdexcept>

#include <Eigen/Cholesky>

namespace radslam {

// ---------------------------------------------------------------------------------------------
// BlockSymmetricMatrix

void BlockSymmetricMatrix::reset(int num_blocks) {
  if (num_blocks < 0) throw std::invalid_argument("BlockSymmetricMatrix: negative size");
  columns_.assign(num_blocks, {});
}

void BlockSymmetricMatrix::add(int r, int c, const Mat6& M) {
  if (r >= c) {
    lower(r, c) += M;
  } else {
    lower(c, r) += M.transpose();
  }
}

Mat6& BlockSymmetricMatrix::lower(int r, int c) {
  if (c < 0 || r < c || r >= numBlocks()) {
    throw std::out_of_range("BlockSymmetricMatrix: block (" + std::to_string(r) + ", " +
                            std::to_string(c) + ") outside the lower triangle of " +
                            std::to_string(numBlocks()) + " blocks");
  }
  auto it = columns_[c].find(r);
  if (it == columns_[c].end()) it = columns_[c].emplace(r, Mat6::Zero()).first;
  return it->second;
}

Mat6 BlockSymmetricMatrix::block(int r, int c) const {
  if (r < c) return block(c, r).transpose();
  const auto& col = columns_.at(c);
  const auto it = col.find(r);
  return it == col.end() ? Mat6::Zero() : it->second;
}

bool BlockSymmetricMatrix::hasBlock(int r, int c) const {
  if (r < c) std::swap(r, c);
  return columns_.at(c).count(r) > 0;
}

int BlockSymmetricMatrix::numStoredBlocks() const {
  int n = 0;
  for (const auto& col : columns_) n += static_cast<int>(col.size());
  return n;
}

Eigen::MatrixXd BlockSymmetricMatrix::toDense() const {
  const int n = dim();
  Eigen::MatrixXd D = Eigen::MatrixXd::Zero(n, n);
  for (int c = 0; c < numBlocks(); ++c) {
    for (const auto& [r, M] : columns_[c]) {
      if (r == c) {
        // Only the lower triangle of a diagonal block is authoritative.
        for (int a = 0; a < 6; ++a) {
          for (int b = 0; b <= a; ++b) {
            D(6 * r + a, 6 * c + b) = M(a, b);
            D(6 * c + b, 6 * r + a) = M(a, b);
          }
        }
      } else {
        D.block<6, 6>(6 * r, 6 * c) = M;
        D.block<6, 6>(6 * c, 6 * r) = M.transpose();
      }
    }
  }
  return D;
}

// ---------------------------------------------------------------------------------------------
// CHOLMOD state

struct ReducedCameraSolver::Cholmod {
  cholmod_common common;
  cholmod_factor* factor = nullptr;
  // Block pattern of the analysed matrix: the symbolic analysis is reused while it is unchanged.
  std::vector<std::pair<int, int>> pattern;
  bool supernodal = true;

  explicit Cholmod(bool use_supernodal) : supernodal(use_supernodal) {
    cholmod_start(&common);
    common.supernodal = use_supernodal ? CHOLMOD_SUPERNODAL : CHOLMOD_SIMPLICIAL;
    common.final_ll = 1;  // keep L L^T so that CHOLMOD_L solves give the half solve
    common.print = 0;
    common.error_handler = nullptr;
  }
  ~Cholmod() {
    if (factor) cholmod_free_factor(&factor, &common);
    cholmod_finish(&common);
  }

  // Wraps an Eigen column-major matrix as a cholmod_dense without copying.
  static cholmod_dense view(const Eigen::MatrixXd& m) {
    cholmod_dense d{};
    d.nrow = static_cast<size_t>(m.rows());
    d.ncol = static_cast<size_t>(m.cols());
    d.nzmax = d.nrow * d.ncol;
    d.d = d.nrow;
    d.x = const_cast<double*>(m.data());
    d.z = nullptr;
    d.xtype = CHOLMOD_REAL;
    d.dtype = CHOLMOD_DOUBLE;
    return d;
  }

  Eigen::MatrixXd solve(int sys, const Eigen::MatrixXd& b) {
    cholmod_dense bd = view(b);
    cholmod_dense* x = cholmod_solve(sys, factor, &bd, &common);
    if (!x) throw std::runtime_error("ReducedCameraSolver: cholmod_solve failed");
    Eigen::MatrixXd out =
        Eigen::Map<const Eigen::MatrixXd>(static_cast<const double*>(x->x), b.rows(), b.cols());
    cholmod_free_dense(&x, &common);
    return out;
  }
};

// ---------------------------------------------------------------------------------------------
// ReducedCameraSolver

ReducedCameraSolver::ReducedCameraSolver(const ReducedCameraSolverOptions& options)
    : options_(options) {}

ReducedCameraSolver::~ReducedCameraSolver() = default;

bool ReducedCameraSolver::factorize(const BlockSymmetricMatrix& H) {
  factorized_ = false;
  inverse_valid_ = false;
  error_.clear();
  dim_ = H.dim();
  if (dim_ == 0) {
    error_ = "reduced camera system is empty (no free pose)";
    return false;
  }
  using Backend = ReducedCameraSolverOptions::Backend;
  using_cholmod_ =
      options_.backend == Backend::kCholmod ||
      (options_.backend == Backend::kAuto && H.numBlocks() >= options_.cholmod_min_blocks);
  factorized_ = using_cholmod_ ? factorizeCholmod(H) : factorizeDense(H);
  return factorized_;
}

bool ReducedCameraSolver::factorizeDense(const BlockSymmetricMatrix& H) {
  const Eigen::MatrixXd A = H.toDense();
  if (!A.allFinite()) {
    error_ = "reduced camera matrix has non-finite entries";
    return false;
  }
  Eigen::LLT<Eigen::MatrixXd> llt(A);
  if (llt.info() != Eigen::Success) {
    error_ =
        "reduced camera matrix is not positive definite (dense LLT failed; is the gauge "
        "fixed?)";
    return false;
  }
  dense_L_ = llt.matrixL();
  return true;
}

bool ReducedCameraSolver::factorizeCholmod(const BlockSymmetricMatrix& H) {
  if (!cholmod_ || cholmod_->supernodal != options_.cholmod_supernodal) {
    cholmod_ = std::make_unique<Cholmod>(options_.cholmod_supernodal);
  }
  Cholmod& cm = *cholmod_;
  const int nb = H.numBlocks();
  const int n = H.dim();

  // Lower triangle in compressed columns (stype = -1), rows sorted within each column.
  std::vector<std::pair<int, int>> pattern;
  size_t nnz = 0;
  for (int c = 0; c < nb; ++c) {
    for (const auto& entry : H.column(c)) {
      pattern.emplace_back(entry.first, c);
      nnz += entry.first == c ? 21 : 36;
    }
  }
  cholmod_sparse* A = cholmod_allocate_sparse(n, n, nnz, /*sorted=*/1, /*packed=*/1, /*stype=*/-1,
                                              CHOLMOD_REAL, &cm.common);
  if (!A) {
    error_ = "cholmod_allocate_sparse failed";
    return false;
  }
  auto* Ap = static_cast<int*>(A->p);
  auto* Ai = static_cast<int*>(A->i);
  auto* Ax = static_cast<double*>(A->x);
  int k = 0;
  bool finite = true;
  for (int c = 0; c < nb; ++c) {
    const auto& col = H.column(c);
    for (int cc = 0; cc < 6; ++cc) {
      Ap[6 * c + cc] = k;
      for (const auto& [r, M] : col) {
        const int first = r == c ? cc : 0;  // lower triangle of diagonal blocks
        for (int rr = first; rr < 6; ++rr) {
          Ai[k] = 6 * r + rr;
          Ax[k] = M(rr, cc);
          finite = finite && std::isfinite(Ax[k]);
          ++k;
        }
      }
    }
  }
  Ap[n] = k;
  if (!finite) {
    cholmod_free_sparse(&A, &cm.common);
    error_ = "reduced camera matrix has non-finite entries";
    return false;
  }

  if (!cm.factor || pattern != cm.pattern) {
    if (cm.factor) cholmod_free_factor(&cm.factor, &cm.common);
    cm.factor = cholmod_analyze(A, &cm.common);
    cm.pattern = std::move(pattern);
    if (!cm.factor) {
      cholmod_free_sparse(&A, &cm.common);
      error_ = "cholmod_analyze failed (status " + std::to_string(cm.common.status) + ")";
      return false;
    }
  }
  const int ok = cholmod_factorize(A, cm.factor, &cm.common);
  cholmod_free_sparse(&A, &cm.common);
  if (!ok || cm.common.status == CHOLMOD_NOT_POSDEF || cm.factor->minor < static_cast<size_t>(n)) {
    error_ = "reduced camera matrix is not positive definite (CHOLMOD failed at column " +
             std::to_string(cm.factor->minor) + " of " + std::to_string(n) +
             "; is the gauge fixed?)";
    // The pattern stays analysed; a failed numeric factor is simply overwritten next time.
    return false;
  }
  return true;
}

Eigen::MatrixXd ReducedCameraSolver::solve(const Eigen::MatrixXd& b) const {
  if (!factorized_) throw std::logic_error("ReducedCameraSolver::solve before factorize");
  if (b.rows() != dim_) throw std::invalid_argument("ReducedCameraSolver::solve: wrong size");
  if (using_cholmod_) return cholmod_->solve(CHOLMOD_A, b);
  const auto L = dense_L_.triangularView<Eigen::Lower>();
  return L.transpose().solve(L.solve(b));
}

const Eigen::MatrixXd& ReducedCameraSolver::inverse() const {
  if (!inverse_valid_) {
    inverse_ = solve(Eigen::MatrixXd(Eigen::MatrixXd::Identity(dim_, dim_)));
    // Symmetrise away rounding so callers can rely on exact symmetry.
    inverse_ = 0.5 * (inverse_ + inverse_.transpose()).eval();
    inverse_valid_ = true;
  }
  return inverse_;
}

Eigen::MatrixXd ReducedCameraSolver::halfSolve(const Eigen::MatrixXd& b) const {
  if (!factorized_) throw std::logic_error("ReducedCameraSolver::halfSolve before factorize");
  if (b.rows() != dim_) throw std::invalid_argument("ReducedCameraSolver::halfSolve: wrong size");
  if (using_cholmod_) return cholmod_->solve(CHOLMOD_L, cholmod_->solve(CHOLMOD_P, b));
  return dense_L_.triangularView<Eigen::Lower>().solve(b);
}

Eigen::MatrixXd ReducedCameraSolver::denseFactorL() const {
  return using_cholmod_ ? Eigen::MatrixXd() : dense_L_;
}

}  // namespace radslam
