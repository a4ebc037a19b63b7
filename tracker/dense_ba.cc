#include "tracker/dense_ba.h"

#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include <opencv2/core/check.hpp>

#include "tracker/dense_ba_kernel.h"
#include "tracker/dense_ba_system.h"

namespace radslam {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

std::string describe(const cv::Mat& m) {
  if (m.empty()) return "empty";
  return std::to_string(m.cols) + "x" + std::to_string(m.rows) + " " + cv::typeToString(m.type());
}

void checkImage(const cv::Mat& m, int type, const CameraModel& cam, const std::string& what) {
  if (m.empty() || m.type() != type || m.cols != cam.width || m.rows != cam.height) {
    throw std::invalid_argument("DenseBA: " + what + " is " + describe(m) + ", expected " +
                                std::to_string(cam.width) + "x" + std::to_string(cam.height) + " " +
                                cv::typeToString(type));
  }
}

bool finitePose(const SE3& T) {
  return T.translation().allFinite() && T.quaternion().coeffs().allFinite();
}

dense_ba::Pinhole<double> pinhole(const CameraModel& c) { return {c.fx, c.fy, c.cx, c.cy}; }

bool stepIsNegligible(const std::vector<Vec6>& dxi, const std::vector<Eigen::VectorXd>& dd,
                      const std::vector<Eigen::VectorXd>& depths, double tolerance) {
  for (const Vec6& x : dxi) {
    if (x.lpNorm<Eigen::Infinity>() >= tolerance) return false;
  }
  for (size_t k = 0; k < dd.size(); ++k) {
    if ((dd[k].array() / depths[k].array()).abs().maxCoeff() >= tolerance) return false;
  }
  return true;
}

}  // namespace

RobustKernel parseRobustKernel(const std::string& name) {
  if (name == "huber") return RobustKernel::kHuber;
  if (name == "cauchy") return RobustKernel::kCauchy;
  throw std::invalid_argument("robust kernel '" + name + "' is unknown (huber, cauchy)");
}

void validateDenseBaProblem(const DenseBaProblem& problem) {
  const CameraModel& cam = problem.camera;
  if (cam.type != CameraModel::Type::kPinhole) {
    throw std::invalid_argument("DenseBA: camera must be pinhole (undistort before BA)");
  }
  for (double k : cam.distortion) {
    if (k != 0) throw std::invalid_argument("DenseBA: camera has distortion; undistort first");
  }
  if (cam.width <= 0 || cam.height <= 0 || !(cam.fx > 0) || !(cam.fy > 0) ||
      !std::isfinite(cam.fx) || !std::isfinite(cam.fy) || !std::isfinite(cam.cx) ||
      !std::isfinite(cam.cy)) {
    throw std::invalid_argument("DenseBA: bad grid camera " + std::to_string(cam.width) + "x" +
                                std::to_string(cam.height) + " fx=" + std::to_string(cam.fx) +
                                " fy=" + std::to_string(cam.fy) + " cx=" + std::to_string(cam.cx) +
                                " cy=" + std::to_string(cam.cy));
  }
  const int K = static_cast<int>(problem.keyframes.size());
  for (int k = 0; k < K; ++k) {
    const DenseBaKeyframe& kf = problem.keyframes[k];
    const std::string name = "keyframe " + std::to_string(k);
    checkImage(kf.inv_depth, CV_32FC1, cam, name + " inv_depth");
    if (!finitePose(kf.T_world_cam)) {
      throw std::invalid_argument("DenseBA: " + name + " has a non-finite pose");
    }
    if (!kf.prior_inv_depth.empty() || !kf.prior_inv_depth_var.empty()) {
      checkImage(kf.prior_inv_depth, CV_32FC1, cam, name + " prior_inv_depth");
      checkImage(kf.prior_inv_depth_var, CV_32FC1, cam, name + " prior_inv_depth_var");
    }
    if (!kf.measured_inv_depth.empty() || !kf.measured_inv_depth_var.empty()) {
      checkImage(kf.measured_inv_depth, CV_32FC1, cam, name + " measured_inv_depth");
      checkImage(kf.measured_inv_depth_var, CV_32FC1, cam, name + " measured_inv_depth_var");
    }
    if (!(std::isfinite(kf.prior_level_var) && kf.prior_level_var >= 0)) {
      throw std::invalid_argument("DenseBA: " + name + " prior_level_var must be finite and >= 0");
    }
  }
  for (size_t n = 0; n < problem.edges.size(); ++n) {
    const DenseBaEdge& e = problem.edges[n];
    const std::string name = "edge " + std::to_string(n) + " (" + std::to_string(e.i) + " -> " +
                             (e.T_i_other ? std::string("fixed") : std::to_string(e.j)) + ")";
    if (e.i < 0 || e.i >= K) {
      throw std::invalid_argument("DenseBA: " + name + ": source keyframe out of range (" +
                                  std::to_string(K) + " keyframes)");
    }
    if (e.T_i_other) {
      if (!finitePose(*e.T_i_other)) {
        throw std::invalid_argument("DenseBA: " + name + ": non-finite T_i_other");
      }
    } else if (e.j < 0 || e.j >= K || e.j == e.i) {
      throw std::invalid_argument("DenseBA: " + name +
                                  ": target keyframe out of range or equal to the source");
    }
    checkImage(e.target, CV_32FC2, cam, name + " target");
    checkImage(e.weight, kFlowWeightType, cam, name + " weight");
  }
}

