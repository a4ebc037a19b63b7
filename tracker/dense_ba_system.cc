#include "tracker/dense_ba_system.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace radslam {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

Eigen::VectorXd toVector(const cv::Mat& m) {
  Eigen::VectorXd v(m.total());
  int p = 0;
  for (int r = 0; r < m.rows; ++r) {
    const float* row = m.ptr<float>(r);
    for (int c = 0; c < m.cols; ++c) v(p++) = row[c];
  }
  return v;
}

}  // namespace

void DenseBundleAdjuster::System::setup(const DenseBaProblem& problem,
                                        const DenseBaOptions& options) {
  options_ = options;
  const CameraModel& cam = problem.camera;
  cam_ = {cam.fx, cam.fy, cam.cx, cam.cy};
  width_ = cam.width;
  height_ = cam.height;
  npix_ = width_ * height_;
  padded_width_ = (width_ + kBlock - 1) / kBlock * kBlock;
  xn_.assign(padded_width_, 0.0);
  yn_.resize(height_);
  d_row_.assign(padded_width_, 1.0);
  P_row_.assign(padded_width_, 0.0);
  w_row_.assign(padded_width_, 0.0);
  for (int u = 0; u < width_; ++u) xn_[u] = (u - cam.cx) / cam.fx;  // padding stays 0
  for (int v = 0; v < height_; ++v) yn_[v] = (v - cam.cy) / cam.fy;

  const int K = static_cast<int>(problem.keyframes.size());
  poses_.resize(K);
  depths_.resize(K);
  prior_mean_.assign(K, Eigen::VectorXd());
  prior_omega_.assign(K, Eigen::VectorXd());
  level_alpha_.assign(K, 0.0);
  level_u_.assign(K, Eigen::VectorXd());
  measured_.assign(K, {});
  measured_var_.assign(K, {});
  var_.assign(K, -1);
  num_vars_ = 0;
  for (int k = 0; k < K; ++k) {
    const DenseBaKeyframe& kf = problem.keyframes[k];
    poses_[k] = kf.T_world_cam;
    depths_[k] = toVector(kf.inv_depth);
    for (int p = 0; p < npix_; ++p) {
      double& d = depths_[k](p);
      // Keep the state inside the admissible range from the start (NaN -> lower bound).
      d = std::isfinite(d) ? std::clamp(d, options_.min_inv_depth, options_.max_inv_depth)
                           : options_.min_inv_depth;
    }
    if (!kf.prior_inv_depth.empty()) {
      prior_mean_[k] = toVector(kf.prior_inv_depth);
      prior_omega_[k] = toVector(kf.prior_inv_depth_var);
      for (int p = 0; p < npix_; ++p) {
        const double var = prior_omega_[k](p);
        const bool valid = std::isfinite(prior_mean_[k](p)) && var > 0 && var < kInf;
        prior_omega_[k](p) = valid ? 1.0 / var : 0.0;
        if (!valid) prior_mean_[k](p) = 0;
      }
      const Eigen::Index with_prior = (prior_omega_[k].array() > 0).count();
      if (kf.prior_level_var > 0 && with_prior > 0) {
        level_alpha_[k] = 1.0 / kf.prior_level_var;
        level_u_[k] = (prior_omega_[k].array() > 0).cast<double>() / with_prior;
      }
    }
    if (!kf.measured_inv_depth.empty()) {
      dense_ba::depthSamples(kf.measured_inv_depth, kf.measured_inv_depth_var, &measured_[k],
                             &measured_var_[k]);
    }
    bool fixed = kf.fixed_pose;
    switch (options_.gauge) {
      case DenseBaGauge::kFlaggedOnly:
        break;
      case DenseBaGauge::kFirstPose:
      case DenseBaGauge::kFirstPoseAndScale:
        fixed = fixed || k == 0;
        break;
      case DenseBaGauge::kFirstTwoPoses:
        fixed = fixed || k <= 1;
        break;
    }
    if (!fixed) var_[k] = num_vars_++;
  }

  pinned_kf_ = -1;
  if (options_.gauge == DenseBaGauge::kFirstPoseAndScale && K >= 2 && var_[1] >= 0) {
    pinned_kf_ = 1;
    scale_distance_ = (poses_[1].translation() - poses_[0].translation()).norm();
    if (!(scale_distance_ > 1e-9)) {
      throw std::invalid_argument(
          "DenseBA: gauge kFirstPoseAndScale needs distinct camera centres for keyframes 0 and "
          "1 (distance " +
          std::to_string(scale_distance_) + ")");
    }
  }

  // Buffers keep their capacity across calls (the front end calls this every round).
  edges_.resize(problem.edges.size());
  out_edges_.assign(K, {});
  src_edges_.assign(K, {});
  for (size_t n = 0; n < problem.edges.size(); ++n) {
    const DenseBaEdge& in = problem.edges[n];
    Edge& e = edges_[n];
    e.i = in.i;
    e.slot = -1;
    if (in.T_i_other) {
      e.j = -1;
      e.T_j_i_fixed = in.T_i_other->inverse();
    } else {
      e.j = in.j;
      e.slot = static_cast<int>(out_edges_[in.i].size());
      out_edges_[in.i].push_back(static_cast<int>(n));
    }
    src_edges_[in.i].push_back(static_cast<int>(n));
    const int padded = height_ * padded_width_;
    e.tu.setZero(padded);
    e.tv.setZero(padded);
    e.wu.setZero(padded);
    e.wuv.setZero(padded);
    e.wv.setZero(padded);
    for (int v = 0; v < height_; ++v) {
      const cv::Vec2f* target = in.target.ptr<cv::Vec2f>(v);
      const cv::Vec3f* weight = in.weight.ptr<cv::Vec3f>(v);
      for (int u = 0; u < width_; ++u) {
        const int p = v * padded_width_ + u;
        double uu, uv, vv;
        if (!std::isfinite(target[u][0]) || !std::isfinite(target[u][1]) ||
            !flowInformation(weight[u], &uu, &uv, &vv)) {
          continue;
        }
        e.wu(p) = uu;
        e.wuv(p) = uv;
        e.wv(p) = vv;
        e.tu(p) = target[u][0];
        e.tv(p) = target[u][1];
      }
    }
  }
  // A keyframe's measurement is one set of data used by every edge into it and by its own
  // prior: each depth residual counts it with 1 / (uses) of its information, so that the uses
  // together count it about once (the edges' residuals share its noise).
  for (int k = 0; k < K; ++k) {
    if (measured_var_[k].empty()) continue;
    int uses = prior_omega_[k].size() > 0 ? 1 : 0;
    for (const Edge& e : edges_) uses += e.j == k;
    for (double& var : measured_var_[k]) var *= std::max(uses, 1);
  }
  cur_ = 0;
  // Keep the solver (and CHOLMOD's symbolic analysis) unless its options changed.
  const ReducedCameraSolverOptions& so = options_.solver;
  if (!solver_ || solver_options_.backend != so.backend ||
      solver_options_.cholmod_min_blocks != so.cholmod_min_blocks ||
      solver_options_.cholmod_supernodal != so.cholmod_supernodal) {
    solver_ = std::make_unique<ReducedCameraSolver>(so);
    solver_options_ = so;
  }
}

