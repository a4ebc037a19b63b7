#include "tracker/object_window_ba.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Dense>

#include "common/camera.h"

namespace radslam {

namespace {

// The displacements E_m = Exp(A theta_m) of a window and J_l(A theta_m) A, shared by every
// point's chained-motion Jacobian.
struct Displacements {
  std::vector<SE3> E;
  std::vector<Eigen::Matrix<double, 6, Eigen::Dynamic, 0, 6, 6>> JlA;

  Displacements(const JointBasis& A, const std::vector<JointVector>& theta) {
    for (const JointVector& t : theta) {
      const Vec6 xi = A * t;
      E.push_back(SE3::exp(xi));
      JlA.push_back(SE3::leftJacobian(xi) * A);
    }
  }

  // Writes columns m*k .. m*k+k-1 of J (3 rows, at least f k columns) for from <= m < f only;
  // returns E_{f-1} ... E_from q.
  Vec3 chain(int from, int f, const Vec3& q, Eigen::MatrixXd* J) const {
    const int k = JlA.empty() ? 0 : static_cast<int>(JlA[0].cols());
    // before[m] = E_{m-1} ... E_from applied to q (the point just before displacement m);
    // after = E_{f-1} ... E_{m+1}.
    Vec3 before[64];
    before[from] = q;
    for (int m = from; m < f; ++m) before[m + 1] = E[m] * before[m];
    Mat3 after = Mat3::Identity();
    for (int m = f - 1; m >= from; --m) {
      const Vec3& p = before[m + 1];  // E_m applied to before[m]
      // Exp(A (theta + d)) ~= Exp(J_l A d) Exp(A theta); d(Exp(e) p)/de = [I, -hat(p)].
      Mat36 H_e;
      H_e << Mat3::Identity(), -hat(p);
      J->middleCols(m * k, k).noalias() = after * H_e * JlA[m];
      after = after * E[m].rotation();
    }
    return before[f];
  }
};

constexpr int kMaxWindowFrames = 63;  // Displacements::chain keeps the chain on the stack

}  // namespace

Eigen::MatrixXd chainedMotionJacobian(const JointBasis& A, const std::vector<JointVector>& theta,
                                      int f, const Vec3& q, Vec3* moved, int from) {
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(3, f * A.cols());
  const Vec3 p = Displacements(A, theta).chain(from, f, q, &J);
  if (moved) *moved = p;
  return J;
}

namespace {

void checkProblem(const ObjectWindowProblem& p, const std::vector<JointVector>* initial) {
  validateCamera(p.camera);
  const int n = static_cast<int>(p.T_world_cam.size());
  if (n < 2 || n > kMaxWindowFrames)
    throw std::invalid_argument("solveObjectWindow: need 2.." + std::to_string(kMaxWindowFrames) +
                                " frames");
  if (!(p.dt > 0)) throw std::invalid_argument("solveObjectWindow: dt must be > 0 s");
  for (const SE3& T : p.T_world_cam)
    if (!T.matrix().allFinite()) throw std::invalid_argument("solveObjectWindow: bad camera pose");
  for (const Vec3& pt : p.points_cam0)
    if (!pt.allFinite() || !(pt.z() > 0))
      throw std::invalid_argument("solveObjectWindow: points must be finite with z > 0");
  if (!p.anchor_frame.empty() && p.anchor_frame.size() != p.points_cam0.size())
    throw std::invalid_argument("solveObjectWindow: anchor_frame needs one frame per point");
  for (const int a : p.anchor_frame)
    if (a < 0 || a > n - 2)
      throw std::invalid_argument("solveObjectWindow: anchor frame " + std::to_string(a) +
                                  " outside 0.." + std::to_string(n - 2));
  for (const ObjectObservation& o : p.observations) {
    if (o.landmark < 0 || o.landmark >= static_cast<int>(p.points_cam0.size()))
      throw std::invalid_argument("solveObjectWindow: observation of unknown landmark " +
                                  std::to_string(o.landmark));
    const int anchor = p.anchor_frame.empty() ? 0 : p.anchor_frame[o.landmark];
    if (o.frame <= anchor || o.frame >= n)
      throw std::invalid_argument("solveObjectWindow: observation in frame " +
                                  std::to_string(o.frame) + " outside " +
                                  std::to_string(anchor + 1) + ".." + std::to_string(n - 1));
    if (!o.px.allFinite()) throw std::invalid_argument("solveObjectWindow: non-finite pixel");
  }
  if (initial) {
    if (static_cast<int>(initial->size()) != n - 1)
      throw std::invalid_argument("solveObjectWindow: initial needs N-1 displacements");
    for (const JointVector& t : *initial)
      if (t.size() != p.joint.dof() || !t.allFinite())
        throw std::invalid_argument("solveObjectWindow: initial displacement of wrong size");
  }
}

struct State {
  std::vector<JointVector> theta;
  std::vector<Vec3> points;  // camera 0 frame
};

// The normal equations with the points kept in 3 x 3 blocks, for the Schur complement.
struct System {
  Eigen::MatrixXd H_tt;  // K x K
  Eigen::VectorXd g_t;
  std::vector<Mat3> H_pp;
  std::vector<Eigen::Matrix<double, Eigen::Dynamic, 3>> H_tp;  // K x 3 per point
  std::vector<Vec3> g_p;
};

class WindowSolver {
 public:
  WindowSolver(const ObjectWindowProblem& p, const ObjectWindowParams& params)
      : p_(p), params_(params), k_(p.joint.dof()), n_(static_cast<int>(p.T_world_cam.size())) {
    K_ = k_ * (n_ - 1);
    for (int f = 0; f < n_; ++f) {
      T_joint_cam_.push_back(p.joint.T_world_joint().inverse() * p.T_world_cam[f]);
      T_cam_joint_.push_back(T_joint_cam_.back().inverse());
    }
    // Per joint coordinate: translation or rotation, for the constant-velocity weights.
    cv_weight_.resize(k_);
    for (int c = 0; c < k_; ++c) {
      const double s = p.joint.basis().col(c).head<3>().norm() > 0 ? params.cv_sigma_translation
                                                                   : params.cv_sigma_rotation;
      cv_weight_(c) = 1.0 / (s * s);
    }
    // A depth pixel's point is uncertain along its ray (depth noise); across the ray only by
    // lateral_sigma_px, since the pixel itself is exact.
    for (const Vec3& pt : p.points_cam0) {
      const Vec3 ray = pt / pt.z();
      const double sz = params.depth_sigma_rel * pt.z() * pt.z();         // m
      const double lat = params.lateral_sigma_px * pt.z() / p.camera.fx;  // m
      const Mat3 cov = sz * sz * ray * ray.transpose() + lat * lat * Mat3::Identity();
      prior_weight_.push_back(cov.inverse());
    }
  }

