// Marginal covariances of dense BA at the current linearisation (DESIGN.md section 3):
// Sigma_T = H_T^-1 and, per pixel, Sigma_d = 1/P + e^T H_T^-1 e / P^2 (the diagonal of the full
// inverse; e = the pixel's column of E), by inverse blocks or by half solves ||L^-1 P e||^2.
// With a level prior (P = D + alpha u u^T, P^-1 = D^-1 - beta q q^T, q = D^-1 u) the pixel's
// column of E P^-1 is (e - beta u_p E q) / D_p and (P^-1)_pp = 1/D_p - beta q_p^2.
#include <algorithm>
#include <limits>

#include <Eigen/Cholesky>

#include "tracker/dense_ba_system.h"

namespace radslam {

bool DenseBundleAdjuster::System::marginals(DenseBaMarginals* out) {
  const int K = static_cast<int>(poses_.size());
  const Linearization& lin = lin_[cur_];
  out->ok = false;
  out->error.clear();
  assembleReduced(lin, 0.0);
  const bool pinned = pinned_kf_ >= 0 && var_[pinned_kf_] >= 0;
  Eigen::MatrixXd Sigma;  // in delta coordinates, 6 * num_vars_ square
  if (num_vars_ > 0) {
    if (!solver_->factorize(H_)) {
      out->error = "marginals: " + solver_->error();
      return false;
    }
    Sigma = solver_->inverse();
    if (pinned) {
      const int r = 6 * var_[pinned_kf_];
      Sigma.row(r).setZero();
      Sigma.col(r).setZero();
      Sigma.middleRows(r, 6) = (lin.Q * Sigma.middleRows(r, 6)).eval();
      Sigma.middleCols(r, 6) = (Sigma.middleCols(r, 6) * lin.Q.transpose()).eval();
    }
  }
  out->pose_covariance.assign(K, Mat6::Zero());
  for (int k = 0; k < K; ++k) {
    if (var_[k] >= 0) out->pose_covariance[k] = Sigma.block<6, 6>(6 * var_[k], 6 * var_[k]);
  }

  out->inv_depth_var.resize(K);
  out->depth_var.resize(K);
  for (int k = 0; k < K; ++k) {
    const int m = static_cast<int>(out_edges_[k].size());
    const std::vector<int> vars = slotVars(k);
    const Eigen::VectorXd& P = lin.P[k];
    const double beta = levelBeta(lin, k);
    // With a level prior the columns of B become those of B D P^-1 (pose slots of E P^-1 D).
    Eigen::MatrixXd B_level;
    Eigen::VectorXd q;
    if (beta > 0) {
      q = (level_u_[k].array() / P.array().max(1e-300)).matrix();
      B_level = lin.B[k];
      B_level.noalias() -= beta * (lin.B[k] * q) * level_u_[k].transpose();
    }
    const Eigen::MatrixXd& B = beta > 0 ? B_level : lin.B[k];
    // quad(p) = e_p^T H_T^-1 e_p.
    Eigen::VectorXd quad = Eigen::VectorXd::Zero(npix_);
    const bool any_free = std::any_of(vars.begin(), vars.end(), [](int v) { return v >= 0; });
    if (m > 0 && any_free) {
      const Eigen::MatrixXd M = slotMap(lin, k);
      if (options_.depth_marginal == DenseBaOptions::DepthMarginal::kInverseBlocks) {
        Eigen::MatrixXd S_loc = Eigen::MatrixXd::Zero(6 * (m + 1), 6 * (m + 1));
        for (int a = 0; a <= m; ++a) {
          for (int b = 0; b <= m; ++b) {
            if (vars[a] >= 0 && vars[b] >= 0) {
              S_loc.block<6, 6>(6 * a, 6 * b) = Sigma.block<6, 6>(6 * vars[a], 6 * vars[b]);
            }
          }
        }
        // K = M^T Sigma_loc M is positive semidefinite: with K = L D L^T (pivoted),
        // quad = sum_i D_i (L^T P B)_i^2 costs half of B^T K B.
        const Eigen::MatrixXd Kq = M.transpose() * S_loc * M;
        const Eigen::LDLT<Eigen::MatrixXd> ldlt(Kq);
        const Eigen::MatrixXd Z =
            ldlt.matrixU() * (ldlt.transpositionsP() * B);  // U = L^T, unit upper
        quad = (Z.array().square().colwise() * ldlt.vectorD().array()).colwise().sum().transpose();
      } else {
        // ||L^-1 P e||^2 with e in the solver's coordinates (Q^T applied, pinned row zero).
        Eigen::MatrixXd Mg = Eigen::MatrixXd::Zero(6 * num_vars_, 6 * m);
        for (int a = 0; a <= m; ++a) {
          if (vars[a] >= 0) Mg.middleRows(6 * vars[a], 6) += M.middleRows(6 * a, 6);
        }
        if (pinned) {
          const int r = 6 * var_[pinned_kf_];
          Mg.middleRows(r, 6) = (lin.Q.transpose() * Mg.middleRows(r, 6)).eval();
          Mg.row(r).setZero();
        }
        const Eigen::MatrixXd Y = solver_->halfSolve(Mg * B);
        quad = Y.colwise().squaredNorm().transpose();
      }
    }
    cv::Mat var_d(height_, width_, CV_32FC1), var_z(height_, width_, CV_32FC1);
    float* vd = var_d.ptr<float>();
    float* vz = var_z.ptr<float>();
    for (int p = 0; p < npix_; ++p) {
      if (P(p) > 0) {
        double s = 1.0 / P(p) + quad(p) / (P(p) * P(p));
        if (beta > 0) s -= beta * q(p) * q(p);
        const double d = depths_[k](p);
        vd[p] = static_cast<float>(s);
        vz[p] = static_cast<float>(s / (d * d * d * d));
      } else {
        vd[p] = vz[p] = std::numeric_limits<float>::infinity();
      }
    }
    out->inv_depth_var[k] = var_d;
    out->depth_var[k] = var_z;
  }
  out->ok = true;
  return true;
}

}  // namespace radslam