template <bool kLinearize>
double DenseBundleAdjuster::System::keyframePass(int kf, const std::vector<SE3>& poses,
                                                 const std::vector<Eigen::VectorXd>& depths,
                                                 Linearization* lin, double* sum_error,
                                                 int* count) {
  const std::vector<int>& list = src_edges_[kf];
  if (list.empty()) return 0;
  ctx_.resize(list.size());
  for (size_t c = 0; c < list.size(); ++c) {
    const Edge& e = edges_[list[c]];
    EdgeContext& x = ctx_[c];
    x.T_j_i = e.j < 0 ? e.T_j_i_fixed : poses[e.j].inverse() * poses[e.i];
    x.R = x.T_j_i.rotation();
    x.t = x.T_j_i.translation();
    x.A.setZero();
    x.g.setZero();
    x.B = kLinearize && e.j >= 0 ? lin->B[kf].data() + 6 * e.slot : nullptr;
    const bool measured = e.j >= 0 && !measured_[e.j].empty();
    x.measured = measured ? measured_[e.j].data() : nullptr;
    x.measured_var = measured ? measured_var_[e.j].data() : nullptr;
  }
  // Rows outer, edges inner: the row's columns of B_kf (W x 6m doubles) stay in cache while
  // every edge writes its slot.
  double cost = 0, err = 0;
  int n = 0;
  for (int v = 0; v < height_; ++v) {
    std::copy_n(depths[kf].data() + v * width_, width_, d_row_.begin());
    if constexpr (kLinearize) {
      std::fill(P_row_.begin(), P_row_.end(), 0.0);
      std::fill(w_row_.begin(), w_row_.end(), 0.0);
    }
    for (size_t c = 0; c < list.size(); ++c) {
      rowPass<kLinearize>(edges_[list[c]], &ctx_[c], v, lin, &cost, &err, &n);
    }
    if constexpr (kLinearize) {
      double* P = lin->P[kf].data() + v * width_;
      double* w = lin->w[kf].data() + v * width_;
      for (int u = 0; u < width_; ++u) {
        P[u] += P_row_[u];
        w[u] += w_row_[u];
      }
    }
  }
  if constexpr (kLinearize) {
    for (size_t c = 0; c < list.size(); ++c) {
      EdgeLin& el = lin->edges[list[c]];
      el.A = ctx_[c].A.selfadjointView<Eigen::Lower>();
      el.g = ctx_[c].g;
      el.Ad = ctx_[c].T_j_i.adjoint();
    }
  }
  if (sum_error) sum_error[kf] += err;
  if (count) count[kf] += n;
  return cost;
}