  // Robust cost at `s`; fills `sys` (if given) with the Gauss-Newton normal equations.
  double evaluate(const State& s, System* sys, int* inliers = nullptr,
                  double* inlier_sq = nullptr) {
    const int L = static_cast<int>(s.points.size());
    if (sys) {
      sys->H_tt.setZero(K_, K_);
      sys->g_t.setZero(K_);
      sys->H_pp.assign(L, Mat3::Zero());
      sys->H_tp.assign(params_.optimise_points ? L : 0,
                       Eigen::Matrix<double, Eigen::Dynamic, 3>::Zero(K_, 3));
      sys->g_p.assign(L, Vec3::Zero());
    }
    if (inliers) *inliers = 0;
    if (inlier_sq) *inlier_sq = 0;
    double cost = 0;
    const double inv_var = 1.0 / (params_.pixel_sigma * params_.pixel_sigma);
    // Chained displacements M_f = Exp(A theta_{f-1}) ... Exp(A theta_0), joint frame; a point
    // anchored in frame a moves by M_f M_a^-1.
    const Displacements D(p_.joint.basis(), s.theta);
    std::vector<SE3> M(n_);
    for (int f = 1; f < n_; ++f) M[f] = D.E[f - 1] * M[f - 1];
    Eigen::MatrixXd J_chain(3, K_), J_t(2, K_);
    for (const ObjectObservation& o : p_.observations) {
      const int a = anchor(o.landmark);
      const Vec3 q = T_joint_cam_[a] * s.points[o.landmark];
      const SE3 M_fa = M[o.frame] * M[a].inverse();
      const Vec3 moved = M_fa * q;
      const SE3& T_cam_joint = T_cam_joint_[o.frame];
      const Vec3 pc = T_cam_joint * moved;
      if (!(pc.z() > 1e-6)) continue;
      Eigen::Matrix<double, 2, 3> H_pc;
      const Eigen::Vector2d r = project(p_.camera, pc, &H_pc) - o.px;
      const double e = r.norm();
      const double h = params_.huber_px;
      const double w = (e <= h ? 1.0 : h / e) * inv_var;
      cost += inv_var * (e <= h ? 0.5 * e * e : h * (e - 0.5 * h));
      if (e <= h) {
        if (inliers) ++*inliers;
        if (inlier_sq) *inlier_sq += e * e;
      }
      if (!sys) continue;
      const Eigen::Matrix<double, 2, 3> H_q = H_pc * T_cam_joint.rotation();
      // Only the displacements a .. frame-1 move the point: columns a k .. frame k.
      const int first = a * k_, cols = (o.frame - a) * k_;
      D.chain(a, o.frame, q, &J_chain);
      J_t.leftCols(cols).noalias() = H_q * J_chain.middleCols(first, cols);
      const auto J = J_t.leftCols(cols);
      sys->H_tt.block(first, first, cols, cols).noalias() += w * J.transpose() * J;
      sys->g_t.segment(first, cols).noalias() += w * J.transpose() * r;
      if (!params_.optimise_points) continue;
      // d moved / d point = R(M_f M_a^-1) R_joint_cam_a.
      const Eigen::Matrix<double, 2, 3> J_p = H_q * M_fa.rotation() * T_joint_cam_[a].rotation();
      sys->H_pp[o.landmark].noalias() += w * J_p.transpose() * J_p;
      sys->H_tp[o.landmark].middleRows(first, cols).noalias() += w * J.transpose() * J_p;
      sys->g_p[o.landmark].noalias() += w * J_p.transpose() * r;
    }
    // Depth prior on the points (camera of their anchor frame).
    for (int l = 0; l < L; ++l) {
      const Vec3 d = s.points[l] - p_.points_cam0[l];
      cost += 0.5 * d.dot(prior_weight_[l] * d);
      if (sys && params_.optimise_points) {
        sys->H_pp[l] += prior_weight_[l];
        sys->g_p[l] += prior_weight_[l] * d;
      }
    }
    // Constant velocity: consecutive displacements (= projected twists times dt) agree.
    for (int i = 0; i + 1 < n_ - 1; ++i) {
      const JointVector d = s.theta[i + 1] - s.theta[i];
      cost += 0.5 * d.dot(cv_weight_.cwiseProduct(d));
      if (!sys) continue;
      for (int c = 0; c < k_; ++c) {
        const int a = i * k_ + c, b = (i + 1) * k_ + c;
        sys->H_tt(a, a) += cv_weight_(c);
        sys->H_tt(b, b) += cv_weight_(c);
        sys->H_tt(a, b) -= cv_weight_(c);
        sys->H_tt(b, a) -= cv_weight_(c);
        sys->g_t(a) -= cv_weight_(c) * d(c);
        sys->g_t(b) += cv_weight_(c) * d(c);
      }
    }
    return cost;
  }