bool denseBaResidual(const CameraModel& camera, const SE3& T_world_i, const SE3& T_world_j,
                     double u, double v, double d, const Eigen::Vector2d& target,
                     double min_depth_ratio, Eigen::Vector2d* r, Mat26* H_i, Mat26* H_j,
                     Eigen::Vector2d* H_d) {
  const SE3 T_j_i = T_world_j.inverse() * T_world_i;
  const Mat3 R = T_j_i.rotation();
  const Vec3 t = T_j_i.translation();
  const bool jac = H_i || H_j || H_d;
  Mat26 J_xi;
  Eigen::Vector2d J_d;
  double pu, pv;
  if (!dense_ba::reproject<double>(R, t, pinhole(camera), (u - camera.cx) / camera.fx,
                                   (v - camera.cy) / camera.fy, d, min_depth_ratio, &pu, &pv,
                                   jac ? &J_xi : nullptr, jac ? &J_d : nullptr)) {
    return false;
  }
  *r = target - Eigen::Vector2d(pu, pv);
  // r = target - pixel; xi = Ad(T_j_i) delta_i - delta_j.
  if (H_i) *H_i = -J_xi * T_j_i.adjoint();
  if (H_j) *H_j = J_xi;
  if (H_d) *H_d = -J_d;
  return true;
}

