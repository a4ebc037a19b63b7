#include "tracker/motion_only.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <Eigen/Cholesky>
#include <opencv2/core/check.hpp>

#include "tracker/dense_ba_kernel.h"

namespace radslam {
namespace {

void checkImage(const cv::Mat& m, int type, const CameraModel& cam, const std::string& what) {
  if (m.empty() || m.type() != type || m.cols != cam.width || m.rows != cam.height) {
    const std::string got = m.empty() ? "empty"
                                      : std::to_string(m.cols) + "x" + std::to_string(m.rows) +
                                            " " + cv::typeToString(m.type());
    throw std::invalid_argument("MotionOnly: " + what + " is " + got + ", expected " +
                                std::to_string(cam.width) + "x" + std::to_string(cam.height) + " " +
                                cv::typeToString(type));
  }
}

void validate(const CameraModel& camera, const std::vector<DenseBaKeyframe>& keyframes,
              const std::vector<MotionOnlyEdge>& edges, const MotionOnlyDepth& frame_depth) {
  if (!frame_depth.inv_depth.empty() || !frame_depth.inv_depth_var.empty()) {
    checkImage(frame_depth.inv_depth, CV_32FC1, camera, "frame inv_depth");
    checkImage(frame_depth.inv_depth_var, CV_32FC1, camera, "frame inv_depth_var");
  }
  // Camera and keyframes follow the dense BA rules.
  DenseBaProblem problem;
  problem.camera = camera;
  problem.keyframes = keyframes;
  validateDenseBaProblem(problem);
  for (size_t n = 0; n < edges.size(); ++n) {
    const MotionOnlyEdge& e = edges[n];
    const std::string name =
        "edge " + std::to_string(n) + " (keyframe " + std::to_string(e.keyframe) + ")";
    if (e.keyframe < 0 || e.keyframe >= static_cast<int>(keyframes.size())) {
      throw std::invalid_argument("MotionOnly: " + name + ": keyframe out of range (" +
                                  std::to_string(keyframes.size()) + " keyframes)");
    }
    checkImage(e.target, CV_32FC2, camera, name + " target");
    checkImage(e.weight, kFlowWeightType, camera, name + " weight");
  }
}

}  // namespace

double MotionOnlyAligner::linearize(const CameraModel& camera,
                                    const std::vector<DenseBaKeyframe>& keyframes,
                                    const std::vector<MotionOnlyEdge>& edges,
                                    const SE3& T_world_frame, Mat6* H, Vec6* g, int* num_residuals,
                                    double* mean_error_px,
                                    const MotionOnlyDepth& frame_depth) const {
  std::vector<double> measured, measured_var;  // empty without a frame depth
  dense_ba::depthSamples(frame_depth.inv_depth, frame_depth.inv_depth_var, &measured,
                         &measured_var);
  return linearizeSamples(camera, keyframes, edges, T_world_frame, measured, measured_var, H, g,
                          num_residuals, mean_error_px);
}

double MotionOnlyAligner::linearizeSamples(
    const CameraModel& camera, const std::vector<DenseBaKeyframe>& keyframes,
    const std::vector<MotionOnlyEdge>& edges, const SE3& T_world_frame,
    const std::vector<double>& measured, const std::vector<double>& measured_var, Mat6* H, Vec6* g,
    int* num_residuals, double* mean_error_px) const {
  const dense_ba::Pinhole<double> cam{camera.fx, camera.fy, camera.cx, camera.cy};
  const SE3 T_frame_world = T_world_frame.inverse();
  Mat6 A = Mat6::Zero();
  Vec6 b = Vec6::Zero();
  double cost = 0, err = 0;
  int n = 0;
  Mat26 J;
  Eigen::Vector2d Jd;
  const bool jac = H || g;
  for (const MotionOnlyEdge& e : edges) {
    const DenseBaKeyframe& kf = keyframes[e.keyframe];
    const SE3 T_f_k = T_frame_world * kf.T_world_cam;
    const Mat3 R = T_f_k.rotation();
    const Vec3 t = T_f_k.translation();
    for (int v = 0; v < camera.height; ++v) {
      const float* d = kf.inv_depth.ptr<float>(v);
      const cv::Vec2f* target = e.target.ptr<cv::Vec2f>(v);
      const cv::Vec3f* weight = e.weight.ptr<cv::Vec3f>(v);
      const double yn = (v - camera.cy) / camera.fy;
      for (int u = 0; u < camera.width; ++u) {
        Eigen::Matrix2d W;
        if (!flowInformation(weight[u], &W(0, 0), &W(0, 1), &W(1, 1))) continue;
        W(1, 0) = W(0, 1);
        const double tu = target[u][0], tv = target[u][1];
        if (!std::isfinite(tu) || !std::isfinite(tv) || !std::isfinite(d[u])) continue;
        double pu, pv;
        const double xn = (u - camera.cx) / camera.fx;
        if (!dense_ba::reproject<double>(R, t, cam, xn, yn, d[u], options_.min_depth_ratio, &pu,
                                         &pv, jac ? &J : nullptr, nullptr)) {
          continue;
        }
        const double ru = tu - pu, rv = tv - pv;
        double irls;
        const Eigen::Vector2d r(ru, rv);
        cost += dense_ba::robustCost(options_.robust_kernel, r.dot(W * r), options_.robust_scale,
                                     &irls);
        err += std::sqrt(ru * ru + rv * rv);
        ++n;
        if (jac) {
          // delta on the right of T_world_frame is xi = -delta on the left of T_frame_k, so
          // dr/d delta = -(-J_xi) = J_xi.
          const Mat26 WJ = irls * W * J;
          A.noalias() += J.transpose() * WJ;
          b.noalias() += WJ.transpose() * r;
        }
        dense_ba::DepthSample m;
        if (measured.empty() ||
            !dense_ba::sampleDepth(measured.data(), measured_var.data(), camera.width,
                                   camera.height, pu, pv, options_.depth_residual_max_jump, &m)) {
          continue;
        }
        const double iz = 1 / (R.row(2).dot(Vec3(xn, yn, 1)) + t(2) * d[u]), s = d[u] * iz;
        const double rz = m.value - s;
        double irls_z;
        cost += dense_ba::robustCost(options_.robust_kernel, rz * rz / m.var, options_.robust_scale,
                                     &irls_z);
        if (jac) {
          // As the reprojection's: dr/d delta = the prediction's Jacobian wrt xi.
          Vec6 jz;
          double unused_jd;
          const Eigen::Matrix<double, 1, 6> j0 = J.row(0), j1 = J.row(1);
          dense_ba::depthResidualJacobians(m, s, (pu - cam.cx) / cam.fx, (pv - cam.cy) / cam.fy, iz,
                                           t(2), j0, j1, 0.0, 0.0, &jz, &unused_jd);
          const double wz = irls_z / m.var;
          A.noalias() += (wz * jz) * jz.transpose();
          b.noalias() += (wz * rz) * jz;
        }
      }
    }
  }
  if (H) *H = A;
  if (g) *g = b;
  if (num_residuals) *num_residuals = n;
  if (mean_error_px) *mean_error_px = n ? err / n : 0.0;
  return cost;
}

MotionOnlyResult MotionOnlyAligner::align(const CameraModel& camera,
                                          const std::vector<DenseBaKeyframe>& keyframes,
                                          const std::vector<MotionOnlyEdge>& edges,
                                          const SE3& T_world_frame_init,
                                          const MotionOnlyDepth& frame_depth) const {
  validate(camera, keyframes, edges, frame_depth);
  std::vector<double> measured, measured_var;  // empty without a frame depth
  dense_ba::depthSamples(frame_depth.inv_depth, frame_depth.inv_depth_var, &measured,
                         &measured_var);
  MotionOnlyResult result;
  result.T_world_frame = T_world_frame_init;
  Mat6 H;
  Vec6 g;
  int n = 0;
  double cost = linearizeSamples(camera, keyframes, edges, result.T_world_frame, measured,
                                 measured_var, &H, &g, &n);
  result.initial_cost = cost;
  if (n < options_.min_residuals) {
    result.error = "motion-only: " + std::to_string(n) + " valid pixels, need " +
                   std::to_string(options_.min_residuals);
    result.num_residuals = n;
    return result;
  }
  double lambda = options_.initial_lambda;
  while (result.iterations < options_.max_iterations) {
    ++result.iterations;
    Mat6 Hd = H;
    for (int a = 0; a < 6; ++a) Hd(a, a) += lambda * std::max(H(a, a), options_.min_lm_diagonal);
    const Eigen::LDLT<Mat6> ldlt(Hd);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) {
      lambda *= options_.lambda_up;
      if (lambda > options_.max_lambda) break;
      continue;
    }
    const Vec6 delta = -ldlt.solve(g);
    const SE3 T_new = result.T_world_frame * SE3::exp(delta);
    Mat6 H_new;
    Vec6 g_new;
    int n_new = 0;
    const double cost_new = linearizeSamples(camera, keyframes, edges, T_new, measured,
                                             measured_var, &H_new, &g_new, &n_new);
    if (cost_new < cost && n_new >= options_.min_residuals) {
      const double decrease = (cost - cost_new) / std::max(cost, 1e-300);
      result.T_world_frame = T_new;
      H = H_new;
      g = g_new;
      cost = cost_new;
      lambda = std::max(lambda * options_.lambda_down, 1e-12);
      if (decrease < options_.function_tolerance) {
        result.converged = true;
        break;
      }
    } else {
      lambda *= options_.lambda_up;
      if (lambda > options_.max_lambda) {
        result.converged = true;  // no decrease at any damping: at the minimum
        break;
      }
    }
  }
  result.final_cost = cost;
  linearizeSamples(camera, keyframes, edges, result.T_world_frame, measured, measured_var, nullptr,
                   nullptr, &result.num_residuals, &result.mean_reprojection_error_px);
  const Eigen::LLT<Mat6> llt(H);
  if (llt.info() != Eigen::Success) {
    result.error = "motion-only: Hessian not positive definite (degenerate geometry)";
    return result;
  }
  result.covariance = llt.solve(Mat6::Identity());
  result.covariance = 0.5 * (result.covariance + result.covariance.transpose()).eval();
  result.ok = true;
  return result;
}

}  // namespace radslam