template <bool kLinearize>
void DenseBundleAdjuster::System::rowPass(const Edge& e, EdgeContext* x, int v, Linearization* lin,
                                          double* cost, double* err, int* n) {
  // The arithmetic of dense_ba::reproject and dense_ba::robustCost on blocks of kBlock pixels of
  // one grid row (fixed-size arrays: unrolled and vectorised); invalid pixels get zero weight, the
  // branches stay in two short scalar loops.
  using Block = Eigen::Array<double, kBlock, 1>;
  using CMap = Eigen::Map<const Block>;
  const double fx = cam_.fx, fy = cam_.fy, cx = cam_.cx, cy = cam_.cy;
  const double k = options_.robust_scale;
  const RobustKernel kernel = options_.robust_kernel;
  const double min_ratio = options_.min_depth_ratio;
  const Mat3& R = x->R;
  const Vec3& t = x->t;
  const double y = yn_[v];
  const double cX = R(0, 1) * y + R(0, 2), cY = R(1, 1) * y + R(1, 2), cZ = R(2, 1) * y + R(2, 2);
  const int ldb = x->B ? static_cast<int>(lin->B[e.i].rows()) : 0;
  for (int u0 = 0; u0 < padded_width_; u0 += kBlock) {
    const int off = v * padded_width_ + u0;
    const CMap xs(xn_.data() + u0), d(d_row_.data() + u0);
    const Block X = R(0, 0) * xs + cX + t(0) * d;
    const Block Y = R(1, 0) * xs + cY + t(1) * d;
    const Block Z = R(2, 0) * xs + cZ + t(2) * d;
    Block iz, wu, wuv, wv;
    for (int q = 0; q < kBlock; ++q) {
      const double a = e.wu(off + q), b = e.wv(off + q);
      const bool used = Z(q) > min_ratio && (a > 0 || b > 0);
      iz(q) = used ? 1.0 / Z(q) : 0.0;
      wu(q) = used ? a : 0.0;
      wuv(q) = used ? e.wuv(off + q) : 0.0;
      wv(q) = used ? b : 0.0;
    }
    const Block xn = X * iz, yn = Y * iz;
    const Block ru = CMap(e.tu.data() + off) - (fx * xn + cx);
    const Block rv = CMap(e.tv.data() + off) - (fy * yn + cy);
    const Block s2 = wu * ru.square() + 2.0 * wuv * ru * rv + wv * rv.square();
    Block irls;
    for (int q = 0; q < kBlock; ++q) {
      if (iz(q) == 0) {
        irls(q) = 0;
        continue;
      }
      *cost += dense_ba::robustCost(kernel, s2(q), k, &irls(q));
      *err += std::sqrt(ru(q) * ru(q) + rv(q) * rv(q));
      ++*n;
    }
    if constexpr (kLinearize) {
      // r = target - pixel, so dr/dxi = -J, dr/dd = -Jd: the signs cancel in J^T W J, and
      // J^T W r is kept with the pixel Jacobian's sign (see dense_ba_system.h).
      // W with the IRLS weight, and W times the depth Jacobian.
      const Block au = irls * wu, auv = irls * wuv, av = irls * wv;
      const Block Jd0 = fx * iz * (t(0) - xn * t(2));
      const Block Jd1 = fy * iz * (t(1) - yn * t(2));
      const Block wd0 = au * Jd0 + auv * Jd1, wd1 = auv * Jd0 + av * Jd1;
      Eigen::Map<Block>(P_row_.data() + u0) += wd0 * Jd0 + wd1 * Jd1;
      Eigen::Map<Block>(w_row_.data() + u0) += wd0 * ru + wd1 * rv;
      if (x->B) {
        // J_xi rows (dense_ba::reproject); j0[1] = j1[0] = 0.
        const Block s = d * iz;
        const Block j0[6] = {
            fx * s, Block::Zero(), -fx * s * xn, -fx * xn * yn, fx * (1.0 + xn.square()), -fx * yn};
        const Block j1[6] = {Block::Zero(), fy * s, -fy * s * yn, -fy * (1.0 + yn.square()),
                             fy * xn * yn,  fy * xn};
        const Block wr0 = au * ru + auv * rv, wr1 = auv * ru + av * rv;  // W r
        // Rows of W J: wj0 = W_uu j0 + W_uv j1, wj1 = W_uv j0 + W_vv j1.
        Block wj0[6], wj1[6];
        wj0[0] = au * j0[0];
        wj1[0] = auv * j0[0];
        wj0[1] = auv * j1[1];
        wj1[1] = av * j1[1];
        for (int a = 2; a < 6; ++a) {
          wj0[a] = au * j0[a] + auv * j1[a];
          wj1[a] = auv * j0[a] + av * j1[a];
        }
        // Lower triangle of A += J^T W J without the products of the zero entries.
        Mat6& A = x->A;
        A(0, 0) += (j0[0] * wj0[0]).sum();
        A(1, 0) += (j1[1] * wj1[0]).sum();
        A(1, 1) += (j1[1] * wj1[1]).sum();
        for (int a = 2; a < 6; ++a) {
          A(a, 0) += (j0[a] * wj0[0] + j1[a] * wj1[0]).sum();
          A(a, 1) += (j0[a] * wj0[1] + j1[a] * wj1[1]).sum();
          for (int c = 2; c <= a; ++c) A(a, c) += (j0[a] * wj0[c] + j1[a] * wj1[c]).sum();
        }
        x->g(0) += (j0[0] * wr0).sum();
        x->g(1) += (j1[1] * wr1).sum();
        for (int a = 2; a < 6; ++a) x->g(a) += (j0[a] * wr0 + j1[a] * wr1).sum();
        // E entries J_xi^T W J_d.
        const Block b0 = j0[0] * wd0, b1 = j1[1] * wd1, b2 = j0[2] * wd0 + j1[2] * wd1,
                    b3 = j0[3] * wd0 + j1[3] * wd1, b4 = j0[4] * wd0 + j1[4] * wd1,
                    b5 = j0[5] * wd0 + j1[5] * wd1;
        const int count = std::min(kBlock, width_ - u0);
        double* col = x->B + static_cast<size_t>(v * width_ + u0) * ldb;
        for (int q = 0; q < count; ++q, col += ldb) {
          col[0] = b0(q);
          col[1] = b1(q);
          col[2] = b2(q);
          col[3] = b3(q);
          col[4] = b4(q);
          col[5] = b5(q);
          if (x->measured) {
            const double j0q[6] = {j0[0](q), 0.0, j0[2](q), j0[3](q), j0[4](q), j0[5](q)};
            const double j1q[6] = {0.0, j1[1](q), j1[2](q), j1[3](q), j1[4](q), j1[5](q)};
            depthTerm(x, iz(q), xn(q), yn(q), d(q), j0q, j1q, Jd0(q), Jd1(q), u0 + q, col, cost);
          }
        }
      }
    } else if (x->measured) {
      for (int q = 0; q < std::min(kBlock, width_ - u0); ++q) {
        depthTerm(x, iz(q), xn(q), yn(q), d(q), nullptr, nullptr, 0, 0, u0 + q, nullptr, cost);
      }
    }
  }
}

