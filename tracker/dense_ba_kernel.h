// Per-pixel kernels shared by dense BA and motion-only alignment: the inverse-depth reprojection
// with its analytic Jacobians and the Huber kernel. Header-only so the inner loops inline them.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Core>

#include "tracker/dense_ba.h"

namespace radslam {
namespace dense_ba {

/// Pinhole intrinsics at BA grid resolution (pixels), in the scalar type of the inner loop.
template <typename S>
struct Pinhole {
  S fx, fy, cx, cy;
};

template <typename S>
using Mat26T = Eigen::Matrix<S, 2, 6>;
template <typename S>
using Vec2T = Eigen::Matrix<S, 2, 1>;

/// Reprojects the point seen at normalised coordinates (x, y) = ((u - cx) / fx, (v - cy) / fy)
/// in camera i with inverse depth d (1/m) into camera j, T_j_i = (R, t).
///
/// The point is used in homogeneous form Y = R (x, y, 1) + t d = d * p_j, whose projection is
/// that of p_j and which stays finite as d -> 0 (points at infinity). Y.z = z_j / z_i is the
/// ratio of the point's depths in j and i; the point is rejected (returns false) when it is
/// below min_depth_ratio (behind camera j or much closer to it), as DROID-SLAM's MIN_DEPTH test,
/// which is invariant to the arbitrary monocular scale.
///
/// On success writes the pixel in j and, when non-null,
///  J_xi: d pixel / d xi for a LEFT perturbation of T_j_i: T_j_i <- Exp(xi) T_j_i, xi = (v, w);
///  J_d:  d pixel / d d.
/// With right perturbations T_world_i <- T_world_i Exp(delta_i), T_world_j <- T_world_j
/// Exp(delta_j) one has xi = Ad(T_j_i) delta_i - delta_j, so
///  d pixel / d delta_i = J_xi Ad(T_j_i) and d pixel / d delta_j = -J_xi.
template <typename S>
inline bool reproject(const Eigen::Matrix<S, 3, 3>& R, const Eigen::Matrix<S, 3, 1>& t,
                      const Pinhole<S>& cam, S x, S y, S d, S min_depth_ratio, S* pu, S* pv,
                      Mat26T<S>* J_xi, Vec2T<S>* J_d) {
  const S X = R(0, 0) * x + R(0, 1) * y + R(0, 2) + t(0) * d;
  const S Y = R(1, 0) * x + R(1, 1) * y + R(1, 2) + t(1) * d;
  const S Z = R(2, 0) * x + R(2, 1) * y + R(2, 2) + t(2) * d;
  if (!(Z > min_depth_ratio)) return false;
  const S iz = S(1) / Z;
  const S xn = X * iz;
  const S yn = Y * iz;
  *pu = cam.fx * xn + cam.cx;
  *pv = cam.fy * yn + cam.cy;
  if (J_xi) {
    // d pixel / dY = [fx iz, 0, -fx xn iz; 0, fy iz, -fy yn iz]; dY/dxi = [d I, -hat(Y)].
    const S fxiz = cam.fx * iz;
    const S fyiz = cam.fy * iz;
    auto& J = *J_xi;
    J(0, 0) = fxiz * d;
    J(0, 1) = S(0);
    J(0, 2) = -fxiz * xn * d;
    J(0, 3) = -cam.fx * xn * yn;
    J(0, 4) = cam.fx * (S(1) + xn * xn);
    J(0, 5) = -cam.fx * yn;
    J(1, 0) = S(0);
    J(1, 1) = fyiz * d;
    J(1, 2) = -fyiz * yn * d;
    J(1, 3) = -cam.fy * (S(1) + yn * yn);
    J(1, 4) = cam.fy * xn * yn;
    J(1, 5) = cam.fy * xn;
  }
  if (J_d) {
    // dY/dd = t.
    (*J_d)(0) = cam.fx * iz * (t(0) - xn * t(2));
    (*J_d)(1) = cam.fy * iz * (t(1) - yn * t(2));
  }
  return true;
}

/// A measured inverse-depth map (row-major, width x height, pixel centres at integers; variance
/// 0 where nothing was measured) at (pu, pv): the plane (affine in the pixel) fitted to the
/// 3 x 3 samples around the nearest one, its value and gradient there, and the largest variance
/// of the nine (a weight that does not move with the point). The gradient enters the residual's
/// Jacobians: fitted over nine samples its noise is a sixth to a twelfth of a difference of two
/// neighbours', and at the centre it is uncorrelated with the value's (the errors-in-variables
/// bias of a noisy slope made the pose marginals overconfident). False within one sample of the
/// border (also for NaN), where a sample is missing, and where the nine spread by more than
/// max_jump times the largest (a depth edge, whose fit would be neither surface).
struct DepthSample {
  double value = 0, du = 0, dv = 0, var = 0;
};

/// A measured map (CV_32FC1 mean and variance) as sampleDepth reads it: row-major doubles, the
/// variance 0 (and the mean 0) where the mean is not finite or the variance not in (0, inf);
/// both empty for an empty map.
inline void depthSamples(const cv::Mat& mean, const cv::Mat& var, std::vector<double>* out_mean,
                         std::vector<double>* out_var) {
  out_mean->resize(mean.total());
  out_var->resize(mean.total());
  for (size_t p = 0; p < mean.total(); ++p) {
    const double m = mean.at<float>(static_cast<int>(p));
    const double s2 = var.at<float>(static_cast<int>(p));
    const bool valid = std::isfinite(m) && s2 > 0 && std::isfinite(s2);
    (*out_mean)[p] = valid ? m : 0.0;
    (*out_var)[p] = valid ? s2 : 0.0;
  }
}

inline bool sampleDepth(const double* mean, const double* var, int width, int height, double pu,
                        double pv, double max_jump, DepthSample* out) {
  const double cu = std::floor(pu + 0.5), cv = std::floor(pv + 0.5);
  if (!(cu >= 1 && cv >= 1 && cu + 1 < width && cv + 1 < height)) return false;
  const int centre = static_cast<int>(cv) * width + static_cast<int>(cu);
  double lo = mean[centre], hi = lo, sum = 0, sum_u = 0, sum_v = 0, var_max = 0;
  for (int dv = -1; dv <= 1; ++dv) {
    const int row = centre + dv * width;
    for (int du = -1; du <= 1; ++du) {
      const double m = mean[row + du], s2 = var[row + du];
      if (!(s2 > 0)) return false;
      lo = std::min(lo, m);
      hi = std::max(hi, m);
      var_max = std::max(var_max, s2);
      sum += m;
      sum_u += du * m;
      sum_v += dv * m;
    }
  }
  if (hi - lo > max_jump * hi) return false;
  // Least squares on the 3 x 3 grid: the mean, and each slope from the outer columns / rows.
  out->du = sum_u / 6;
  out->dv = sum_v / 6;
  out->value = sum / 9 + out->du * (pu - cu) + out->dv * (pv - cv);
  out->var = var_max;
  return true;
}

/// The depth residual of a point reprojected by dense_ba::reproject (its normalised coordinates
/// xn, yn in j, s = d / Z its inverse depth in j): r = measured(pixel) - s. With the pixel
/// Jacobian rows j0, j1 (wrt xi, left perturbation of T_j_i) and Jd (wrt d) of that call, the
/// prediction's Jacobians, in the sign convention of the reprojection's (J = -dr/dx):
///   jz = ds/dxi - grad . dpixel/dxi, ds/dxi = -s [0, 0, s, yn, -xn, 0] (dZ/dxi = [0 0 d Y -X 0]);
///   jd = ds/dd - grad . dpixel/dd,   ds/dd = (1 - s t_z) / Z.
template <typename Row>
inline void depthResidualJacobians(const DepthSample& m, double s, double xn, double yn, double iz,
                                   double tz, const Row& j0, const Row& j1, double jd0, double jd1,
                                   Eigen::Matrix<double, 6, 1>* jz, double* jd) {
  for (int a = 0; a < 6; ++a) (*jz)(a) = -m.du * j0[a] - m.dv * j1[a];
  (*jz)(2) -= s * s;
  (*jz)(3) -= s * yn;
  (*jz)(4) += s * xn;
  *jd = iz * (1 - s * tz) - m.du * jd0 - m.dv * jd1;
}

/// Huber kernel on the whitened residual norm s = sqrt(r^T W r) with threshold k (k <= 0:
/// plain least squares). Returns the robust cost rho (= s^2 below k, 2 k s - k^2 above, so the
/// cost is continuous with continuous slope) and writes the IRLS weight rho'(s^2) = min(1, k/s).
template <typename S>
inline S huber(S s2, S k, S* irls_weight) {
  if (k <= S(0) || s2 <= k * k) {
    *irls_weight = S(1);
    return s2;
  }
  const S s = std::sqrt(s2);
  *irls_weight = k / s;
  return S(2) * k * s - k * k;
}

/// Cauchy kernel with scale k (k <= 0: plain least squares): rho = k^2 log(1 + s^2 / k^2),
/// IRLS weight rho'(s^2) = 1 / (1 + s^2 / k^2). Redescending: a gross error's pull falls as
/// 1/s instead of staying at Huber's k, so a cluster of consistent wrong flows (a textureless
/// stretch, a repeated pattern) cannot drag the estimate the way it does under Huber.
template <typename S>
inline S cauchy(S s2, S k, S* irls_weight) {
  if (k <= S(0)) {
    *irls_weight = S(1);
    return s2;
  }
  const S c2 = k * k;
  *irls_weight = S(1) / (S(1) + s2 / c2);
  return c2 * std::log1p(s2 / c2);
}

/// The kernel's cost at squared whitened norm s2 with scale k, and its IRLS weight.
template <typename S>
inline S robustCost(RobustKernel kernel, S s2, S k, S* irls_weight) {
  return kernel == RobustKernel::kCauchy ? cauchy(s2, k, irls_weight) : huber(s2, k, irls_weight);
}

}  // namespace dense_ba
}  // namespace radslam