bool denseBaDepthResidual(const CameraModel& camera, const SE3& T_world_i, const SE3& T_world_j,
                          double u, double v, double d, const cv::Mat& measured_inv_depth,
                          const cv::Mat& measured_inv_depth_var, double min_depth_ratio,
                          double max_jump, double* r, double* weight,
                          Eigen::Matrix<double, 1, 6>* H_i, Eigen::Matrix<double, 1, 6>* H_j,
                          double* H_d) {
  checkImage(measured_inv_depth, CV_32FC1, camera, "denseBaDepthResidual measured_inv_depth");
  checkImage(measured_inv_depth_var, CV_32FC1, camera,
             "denseBaDepthResidual measured_inv_depth_var");
  const SE3 T_j_i = T_world_j.inverse() * T_world_i;
  const Mat3 R = T_j_i.rotation();
  const Vec3 t = T_j_i.translation();
  Mat26 J_xi;
  Eigen::Vector2d J_d;
  double pu, pv;
  const double x = (u - camera.cx) / camera.fx, y = (v - camera.cy) / camera.fy;
  if (!dense_ba::reproject<double>(R, t, pinhole(camera), x, y, d, min_depth_ratio, &pu, &pv, &J_xi,
                                   &J_d)) {
    return false;
  }
  std::vector<double> mean, var;
  dense_ba::depthSamples(measured_inv_depth, measured_inv_depth_var, &mean, &var);
  dense_ba::DepthSample sample;
  if (!dense_ba::sampleDepth(mean.data(), var.data(), camera.width, camera.height, pu, pv, max_jump,
                             &sample)) {
    return false;
  }
  const double Z = R.row(2).dot(Vec3(x, y, 1)) + t(2) * d;
  const double iz = 1 / Z, s = d * iz;
  *r = sample.value - s;
  *weight = 1 / sample.var;
  Vec6 jz;
  double jd;
  const Eigen::Matrix<double, 1, 6> j0 = J_xi.row(0), j1 = J_xi.row(1);
  dense_ba::depthResidualJacobians(sample, s, (pu - camera.cx) / camera.fx,
                                   (pv - camera.cy) / camera.fy, iz, t(2), j0, j1, J_d(0), J_d(1),
                                   &jz, &jd);
  // r = measured - prediction: dr = -J; xi = Ad(T_j_i) delta_i - delta_j.
  if (H_i) *H_i = -jz.transpose() * T_j_i.adjoint();
  if (H_j) *H_j = jz.transpose();
  if (H_d) *H_d = -jd;
  return true;
}

cv::Mat reprojectKeyframe(const CameraModel& camera, const DenseBaKeyframe& keyframe,
                          const SE3& T_world_j, double min_depth_ratio) {
  checkImage(keyframe.inv_depth, CV_32FC1, camera, "reprojectKeyframe inv_depth");
  const SE3 T_j_i = T_world_j.inverse() * keyframe.T_world_cam;
  const Mat3 R = T_j_i.rotation();
  const Vec3 t = T_j_i.translation();
  const dense_ba::Pinhole<double> cam = pinhole(camera);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  cv::Mat out(camera.height, camera.width, CV_32FC2);
  for (int v = 0; v < camera.height; ++v) {
    const float* d = keyframe.inv_depth.ptr<float>(v);
    cv::Vec2f* o = out.ptr<cv::Vec2f>(v);
    const double yn = (v - camera.cy) / camera.fy;
    for (int u = 0; u < camera.width; ++u) {
      double pu, pv;
      const bool ok = dense_ba::reproject<double>(R, t, cam, (u - camera.cx) / camera.fx, yn, d[u],
                                                  min_depth_ratio, &pu, &pv, nullptr, nullptr);
      o[u] = ok ? cv::Vec2f(static_cast<float>(pu), static_cast<float>(pv)) : cv::Vec2f(nan, nan);
    }
  }
  return out;
}

DenseBundleAdjuster::DenseBundleAdjuster(const DenseBaOptions& options)
    : options_(options), system_(std::make_unique<System>()) {}

DenseBundleAdjuster::~DenseBundleAdjuster() = default;