void DenseBundleAdjuster::System::depthTerm(EdgeContext* x, double iz, double xn, double yn,
                                            double d, const double* j0, const double* j1,
                                            double jd0, double jd1, int u, double* col,
                                            double* cost) {
  if (iz == 0) return;  // no reprojection: occluded, masked or behind the camera
  dense_ba::DepthSample m;
  if (!dense_ba::sampleDepth(x->measured, x->measured_var, width_, height_, cam_.fx * xn + cam_.cx,
                             cam_.fy * yn + cam_.cy, options_.depth_residual_max_jump, &m)) {
    return;
  }
  const double s = d * iz, r = m.value - s;
  double irls;
  *cost +=
      dense_ba::robustCost(options_.robust_kernel, r * r / m.var, options_.robust_scale, &irls);
  if (!j0) return;
  Vec6 jz;
  double jd;
  dense_ba::depthResidualJacobians(m, s, xn, yn, iz, x->t(2), j0, j1, jd0, jd1, &jz, &jd);
  const double w = irls / m.var;
  x->A.noalias() += (w * jz) * jz.transpose();
  x->g += (w * r) * jz;
  P_row_[u] += w * jd * jd;
  w_row_[u] += w * jd * r;
  if (col) {
    for (int a = 0; a < 6; ++a) col[a] += w * jz(a) * jd;
  }
}

