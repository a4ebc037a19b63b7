// Internal to dense BA (tracker/dense_ba.cc): the linearised problem and its Schur-complement
// solve (dense_ba_system.cc), the marginal covariances (dense_ba_marginals.cc). Not part of the
// front end's API.
//
// Per edge e = (i -> j) the pose part is accumulated once in the frame of T_j_i (left
// perturbation xi, see dense_ba::reproject): A_e = sum J_xi^T W J_xi, g_e = sum J_xi^T W r.
// Since xi = Ad_e delta_i - delta_j (Ad_e = Ad(T_j_i)), the pose blocks are
//   C_ii += Ad^T A Ad, C_ij += -Ad^T A, C_jj += A, v_i += Ad^T g, v_j += -g,
// and per pixel the pose-depth column of E is e_p(i) = sum_e Ad_e^T b_e,p, e_p(j_e) = -b_e,p with
// b_e,p = J_xi^T W J_d. The b's of keyframe i are stored as the columns of B_i (6m x pixels, m =
// edges out of i), so that the Schur term of keyframe i is M_i (B_i P^-1 B_i^T) M_i^T with the
// small fixed map M_i (pose i: [Ad_1^T .. Ad_m^T]; pose j_e: -I in block e): one SYRK per
// keyframe instead of a 6m x 6m outer product per pixel.
//
// Damping: poses get diag(C) += lambda * max(diag(C), min_lm_diagonal); depths P <- (1 + lambda) P.
// The depth damping being a pure factor, the Schur term G = E P^-1 E^T of a linearisation
// becomes G / (1 + lambda): it is built once per linearisation, not once per trial lambda.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "tracker/dense_ba.h"
#include "tracker/dense_ba_kernel.h"

namespace radslam {

class DenseBundleAdjuster::System {
 public:
  /// Copies the state to double precision and sets up variables, gauge and edge structure.
  /// The problem must have been validated.
  void setup(const DenseBaProblem& problem, const DenseBaOptions& options);

  /// Robust cost at a state; also fills per-keyframe reprojection statistics when asked.
  double evaluate(const std::vector<SE3>& poses, const std::vector<Eigen::VectorXd>& depths,
                  std::vector<double>* mean_error_px = nullptr, int* num_residuals = nullptr);

  /// Linearises at the current state (poses_, depths_); returns the cost there.
  double linearize() { return linearizeInto(poses_, depths_, &lin_[cur_]); }
  /// Linearises at a candidate state into the spare buffers; returns its cost. The cost of a
  /// Levenberg-Marquardt trial point comes with its linearisation, which acceptCandidate() keeps.
  double linearizeCandidate(const std::vector<SE3>& poses,
                            const std::vector<Eigen::VectorXd>& depths) {
    return linearizeInto(poses, depths, &lin_[1 - cur_]);
  }
  /// Makes the candidate (state and linearisation) current; the arguments receive the old state.
  void acceptCandidate(std::vector<SE3>* poses, std::vector<Eigen::VectorXd>* depths);

  /// Damped step from the current linearisation. Returns false when the reduced system is not
  /// positive definite.
  bool solve(double lambda, std::vector<Vec6>* dxi, std::vector<Eigen::VectorXd>* dd);

  /// Marginals from the current linearisation (undamped).
  bool marginals(DenseBaMarginals* out);

  /// Applies a step: T <- T Exp(dxi) (plus the scale-gauge retraction), d <- clamp(d + dd).
  void retract(const std::vector<Vec6>& dxi, const std::vector<Eigen::VectorXd>& dd,
               std::vector<SE3>* poses, std::vector<Eigen::VectorXd>* depths) const;

  /// Of the current linearisation.
  double cost() const { return lin_[cur_].cost; }
  const std::vector<double>& meanErrorPx() const { return lin_[cur_].mean_error_px; }
  int numResiduals() const { return lin_[cur_].num_residuals; }
  std::vector<Vec6> poseRhs() const;
  const std::vector<Eigen::VectorXd>& depthRhs() const { return lin_[cur_].w; }
  const std::vector<Eigen::VectorXd>& depthHessian() const { return lin_[cur_].P; }
  bool usedCholmod() const { return solver_ && solver_->usingCholmod(); }
  const std::string& solverError() const { return solver_error_; }

  std::vector<SE3> poses_;
  std::vector<Eigen::VectorXd> depths_;

 private:
  struct Edge {
    int i = 0, j = -1;  // j = -1: fixed-relative (stereo) edge
    SE3 T_j_i_fixed;    // stereo only
    // Planar copies of target (u, v) and of the information matrix (W_uu, W_uv, W_vv) with
    // invalid entries (non-finite target, no information) set to 0; rows padded to
    // padded_width_ pixels.
    Eigen::ArrayXd tu, tv, wu, wuv, wv;
    int slot = -1;  // block row in B_i (non-stereo)
  };
  struct EdgeLin {
    Mat6 Ad = Mat6::Identity();  // Ad(T_j_i)
    Mat6 A = Mat6::Zero();
    Vec6 g = Vec6::Zero();
  };
  struct Linearization {
    std::vector<EdgeLin> edges;
    std::vector<Eigen::MatrixXd> B;     // per keyframe, 6m x pixels
    std::vector<Eigen::VectorXd> P, w;  // per keyframe, per pixel (P: the diagonal part)
    BlockSymmetricMatrix C;             // undamped pose Hessian (free poses)
    Eigen::VectorXd v;                  // pose right-hand side
    BlockSymmetricMatrix G;             // Schur term E P^-1 E^T (undamped P)
    Eigen::VectorXd h;                  // E P^-1 w
    Mat6 Q = Mat6::Identity();          // scale-gauge rotation at this state
    double cost = 0;
    std::vector<double> mean_error_px;
    int num_residuals = 0;
  };