  // Reduced camera-style system over the displacements: S = H_tt - sum H_tp H_pp^-1 H_pt.
  void reduce(const System& sys, double lambda, Eigen::MatrixXd* S, Eigen::VectorXd* b) const {
    *S = sys.H_tt;
    S->diagonal() += lambda * (Eigen::VectorXd::Ones(K_) + sys.H_tt.diagonal());
    *b = sys.g_t;
    for (size_t l = 0; l < sys.H_tp.size(); ++l) {
      Mat3 Hpp = sys.H_pp[l];
      Hpp.diagonal() += lambda * (Vec3::Ones() + sys.H_pp[l].diagonal());
      const Mat3 inv = Hpp.inverse();
      S->noalias() -= sys.H_tp[l] * inv * sys.H_tp[l].transpose();
      b->noalias() -= sys.H_tp[l] * (inv * sys.g_p[l]);
    }
  }

  State step(const State& s, const System& sys, double lambda) const {
    Eigen::MatrixXd S;
    Eigen::VectorXd b;
    reduce(sys, lambda, &S, &b);
    const Eigen::VectorXd dt = -S.ldlt().solve(b);
    State out = s;
    for (int i = 0; i < n_ - 1; ++i) out.theta[i] += dt.segment(i * k_, k_);
    for (size_t l = 0; l < sys.H_tp.size(); ++l) {
      Mat3 Hpp = sys.H_pp[l];
      Hpp.diagonal() += lambda * (Vec3::Ones() + sys.H_pp[l].diagonal());
      out.points[l] -= Hpp.inverse() * (sys.g_p[l] + sys.H_tp[l].transpose() * dt);
    }
    return out;
  }