double DenseBundleAdjuster::System::priorPass(int k, const Eigen::VectorXd& d,
                                              Linearization* lin) const {
  if (prior_omega_[k].size() == 0) return 0;
  const Eigen::VectorXd& omega = prior_omega_[k];
  const Eigen::VectorXd r = prior_mean_[k] - d;
  if (lin) {
    lin->P[k] += omega;
    lin->w[k] += omega.cwiseProduct(r);
  }
  double cost = omega.dot(r.cwiseProduct(r));
  if (level_alpha_[k] > 0) {
    const double level = level_u_[k].dot(r);
    if (lin) lin->w[k] += level_alpha_[k] * level * level_u_[k];
    cost += level_alpha_[k] * level * level;
  }
  return cost;
}

double DenseBundleAdjuster::System::levelBeta(const Linearization& lin, int k) const {
  if (level_alpha_[k] <= 0) return 0;
  // u is zero wherever D is (u only covers pixels with a prior, whose D holds its omega).
  const double uDu = (level_u_[k].array().square() / lin.P[k].array().max(1e-300)).sum();
  return level_alpha_[k] / (1 + level_alpha_[k] * uDu);
}

double DenseBundleAdjuster::System::evaluate(const std::vector<SE3>& poses,
                                             const std::vector<Eigen::VectorXd>& depths,
                                             std::vector<double>* mean_error_px,
                                             int* num_residuals) {
  const int K = static_cast<int>(poses.size());
  std::vector<double> sum(K, 0.0);
  std::vector<int> count(K, 0);
  double cost = 0;
  for (int k = 0; k < K; ++k) {
    cost += keyframePass<false>(k, poses, depths, nullptr, sum.data(), count.data());
  }
  for (int k = 0; k < K; ++k) cost += priorPass(k, depths[k], nullptr);
  if (mean_error_px) {
    mean_error_px->assign(K, 0.0);
    for (int k = 0; k < K; ++k) (*mean_error_px)[k] = count[k] ? sum[k] / count[k] : 0.0;
  }
  if (num_residuals) {
    *num_residuals = 0;
    for (int c : count) *num_residuals += c;
  }
  return cost;
}