  double linearizeInto(const std::vector<SE3>& poses, const std::vector<Eigen::VectorXd>& depths,
                       Linearization* lin);
  // Per-edge state of one keyframe pass.
  struct EdgeContext {
    SE3 T_j_i;
    Mat3 R;
    Vec3 t;
    Mat6 A;  // lower triangle accumulated
    Vec6 g;
    double* B;  // slot of the edge in B_i, null for stereo edges or cost-only passes
    // The target keyframe's measured inverse depth and variance (0: none), null for none.
    const double* measured = nullptr;
    const double* measured_var = nullptr;
  };
  /// Cost (and with kLinearize the linearisation) of all edges out of keyframe kf.
  template <bool kLinearize>
  double keyframePass(int kf, const std::vector<SE3>& poses,
                      const std::vector<Eigen::VectorXd>& depths, Linearization* lin,
                      double* sum_error, int* count);
  template <bool kLinearize>
  void rowPass(const Edge& e, EdgeContext* x, int v, Linearization* lin, double* cost, double* err,
               int* n);
  // The depth residual of one point of rowPass (iz = 0: not reprojected). With the pixel
  // Jacobian rows j0, j1 (null: cost only) accumulates into x, the row's P and w and the point's
  // column col of B_i.
  void depthTerm(EdgeContext* x, double iz, double xn, double yn, double d, const double* j0,
                 const double* j1, double jd0, double jd1, int u, double* col, double* cost);
  double priorPass(int k, const Eigen::VectorXd& d, Linearization* lin) const;
  Mat6 scaleGaugeRotation(const std::vector<SE3>& poses) const;
  void buildPoseSystem(Linearization* lin) const;
  void buildSchurTerm(Linearization* lin);
  /// H = C + lambda D - G / (1 + lambda), rhs = v - h / (1 + lambda), gauge pinned.
  void assembleReduced(const Linearization& lin, double lambda);
  // M_i: rows 6(m+1) (slot 0 = pose i, slot s = pose j of edge s-1), cols 6m.
  Eigen::MatrixXd slotMap(const Linearization& lin, int k) const;
  std::vector<int> slotVars(int k) const;

  DenseBaOptions options_;
  dense_ba::Pinhole<double> cam_{};
  int width_ = 0, height_ = 0, npix_ = 0;
  std::vector<double> xn_, yn_;  // normalised coordinates of grid columns (padded) / rows
  std::vector<Edge> edges_;
  std::vector<std::vector<int>> out_edges_;  // per keyframe: non-stereo edges, by slot
  std::vector<std::vector<int>> src_edges_;  // per keyframe: all edges out of it
  std::vector<int> var_;                     // keyframe -> pose variable, -1 if fixed
  int num_vars_ = 0;
  // Scale gauge (kFirstPoseAndScale): keyframe whose first rotated translation coordinate is
  // pinned (delta = Q a, a_0 = 0) and the held distance.
  int pinned_kf_ = -1;
  double scale_distance_ = 0;
  // Priors (omega = 1 / var, 0 for none). Level priors: alpha (u^T r)^2 with u = 1/N on the N
  // pixels with a prior (alpha = 0, u empty for none); the depth block is then
  // P = D + alpha u u^T, D the diagonal that Linearization::P holds.
  std::vector<Eigen::VectorXd> prior_mean_, prior_omega_;
  std::vector<double> level_alpha_;
  std::vector<Eigen::VectorXd> level_u_;
  // Measured inverse depth and its variance per keyframe (0 where none; empty for none).
  std::vector<std::vector<double>> measured_, measured_var_;
  /// Sherman-Morrison factor of keyframe k's depth block: P^-1 = D^-1 - beta q q^T, q = D^-1 u,
  /// beta = alpha / (1 + alpha u^T D^-1 u); 0 without a level prior.
  double levelBeta(const Linearization& lin, int k) const;
  Linearization lin_[2];
  int cur_ = 0;
  // Reduced system of the last solve.
  BlockSymmetricMatrix H_;
  Eigen::VectorXd rhs_;
  std::unique_ptr<ReducedCameraSolver> solver_;
  ReducedCameraSolverOptions solver_options_;
  std::string solver_error_;
  Eigen::MatrixXd Bt_;  // scratch: B scaled by P^-1/2
  // Row staging of keyframePass, padded to a multiple of kBlock pixels: inverse depths and the
  // row's P and w accumulated over the keyframe's edges.
  static constexpr int kBlock = 16;
  int padded_width_ = 0;
  std::vector<double> d_row_, P_row_, w_row_;
  std::vector<EdgeContext> ctx_;
};

}  // namespace radslam