DenseBaSummary DenseBundleAdjuster::optimize(DenseBaProblem* problem) {
  if (!problem) throw std::invalid_argument("DenseBA: null problem");
  validateDenseBaProblem(*problem);
  const auto t_start = Clock::now();
  DenseBaSummary summary;
  System& sys = *system_;
  sys.setup(*problem, options_);

  auto t0 = Clock::now();
  double cost = sys.linearize();
  summary.linearize_ms += msSince(t0);
  summary.initial_cost = cost;
  const int K = static_cast<int>(problem->keyframes.size());

  double lambda = options_.initial_lambda;
  std::vector<Vec6> dxi;
  std::vector<Eigen::VectorXd> dd, cand_depths;
  std::vector<SE3> cand_poses;
  bool any_solve = false;
  while (summary.iterations < options_.max_iterations) {
    ++summary.iterations;
    t0 = Clock::now();
    const bool solved = sys.solve(lambda, &dxi, &dd);
    summary.solve_ms += msSince(t0);
    if (!solved) {
      summary.error = sys.solverError();
      lambda *= options_.lambda_up;
      if (lambda > options_.max_lambda) break;
      continue;
    }
    any_solve = true;
    if (stepIsNegligible(dxi, dd, sys.depths_, options_.step_tolerance)) {
      summary.converged = true;
      break;
    }
    sys.retract(dxi, dd, &cand_poses, &cand_depths);
    // The trial point is linearised right away: most steps are accepted, and the linearisation
    // then serves the next iteration (one pass over the pixels per iteration).
    t0 = Clock::now();
    const double new_cost = sys.linearizeCandidate(cand_poses, cand_depths);
    summary.linearize_ms += msSince(t0);
    if (new_cost < cost) {
      ++summary.accepted_steps;
      const double decrease = (cost - new_cost) / std::max(cost, 1e-300);
      sys.acceptCandidate(&cand_poses, &cand_depths);
      cost = new_cost;
      lambda = std::max(lambda * options_.lambda_down, options_.min_lambda);
      if (decrease < options_.function_tolerance) {
        summary.converged = true;
        break;
      }
    } else {
      lambda *= options_.lambda_up;
      if (lambda > options_.max_lambda) {
        // No damping finds a decrease: at a minimum to numerical precision.
        summary.converged = true;
        break;
      }
    }
  }
  summary.mean_reprojection_error_px = sys.meanErrorPx();
  summary.num_residuals = sys.numResiduals();
  summary.ok = any_solve || options_.max_iterations == 0;
  if (summary.ok) summary.error.clear();
  summary.final_cost = cost;
  summary.final_lambda = lambda;
  summary.used_cholmod = sys.usedCholmod();

  for (int k = 0; k < K; ++k) {
    DenseBaKeyframe& kf = problem->keyframes[k];
    kf.T_world_cam = sys.poses_[k];
    cv::Mat d(kf.inv_depth.rows, kf.inv_depth.cols, CV_32FC1);
    float* out = d.ptr<float>();
    const Eigen::VectorXd& src = sys.depths_[k];
    for (int p = 0; p < src.size(); ++p) out[p] = static_cast<float>(src(p));
    kf.inv_depth = d;
  }
  summary.total_ms = msSince(t_start);
  return summary;
}

DenseBaMarginals DenseBundleAdjuster::computeMarginals(const DenseBaProblem& problem) {
  validateDenseBaProblem(problem);
  System& sys = *system_;
  sys.setup(problem, options_);
  sys.linearize();
  DenseBaMarginals out;
  sys.marginals(&out);
  return out;
}

double DenseBundleAdjuster::evaluateCost(const DenseBaProblem& problem) {
  validateDenseBaProblem(problem);
  System& sys = *system_;
  sys.setup(problem, options_);
  return sys.evaluate(sys.poses_, sys.depths_);
}

bool DenseBundleAdjuster::computeStep(const DenseBaProblem& problem, double lambda,
                                      DenseBaStep* step, std::string* error) {
  validateDenseBaProblem(problem);
  System& sys = *system_;
  sys.setup(problem, options_);
  step->cost = sys.linearize();
  const CameraModel& cam = problem.camera;
  auto toMat = [&](const Eigen::VectorXd& v) {
    cv::Mat m(cam.height, cam.width, CV_64FC1);
    Eigen::Map<Eigen::VectorXd>(m.ptr<double>(), v.size()) = v;
    return m;
  };
  const size_t K = problem.keyframes.size();
  step->pose_rhs = sys.poseRhs();
  step->depth_rhs.clear();
  step->depth_hessian.clear();
  for (size_t k = 0; k < K; ++k) {
    step->depth_rhs.push_back(toMat(sys.depthRhs()[k]));
    step->depth_hessian.push_back(toMat(sys.depthHessian()[k]));
  }
  std::vector<Eigen::VectorXd> dd;
  step->dd.clear();
  if (!sys.solve(lambda, &step->dxi, &dd)) {
    if (error) *error = sys.solverError();
    return false;
  }
  for (size_t k = 0; k < K; ++k) step->dd.push_back(toMat(dd[k]));
  return true;
}

}  // namespace radslam