double DenseBundleAdjuster::System::linearizeInto(const std::vector<SE3>& poses,
                                                  const std::vector<Eigen::VectorXd>& depths,
                                                  Linearization* lin) {
  const int K = static_cast<int>(poses.size());
  lin->edges.resize(edges_.size());
  lin->B.resize(K);
  lin->P.resize(K);
  lin->w.resize(K);
  for (int k = 0; k < K; ++k) {
    lin->P[k].setZero(npix_);
    lin->w[k].setZero(npix_);
    lin->B[k].resize(6 * static_cast<int>(out_edges_[k].size()), npix_);
  }
  lin->Q = scaleGaugeRotation(poses);
  std::vector<double> sum(K, 0.0);
  std::vector<int> count(K, 0);
  double cost = 0;
  for (int k = 0; k < K; ++k) {
    cost += keyframePass<true>(k, poses, depths, lin, sum.data(), count.data());
  }
  for (int k = 0; k < K; ++k) cost += priorPass(k, depths[k], lin);
  lin->cost = cost;
  lin->mean_error_px.assign(K, 0.0);
  lin->num_residuals = 0;
  for (int k = 0; k < K; ++k) {
    lin->mean_error_px[k] = count[k] ? sum[k] / count[k] : 0.0;
    lin->num_residuals += count[k];
  }
  buildPoseSystem(lin);
  buildSchurTerm(lin);
  return cost;
}

void DenseBundleAdjuster::System::acceptCandidate(std::vector<SE3>* poses,
                                                  std::vector<Eigen::VectorXd>* depths) {
  std::swap(poses_, *poses);
  std::swap(depths_, *depths);
  cur_ = 1 - cur_;
}

Mat6 DenseBundleAdjuster::System::scaleGaugeRotation(const std::vector<SE3>& poses) const {
  Mat6 Q = Mat6::Identity();
  if (pinned_kf_ < 0) return Q;
  // The pinned coordinate is the camera-centre motion along the baseline 0 -> 1, written in the
  // body frame of keyframe 1 (a right perturbation moves the centre by R_world_1 v).
  const Vec3 u = (poses[1].translation() - poses[0].translation()).normalized();
  const Vec3 n = poses[1].so3().inverse() * u;
  Vec3 axis = Vec3::Zero();
  int k_min;
  n.cwiseAbs().minCoeff(&k_min);
  axis(k_min) = 1;
  const Vec3 b2 = n.cross(axis).normalized();
  Q.block<3, 1>(0, 0) = n;
  Q.block<3, 1>(0, 1) = b2;
  Q.block<3, 1>(0, 2) = n.cross(b2);
  return Q;
}

Eigen::MatrixXd DenseBundleAdjuster::System::slotMap(const Linearization& lin, int k) const {
  const int m = static_cast<int>(out_edges_[k].size());
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(6 * (m + 1), 6 * m);
  for (int s = 0; s < m; ++s) {
    M.block<6, 6>(0, 6 * s) = lin.edges[out_edges_[k][s]].Ad.transpose();
    M.block<6, 6>(6 * (s + 1), 6 * s) = -Mat6::Identity();
  }
  return M;
}

std::vector<int> DenseBundleAdjuster::System::slotVars(int k) const {
  std::vector<int> vars{var_[k]};
  for (int ei : out_edges_[k]) vars.push_back(var_[edges_[ei].j]);
  return vars;
}

void DenseBundleAdjuster::System::buildPoseSystem(Linearization* lin) const {
  lin->C.reset(num_vars_);
  lin->v.setZero(6 * num_vars_);
  for (size_t n = 0; n < edges_.size(); ++n) {
    const Edge& e = edges_[n];
    if (e.j < 0) continue;
    const EdgeLin& el = lin->edges[n];
    const int vi = var_[e.i], vj = var_[e.j];
    const Mat6 AdT_A = el.Ad.transpose() * el.A;
    if (vi >= 0) {
      lin->C.lower(vi, vi) += AdT_A * el.Ad;
      lin->v.segment<6>(6 * vi) += el.Ad.transpose() * el.g;
    }
    if (vj >= 0) {
      lin->C.lower(vj, vj) += el.A;
      lin->v.segment<6>(6 * vj) -= el.g;
    }
    if (vi >= 0 && vj >= 0) lin->C.add(vi, vj, -AdT_A);
  }
}