  int K() const { return K_; }

 private:
  int anchor(int landmark) const { return p_.anchor_frame.empty() ? 0 : p_.anchor_frame[landmark]; }

  const ObjectWindowProblem& p_;
  const ObjectWindowParams& params_;
  int k_, n_, K_ = 0;
  std::vector<SE3> T_joint_cam_, T_cam_joint_;
  JointVector cv_weight_;
  std::vector<Mat3> prior_weight_;  // information of each point's measurement
};

}  // namespace

ObjectWindowResult solveObjectWindow(const ObjectWindowProblem& problem,
                                     const ObjectWindowParams& params,
                                     const std::vector<JointVector>* initial) {
  checkProblem(problem, initial);
  if (!(params.pixel_sigma > 0) || !(params.huber_px > 0) || !(params.depth_sigma_rel > 0) ||
      !(params.lateral_sigma_px > 0) || !(params.cv_sigma_translation > 0) ||
      !(params.cv_sigma_rotation > 0))
    throw std::invalid_argument("solveObjectWindow: sigmas and huber_px must be > 0");
  const int n = static_cast<int>(problem.T_world_cam.size());
  const int k = problem.joint.dof();
  State s;
  s.theta = initial ? *initial : std::vector<JointVector>(n - 1, JointVector::Zero(k));
  s.points = problem.points_cam0;
  WindowSolver solver(problem, params);
  ObjectWindowResult res;
  System sys;
  double cost = solver.evaluate(s, &sys);
  double lambda = 1e-6;
  for (res.iterations = 0; res.iterations < params.max_iterations; ++res.iterations) {
    bool improved = false;
    State trial;
    for (int attempt = 0; attempt < 10 && !improved; ++attempt) {
      trial = solver.step(s, sys, lambda);
      const double trial_cost = solver.evaluate(trial, nullptr);
      if (std::isfinite(trial_cost) && trial_cost <= cost) {
        improved = true;
        const double gain = cost - trial_cost;
        cost = trial_cost;
        double change = 0;
        for (int i = 0; i < n - 1; ++i) change += (trial.theta[i] - s.theta[i]).squaredNorm();
        s = trial;
        lambda = std::max(1e-9, lambda * 0.3);
        solver.evaluate(s, &sys);
        if (change < 1e-20 || gain < 1e-12 * (1 + cost)) res.converged = true;
      } else {
        lambda *= 10;
      }
    }
    if (!improved) res.converged = true;
    if (res.converged) break;
  }
  // Marginal covariance of the displacements (points eliminated), at the solution.
  int inliers = 0;
  double inlier_sq = 0;
  solver.evaluate(s, &sys, &inliers, &inlier_sq);
  Eigen::MatrixXd S;
  Eigen::VectorXd b;
  solver.reduce(sys, 0.0, &S, &b);
  res.covariance = S.ldlt().solve(Eigen::MatrixXd::Identity(solver.K(), solver.K()));
  res.rms_px = inliers > 0 ? std::sqrt(inlier_sq / inliers) : 0;
  res.theta = s.theta;
  res.points_cam0 = s.points;
  res.is_static = true;
  const JointBasis& A = problem.joint.basis();
  for (int i = 0; i < n - 1; ++i) {
    res.motion_world.push_back(problem.joint.motionWorld(s.theta[i]));
    res.twist_joint.push_back(problem.joint.twist(s.theta[i], problem.dt));
    const Eigen::MatrixXd C = res.covariance.block(i * k, i * k, k, k);
    res.twist_covariance.push_back(A * C * A.transpose() / (problem.dt * problem.dt));
    const Vec6 xi = A * s.theta[i];
    if (xi.head<3>().norm() >= params.static_translation ||
        xi.tail<3>().norm() >= params.static_rotation)
      res.is_static = false;
  }
  return res;
}

}  // namespace radslam