void DenseBundleAdjuster::System::buildSchurTerm(Linearization* lin) {
  const int K = static_cast<int>(poses_.size());
  lin->G.reset(num_vars_);
  lin->h.setZero(6 * num_vars_);
  for (int k = 0; k < K; ++k) {
    const int m = static_cast<int>(out_edges_[k].size());
    const std::vector<int> vars = slotVars(k);
    if (m == 0 || std::all_of(vars.begin(), vars.end(), [](int v) { return v < 0; })) continue;
    // Keyframe k's part: M (B P^-1 B^T) M^T and M B P^-1 w over pixels with P > 0.
    const Eigen::MatrixXd& B = lin->B[k];
    const Eigen::VectorXd& P = lin->P[k];
    // One SYRK of [B D^-1/2; w^T D^-1/2; u^T D^-1/2] gives B D^-1 B^T, B D^-1 w (row `rows`)
    // and, with a level prior, B D^-1 u (last row); P^-1 = D^-1 - beta q q^T corrects both.
    const int rows = static_cast<int>(B.rows());
    const bool level = level_alpha_[k] > 0;
    const int extra = level ? 2 : 1;
    Bt_.resize(rows + extra, npix_);
    for (int p = 0; p < npix_; ++p) {
      const double scale = P(p) > 0 ? 1.0 / std::sqrt(P(p)) : 0.0;
      Bt_(rows, p) = lin->w[k](p) * scale;
      if (level) Bt_(rows + 1, p) = level_u_[k](p) * scale;
      Bt_.col(p).head(rows) = B.col(p) * scale;
    }
    Eigen::MatrixXd S = Eigen::MatrixXd::Zero(rows + extra, rows + extra);
    S.selfadjointView<Eigen::Lower>().rankUpdate(Bt_);
    Eigen::MatrixXd BPB = S.topLeftCorner(rows, rows).selfadjointView<Eigen::Lower>();
    Eigen::VectorXd BPw = S.row(rows).head(rows).transpose();
    if (level) {
      const double beta = levelBeta(*lin, k);
      const Eigen::VectorXd BDu = S.row(rows + 1).head(rows).transpose();
      BPB.noalias() -= beta * BDu * BDu.transpose();
      BPw -= beta * S(rows + 1, rows) * BDu;
    }
    const Eigen::MatrixXd M = slotMap(*lin, k);
    const Eigen::MatrixXd G = M * BPB * M.transpose();
    const Eigen::VectorXd h = M * BPw;
    for (int a = 0; a <= m; ++a) {
      const int va = vars[a];
      if (va < 0) continue;
      lin->h.segment<6>(6 * va) += h.segment<6>(6 * a);
      for (int b = 0; b <= m; ++b) {
        const int vb = vars[b];
        if (vb < 0 || vb > va) continue;
        // Slots mapping to the same pose (duplicate edges) sum both orders into its block.
        lin->G.lower(va, vb) += G.block<6, 6>(6 * a, 6 * b);
      }
    }
  }
}

void DenseBundleAdjuster::System::assembleReduced(const Linearization& lin, double lambda) {
  H_.reset(num_vars_);
  const double schur_scale = 1.0 / (1.0 + lambda);
  for (int c = 0; c < num_vars_; ++c) {
    for (const auto& [r, M] : lin.C.column(c)) H_.lower(r, c) += M;
    for (const auto& [r, M] : lin.G.column(c)) H_.lower(r, c) -= schur_scale * M;
    if (lambda > 0) {
      Mat6& D = H_.lower(c, c);
      const Mat6 C = lin.C.block(c, c);
      for (int a = 0; a < 6; ++a) D(a, a) += lambda * std::max(C(a, a), options_.min_lm_diagonal);
    }
  }
  rhs_ = lin.v - schur_scale * lin.h;
  if (pinned_kf_ < 0 || var_[pinned_kf_] < 0) return;

  // H <- Q^T H Q on the rows / columns of the pinned pose, then its coordinate 0 becomes a
  // decoupled unit row (a_0 = 0): exactly as if it were not a variable.
  const int v1 = var_[pinned_kf_];
  const Mat6& Q = lin.Q;
  for (int c = 0; c < v1; ++c) {
    if (!H_.hasBlock(v1, c)) continue;
    Mat6& M = H_.lower(v1, c);
    M = (Q.transpose() * M).eval();
    M.row(0).setZero();
  }
  std::vector<int> rows;
  for (const auto& entry : H_.column(v1)) rows.push_back(entry.first);
  for (int r : rows) {
    Mat6& M = H_.lower(r, v1);
    if (r == v1) {
      M = (Q.transpose() * M * Q).eval();
      M.row(0).setZero();
      M.col(0).setZero();
      M(0, 0) = 1;
    } else {
      M = (M * Q).eval();
      M.col(0).setZero();
    }
  }
  rhs_.segment<6>(6 * v1) = (Q.transpose() * rhs_.segment<6>(6 * v1)).eval();
  rhs_(6 * v1) = 0;
}

bool DenseBundleAdjuster::System::solve(double lambda, std::vector<Vec6>* dxi,
                                        std::vector<Eigen::VectorXd>* dd) {
  const int K = static_cast<int>(poses_.size());
  const Linearization& lin = lin_[cur_];
  assembleReduced(lin, lambda);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(6 * num_vars_);
  solver_error_.clear();
  if (num_vars_ > 0) {
    if (!solver_->factorize(H_)) {
      solver_error_ = solver_->error();
      return false;
    }
    x = solver_->solve(rhs_);
    if (pinned_kf_ >= 0 && var_[pinned_kf_] >= 0) {
      const int v1 = var_[pinned_kf_];
      x.segment<6>(6 * v1) = (lin.Q * x.segment<6>(6 * v1)).eval();
    }
  }
  dxi->assign(K, Vec6::Zero());
  for (int k = 0; k < K; ++k) {
    if (var_[k] >= 0) (*dxi)[k] = x.segment<6>(6 * var_[k]);
  }
  dd->resize(K);
  const double depth_scale = 1.0 / (1.0 + lambda);
  for (int k = 0; k < K; ++k) {
    const int m = static_cast<int>(out_edges_[k].size());
    // e_p^T dxi = sum_e b_e,p . (Ad_e dxi_i - dxi_j).
    Eigen::VectorXd U(6 * m);
    for (int s = 0; s < m; ++s) {
      const int ei = out_edges_[k][s];
      U.segment<6>(6 * s) = lin.edges[ei].Ad * (*dxi)[k] - (*dxi)[edges_[ei].j];
    }
    Eigen::VectorXd& step = (*dd)[k];
    step = lin.w[k];
    if (m > 0) step.noalias() -= lin.B[k].transpose() * U;
    const Eigen::VectorXd& P = lin.P[k];
    for (int p = 0; p < npix_; ++p) step(p) = P(p) > 0 ? step(p) / P(p) : 0.0;
    if (level_alpha_[k] > 0) {
      // P^-1 r = D^-1 r - beta q (u^T D^-1 r), q = D^-1 u.
      const double beta = levelBeta(lin, k), uDr = level_u_[k].dot(step);
      for (int p = 0; p < npix_; ++p) {
        if (P(p) > 0) step(p) -= beta * uDr * level_u_[k](p) / P(p);
      }
    }
    step *= depth_scale;
  }
  return true;
}

void DenseBundleAdjuster::System::retract(const std::vector<Vec6>& dxi,
                                          const std::vector<Eigen::VectorXd>& dd,
                                          std::vector<SE3>* poses,
                                          std::vector<Eigen::VectorXd>* depths) const {
  const int K = static_cast<int>(poses_.size());
  poses->resize(K);
  depths->resize(K);
  for (int k = 0; k < K; ++k) {
    (*poses)[k] = var_[k] >= 0 ? poses_[k] * SE3::exp(dxi[k]) : poses_[k];
    Eigen::VectorXd& d = (*depths)[k];
    d.resize(npix_);
    for (int p = 0; p < npix_; ++p) {
      d(p) = std::clamp(depths_[k](p) + dd[k](p), options_.min_inv_depth, options_.max_inv_depth);
    }
  }
  if (pinned_kf_ >= 0 && var_[pinned_kf_] >= 0) {
    // The linear step keeps the baseline length to first order; restore it exactly.
    const Vec3 c0 = (*poses)[0].translation();
    Vec3& c1 = (*poses)[pinned_kf_].translation();
    c1 = c0 + (c1 - c0) * (scale_distance_ / (c1 - c0).norm());
  }
}

std::vector<Vec6> DenseBundleAdjuster::System::poseRhs() const {
  const Linearization& lin = lin_[cur_];
  std::vector<Vec6> v(poses_.size(), Vec6::Zero());
  for (size_t n = 0; n < edges_.size(); ++n) {
    const Edge& e = edges_[n];
    if (e.j < 0) continue;
    v[e.i] += lin.edges[n].Ad.transpose() * lin.edges[n].g;
    v[e.j] -= lin.edges[n].g;
  }
  return v;
}

}  // namespace radslam
